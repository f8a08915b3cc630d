"""Vendor-style programs written by hand, as the vendors document them, for the kr16 (6 axes).

Cartesian values are the nominal kr16's TCP (tool 12.5, 0, 180 mm on tool0; base
1000, -200, 0 mm turned 90 deg about z where the language declares one) at
(10, -80, 95, 0, 30, 0), (20, -70, 100, 15, 50, -30) and (-15, -100, 110, -20, 40, 60) deg,
rounded as a teach pendant would show them.
"""

#: KUKA KSS 8.x, "Operating and Programming Instructions for System Integrators": module =
#: .src (DEF ... END, FOLDs, $TOOL/$BASE, PTP/LIN with inline aggregates) + .dat (DEFDAT, DECL).
KRL_SRC = """&ACCESS RVP
&REL 3
&PARAM TEMPLATE = C:\\KRC\\Roboter\\Template\\vorgabe
&PARAM EDITMASK = *
DEF weld_demo( )
;FOLD INI;%{PE}
  ;FOLD BASISTECH INI
    GLOBAL INTERRUPT DECL 3 WHEN $STOPMESS==TRUE DO IR_STOPM ( )
    INTERRUPT ON 3
    BAS (#INITMOV,0 )
  ;ENDFOLD (BASISTECH INI)
;ENDFOLD (INI)
$TOOL={X 12.5,Y 0.0,Z 180.0,A 0.0,B 0.0,C 0.0}
$BASE={X 1000.0,Y -200.0,Z 0.0,A 90.0,B 0.0,C 0.0}
PTP XHOME
PTP {A1 10.0,A2 -80.0,A3 95.0,A4 0.0,A5 30.0,A6 0.0}
LIN XP2 C_DIS
LIN {X -237.6,Y -18.8,Z 620.4,A 49.54,B 14.24,C -173.08,S 2,T 35} C_DIS
PTP XP4
END
"""

KRL_DAT = """&ACCESS RVP
&REL 3
DEFDAT  WELD_DEMO
;FOLD EXTERNAL DECLARATIONS;%{PE}%MKUKATPBASIS,%CEXT,%VCOMMON,%P
;ENDFOLD (EXTERNAL DECLARATIONS)
DECL E6AXIS XHOME={A1 0.0,A2 -90.0,A3 90.0,A4 0.0,A5 30.0,A6 0.0,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
DECL E6POS XP2={X -16.4,Y -227.4,Z 889.6,A 80.0,B 45.0,C 180.0,S 6,T 50,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
DECL FDAT FP2={TOOL_NO 1,BASE_NO 1,IPO_FRAME #BASE,POINT2[] " "}
DECL E6POS XP4={X 524.9,Y 41.6,Z 940.5,A 162.77,B 36.18,C -154.39,S 2,T 10,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
ENDDAT
"""

#: ABB "Technical reference manual - RAPID Instructions, Functions and Data types":
#: MODULE, tooldata/wobjdata, robtarget/jointtarget (CONST/PERS), MoveAbsJ/MoveJ/MoveL. The confdata
#: of pApproach and pWeld are those of the joints they were taught at; the last MoveL's [0,0,0,0] is not
#: (its joints, -15, -100, 110, -20, 40, 60 deg, have cf1 -1 and cf4 -1).
RAPID_MOD = """MODULE WeldDemo
    ! taught on the pendant
    PERS tooldata tWeld:=[TRUE,[[12.5,0,180],[1,0,0,0]],[2.5,[0,0,100],[1,0,0,0],0,0,0]];
    TASK PERS wobjdata wTable:=[FALSE,TRUE,"",[[1000,-200,0],[0.707106781,0,0,0.707106781]],[[0,0,0],[1,0,0,0]]];
    CONST jointtarget jHome:=[[0,-90,90,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
    CONST robtarget pApproach:=[[-16.4,-227.4,889.6],[0.24598,0.70773,0.59386,-0.29315],[0,0,-1,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
    PERS robtarget pWeld:=[[-237.6,-18.8,620.4],[-0.00253,0.9025,0.40816,-0.13745],[0,0,-1,0],[9E9,9E9,9E9,9E9,9E9,9E9]];

    PROC main()
        MoveAbsJ jHome\\NoEOffs, v1000, fine, tWeld;
        MoveAbsJ [[10,-80,95,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]]\\NoEOffs, v500, z10, tWeld;
        MoveJ pApproach, v1000, z50, tWeld\\WObj:=wTable;
        MoveL pWeld, v100, fine, tWeld\\WObj:=wTable;
        MoveL [[524.9,41.6,940.5],[0.26783,0.20687,0.90617,-0.25364],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]], v100, fine, tWeld\\WObj:=wTable;
    ENDPROC
ENDMODULE
"""

#: FANUC R-30iB Operator's Manual, "Program structure" / ASCII .ls: /PROG, /ATTR, /MN, /POS, /END;
#: positions with GP1 in joint (J1..J6 deg) or Cartesian (X, Y, Z mm, W, P, R deg, CONFIG).
#: Its user frame 1 and tool frame 1 are controller data: the test gives them (--base, --tool).
TP_LS = """/PROG  WELD_DEMO
/ATTR
OWNER\t\t= MNEDITOR;
COMMENT\t\t= "weld demo";
PROG_SIZE\t= 636;
LINE_COUNT\t= 5;
MEMORY_SIZE\t= 1000;
DEFAULT_GROUP\t= 1,*,*,*,*;
/MN
   1:  UFRAME_NUM=1 ;
   2:  UTOOL_NUM=1 ;
   3:J P[1:HOME] 100% FINE    ;
   4:J P[2] 50% CNT50    ;
   5:L P[3:weld] 100mm/sec FINE    ;
/POS
P[1:"HOME"]{
   GP1:
\tUF : 1, UT : 1,\t
\tJ1=    10.000 deg,\tJ2=   -80.000 deg,\tJ3=    95.000 deg,
\tJ4=      .000 deg,\tJ5=    30.000 deg,\tJ6=      .000 deg
};
P[2]{
   GP1:
\tUF : 1, UT : 1,\t\tCONFIG : 'N U T, 0, 0, 0',
\tX =   -16.400  mm,\tY =  -227.400  mm,\tZ =   889.600  mm,
\tW =   180.000 deg,\tP =    45.000 deg,\tR =    80.000 deg
};
P[3:"weld"]{
   GP1:
\tUF : 1, UT : 1,\t\tCONFIG : 'N U T, 0, 0, 0',
\tX =  -237.600  mm,\tY =   -18.800  mm,\tZ =   620.400  mm,
\tW =  -173.080 deg,\tP =    14.240 deg,\tR =    49.540 deg
};
/END
"""

#: Universal Robots "The URScript Programming Language" (e-Series): def/end, set_tcp,
#: variables, movej with a joint list [rad] and with a pose, movel to a pose p[m, rotation vector].
UR_SCRIPT = """def pick_demo():
  set_tcp(p[0.0, 0.0, 0.15, 0.0, 0.0, 0.0])
  home = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]
  approach = p[0.5655, 0.2893, 0.2899, -2.0896, 2.3098, -0.0181]
  movej(home, a=1.4, v=1.05)
  movej([0.3, -1.2, 1.5, -1.9, -1.57, 0.4], a=1.4, v=1.05)
  movel(approach, a=1.2, v=0.25)
  movel(p[0.4508, -0.1153, 0.3095, 0.1063, -3.1114, -0.1511], a=1.2, v=0.25)
end
pick_demo()
"""

#: The Cartesian target CSV of docs/compensate.md.
CSV_POSES = """# targets of a deburring path; x, y, z [mm], rx, ry, rz [deg] fixed XYZ
name,x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg
a,-16.4,-227.4,889.6,180.0,45.0,80.0
b,-237.6,-18.8,620.4,-173.08,14.24,49.54
"""
