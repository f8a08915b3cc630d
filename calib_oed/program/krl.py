"""KUKA KRL: a ``.src`` with ``PTP`` moves to ``E6AXIS`` joint targets declared in the ``.dat``.

Each target is ``DECL E6AXIS XCAL_NAME={A1 ..,A2 ..,...,A6 ..,E1 0.0,...,E6 0.0}`` [deg]
(``XCAL_HOME``, ``XCAL_P1``, ``XCAL_V1``: never a global name of the controller such as
``$config.dat``'s ``XHOME``, which a declaration in the module would shadow);
each measurement pose is followed by ``WAIT SEC dwell`` and a comment naming it. The
``.src`` opens with KUKA's usual initialisation: the stop-message interrupt
(``INTERRUPT DECL 3 WHEN $STOPMESS==TRUE DO IR_STOPM ( )``, ``INTERRUPT ON 3``) and
``BAS (#INITMOV,0 )``. The module name (the output name, upper-cased) is a KRL name: at most
24 ASCII characters, not a keyword of the language, not one of the controller's own modules
the program calls (``BAS``, ``IR_STOPM``) and not of the targets' form (``XCAL_...``).

Checked (issue 31) against the ANTLR KRL grammar of ``grammars-v4`` (``kuka/krl.g4``, run
once by hand: no package ships it, so no test can): 0 findings on the written ``.src`` and
``.dat`` with and without handshake, tool, base, payload and controller block; the tests
parse every line with the statements' forms and read the files back
(:mod:`calib_oed.program.parse.krl`).
"""

from __future__ import annotations

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.program.format_common import (
    MeasureWords,
    degrees,
    frame_values,
    header_lines,
    require_six_axes,
    steps,
)
from calib_oed.program.records import Program

#: Prefix of the targets' names in the ``.dat`` (not ``X``: ``XHOME`` is the controller's).
TARGET_PREFIX = "XCAL_"
#: Longest KRL name (characters; KUKA System Software 8, "Names").
KRL_NAME_LENGTH = 24
#: Names a module may not take: KRL's keywords (the statements and types a module may hold) and
#: the controller modules the program calls.
RESERVED = frozenset(
    "AND ANIN ANOUT B_AND B_EXOR B_NOT B_OR BOOL BRAKE C_DIS C_ORI C_PTP C_VEL CASE CHAR CIRC "
    "CIRC_REL CONST CONTINUE DECL DEF DEFAULT DEFDAT DEFFCT DELAY DO ELSE END ENDDAT ENDFCT ENDFOR "
    "ENDIF ENDLOOP ENDSWITCH ENDWHILE ENUM EXIT EXOR EXT EXTFCT FALSE FOR GLOBAL GOTO HALT IF IMPORT "
    "INT INTERRUPT IS LIN LIN_REL LOOP MAXIMUM MINIMUM NOT OR PRIO PTP PTP_REL PUBLIC REAL REPEAT "
    "RESUME RETURN SCIRC SEC SIGNAL SLIN SPTP STEP STRUC SWITCH THEN TO TRIGGER TRUE UNTIL WAIT WHEN "
    "WHILE BAS IR_STOPM".split())


def check_module_name(name: str) -> str:
    """The KRL module name of output name ``name`` (upper case), or ProgramError naming the rule broken."""
    module = name.upper()
    if not (name.isascii() and name.isidentifier()) or len(name) > KRL_NAME_LENGTH:
        raise ProgramError("name", name, f"a KRL module name is at most {KRL_NAME_LENGTH} ASCII letters, "
                           "digits and _, not starting with a digit")
    if module in RESERVED or module.startswith(TARGET_PREFIX):
        raise ProgramError("name", name, f"a KRL keyword, a controller module or a target's name "
                           f"({TARGET_PREFIX}...): choose another module name")
    return module


def _frame(frame) -> str:
    x, y, z, a, b, c = frame_values(frame)
    return f"{{X {x:.3f},Y {y:.3f},Z {z:.3f},A {a:.4f},B {b:.4f},C {c:.4f}}}"


def _declarations(program: Program) -> list[str]:
    """``$TOOL``, ``$BASE``, ``$LOAD`` from the scene's program block (after ``BAS``, which resets them)."""
    out = []
    if program.tool is not None:
        out.append(f"  $TOOL={_frame(program.tool)} ; tool {program.tool.number}")
    if program.base is not None:
        out.append(f"  $BASE={_frame(program.base)} ; base {program.base.number}")
    if program.payload is not None:
        x, y, z = (1e3 * np.asarray(program.payload.com, float)).tolist()
        out += [f"  $LOAD.M={program.payload.mass:.3f}",
                f"  $LOAD.CM={{X {x:.3f},Y {y:.3f},Z {z:.3f},A 0.0,B 0.0,C 0.0}}"]
    return out


#: The lines at a measurement pose (:class:`~calib_oed.program.format_common.MeasureWords`).
MEASURE = MeasureWords("  WAIT SEC {dwell:.2f} ; measure pose {pose}", "  {ROUTINE}( ) ; measure pose {pose}",
                       ("  $OUT[{output}]=TRUE ; measure pose {pose}", "  WAIT FOR $IN[{input}]",
                        "  $OUT[{output}]=FALSE"))


def write_krl(program: Program, name: str) -> dict[str, str]:
    """``{name.src: text, name.dat: text}``; ``name`` is the KRL module name."""
    require_six_axes(program, "krl")
    module = check_module_name(name)
    all_steps = steps(program)
    src = ["&ACCESS RVP", "&REL 1", f"DEF {module}( )"]
    src += [f"; {line}" for line in header_lines(program, "degrees (A1..A6)")]
    src += ["  GLOBAL INTERRUPT DECL 3 WHEN $STOPMESS==TRUE DO IR_STOPM ( )", "  INTERRUPT ON 3",
            "  BAS (#INITMOV,0 )", *_declarations(program), "  $VEL_AXIS[1]=100", "  $VEL_AXIS[2]=100", "  $VEL_AXIS[3]=100",
            "  $VEL_AXIS[4]=100", "  $VEL_AXIS[5]=100", "  $VEL_AXIS[6]=100"]
    for step in all_steps:
        what = {"home": "home", "via": "via point (no measurement)"}.get(step.kind, f"pose {step.pose}")
        src.append(f"  PTP {TARGET_PREFIX}{step.name} ; {what}")
        if step.kind == "pose":
            src += MEASURE.compute_lines(program, step.pose)
    src.append("END")
    dat = ["&ACCESS RVP", "&REL 1", f"DEFDAT {module}"]
    seen = set()
    for step in all_steps:
        if step.name in seen:
            continue
        seen.add(step.name)
        axes = ",".join(f"A{i + 1} {v}" for i, v in enumerate(degrees(step.q)))
        dat.append(f"DECL E6AXIS {TARGET_PREFIX}{step.name}={{{axes},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}")
    dat.append("ENDDAT")
    return {f"{name}.src": "\n".join(src) + "\n", f"{name}.dat": "\n".join(dat) + "\n"}
