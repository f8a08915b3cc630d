"""Every program format parsed with a small grammar: the joint values, dwells and pose
comments round-trip (degrees to 1e-4 deg, URScript radians to 1e-6 rad)."""

from __future__ import annotations

import csv
import io
import re

import numpy as np
import pytest

from calib_oed.exceptions import ExportError, ProgramError
from calib_oed.program.continuous import MoveCheck
from calib_oed.program.fanuc_tp import J2_J3_NOTE
from calib_oed.program.format_common import header_lines, steps
from calib_oed.program.formats import FORMATS, program_texts, write_program
from calib_oed.program.records import Move, Program
from calib_oed.program.settings import Handshake

NUM = r"(-?\d+\.\d+)"
JOINTS = tuple(f"joint_a{i}" for i in range(1, 7))


@pytest.fixture(scope="module")
def program() -> Program:
    """Home, three poses (design rows 3, 1, 2 in that order), one move through two via points."""
    rng = np.random.default_rng(5)
    home = np.zeros(6)
    poses = rng.uniform(-2, 2, size=(3, 6))
    vias = rng.uniform(-2, 2, size=(2, 6))
    ok = MoveCheck(True, False, 3, 0.1, "self:a|b")
    nodes = [0, 3, 1, 2, 0]
    moves = []
    for a, b in zip(nodes[:-1], nodes[1:], strict=True):
        qa = home if a == 0 else poses[a - 1]
        qb = home if b == 0 else poses[b - 1]
        way = np.vstack([qa, vias, qb]) if (a, b) == (1, 2) else np.vstack([qa, qb])
        moves.append(Move(a, b, way, 1.0, ok))
    return Program("test", JOINTS, home, poses, np.array([2, 0, 1]), tuple(moves), 1.5,
                   {"design order": 20.0, "nearest neighbour": 12.0, "optimised": 10.0}, "lkh")


def _expected(program):
    return [(s.kind, s.q, s.pose) for s in steps(program)]


def _parse(lines, rules):
    """Match every non-empty line against one rule; return (rule name, groups) per line."""
    out = []
    for line in lines:
        if not line.strip():
            continue
        for name, rx in rules:
            m = re.fullmatch(rx, line)
            if m:
                out.append((name, m.groups()))
                break
        else:
            raise AssertionError(f"line not in the grammar: {line!r}")
    return out


def _kind(comment: str):
    if comment == "home":
        return "home", None
    if comment.startswith("via point"):
        return "via", None
    m = re.fullmatch(r"pose (\d+)", comment)
    assert m, comment
    return "pose", int(m.group(1))


def _check(parsed_steps, dwells, program, unit=np.rad2deg, tol=0.6e-4):
    exp = _expected(program)
    assert [(k, p) for k, _, p in parsed_steps] == [(k, p) for k, _, p in exp]
    for (_, q, _), (_, qe, _) in zip(parsed_steps, exp, strict=True):
        assert np.allclose(q, unit(qe), atol=tol, rtol=0)
    assert dwells == [(program.dwell, p) for k, _, p in exp if k == "pose"]


def test_krl(program):
    files = program_texts(program, "krl", "calib_program")
    dat = _parse(files["calib_program.dat"].splitlines(), [
        ("head", r"&ACCESS RVP|&REL 1|DEFDAT CALIB_PROGRAM|ENDDAT"),
        ("decl", r"DECL E6AXIS XCAL_(\w+)=\{" + ",".join(f"A{i} {NUM}" for i in range(1, 7))
         + r",E1 0\.0,E2 0\.0,E3 0\.0,E4 0\.0,E5 0\.0,E6 0\.0\}")])
    targets = {g[0]: np.array(g[1:], float) for name, g in dat if name == "decl"}
    src = _parse(files["calib_program.src"].splitlines(), [
        ("head", r"&ACCESS RVP|&REL 1|DEF CALIB_PROGRAM\( \)|END|  BAS \(#INITMOV,0 \)"
         r"|  GLOBAL INTERRUPT DECL 3 WHEN \$STOPMESS==TRUE DO IR_STOPM \( \)|  INTERRUPT ON 3"
         r"|  \$VEL_AXIS\[\d\]=100"),
        ("comment", r"; .*"),
        ("ptp", r"  PTP XCAL_(\w+) ; (.*)"),
        ("wait", r"  WAIT SEC " + NUM + r" ; measure pose (\d+)")])
    got = [(*_kind(g[1]), targets[g[0]]) for name, g in src if name == "ptp"]
    dwells = [(float(g[0]), int(g[1])) for name, g in src if name == "wait"]
    _check([(k, q, p) for k, p, q in got], dwells, program)
    assert "; joint values: URDF joint angles in degrees" in files["calib_program.src"]
    # no global name of the controller redefined; the stop-message interrupt before the first move
    assert "XHOME" not in files["calib_program.dat"].replace("XCAL_HOME", "")
    src_lines = files["calib_program.src"].splitlines()
    assert src_lines.index("  INTERRUPT ON 3") < src_lines.index("  BAS (#INITMOV,0 )") < min(
        i for i, line in enumerate(src_lines) if line.startswith("  PTP"))


def test_rapid(program):
    text = program_texts(program, "rapid", "CalibProgram")["CalibProgram.mod"]
    rows = _parse(text.splitlines(), [
        ("head", r"MODULE CalibProgram|ENDMODULE|  PROC CalibProgram_run\(\)|  ENDPROC"),
        ("comment", r"  ! .*"),
        ("target", r"  CONST jointtarget j(\w+):=\[\[" + ",".join([NUM] * 6)
         + r"\],\[9E9,9E9,9E9,9E9,9E9,9E9\]\];"),
        ("move", r"    MoveAbsJ j(\w+)\\NoEOffs, v1000(?:\\T:=" + NUM + r")?, fine, tool0; ! (.*)"),
        ("wait", r"    WaitTime " + NUM + r"; ! measure pose (\d+)")])
    targets = {g[0]: np.array(g[1:], float) for name, g in rows if name == "target"}
    got = [(*_kind(g[2]), targets[g[0]]) for name, g in rows if name == "move"]
    dwells = [(float(g[0]), int(g[1])) for name, g in rows if name == "wait"]
    _check([(k, q, p) for k, p, q in got], dwells, program)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # rapidchecker's own pyparsing calls
def test_rapid_passes_an_independent_checker(program):
    """rapidchecker (PyPI; a pyparsing grammar of RAPID and ABB's formatting rules): 0 findings,
    and it does find a missing comma (so the check can fail)."""
    from rapidchecker.cli import check_file

    text = program_texts(program, "rapid", "CalibProgram")["CalibProgram.mod"]
    assert [str(e) for e in check_file(text)] == []
    assert check_file(text.replace("\\NoEOffs, v1000", "\\NoEOffs v1000", 1))
    with pytest.raises(ProgramError, match="28"):
        program_texts(program, "rapid", "N" * 29)


def test_fanuc_tp(program):
    text = program_texts(program, "tp", "calib_program")["calib_program.ls"]
    head, rest = text.split("/MN\n")
    mn, pos = rest.split("/POS\n")
    assert head.startswith("/PROG  CALIB_PROGRAM\n")
    rows = _parse(mn.splitlines(), [
        ("move", r"\s*\d+:  J P\[(\d+):([^\]]*)\] 100% FINE ;"),
        ("wait", r"\s*\d+:  WAIT\s+" + NUM + r"\(sec\) ;"),
        ("measure", r"\s*\d+:  ! measure pose (\d+) ;"),
        ("comment", r"\s*\d+:  ! (.{1,30}) ;")])
    assert any("J2/J3" in g[0] for name, g in rows if name == "comment")
    # ';' ends a TP statement: each /MN line holds exactly one, its last character (the
    # header's own sentences have ';' in them, issue 31)
    assert all(line.count(";") == 1 and line.endswith(" ;") for line in mn.splitlines())
    assert any(";" in line for line in header_lines(program, "degrees (J1..J6)") + [J2_J3_NOTE])
    blocks = re.findall(r"P\[(\d+)\]\{\n   GP1:\n\tUF : 0, UT : 1,\n"
                        + r"\tJ1= {0} deg,\tJ2= {0} deg,\tJ3= {0} deg,\n\tJ4= {0} deg,\tJ5= {0} deg,"
                        r"\tJ6= {0} deg\n\};".replace("{0}", NUM), pos)
    positions = {int(b[0]): np.array(b[1:], float) for b in blocks}
    assert pos.rstrip().endswith("/END") and len(positions) == pos.count("GP1:")
    got = [(*_kind(g[1].replace("via point", "via point")), positions[int(g[0])])
           for name, g in rows if name == "move"]
    measured = [int(g[0]) for name, g in rows if name == "measure"]
    dwells = [(float(g[0]), p) for (name, g), p in zip([r for r in rows if r[0] == "wait"], measured,
                                                        strict=True)]
    _check([(k, q, p) for k, p, q in got], dwells, program)


def test_urscript(program):
    text = program_texts(program, "urscript", "calib_program")["calib_program.script"]
    rows = _parse(text.splitlines(), [
        ("head", r"def calib_program\(\):|end|calib_program\(\)"),
        ("what", r"  # (home|via point \(no measurement\)|pose \d+)"),
        ("comment", r"# .*"),
        ("move", r"  movej\(\[" + ", ".join([NUM] * 6) + r"\], a=" + NUM + ", v=" + NUM
         + r"(?:, t=" + NUM + r")?\)"),
        ("wait", r"  sleep\(" + NUM + r"\)  # measure pose (\d+)")])
    whats = [_kind(g[0]) for name, g in rows if name == "what"]
    qs = [np.array(g[:6], float) for name, g in rows if name == "move"]
    dwells = [(float(g[0]), int(g[1])) for name, g in rows if name == "wait"]
    _check([(k, q, p) for (k, p), q in zip(whats, qs, strict=True)], dwells, program,
           unit=lambda q: q, tol=0.6e-6)
    assert "radians" in text.splitlines()[1]


def test_csv(program):
    text = program_texts(program, "csv", "calib_program")["calib_program.csv"]
    body = [line for line in text.splitlines() if not line.startswith("#")]
    rows = list(csv.DictReader(io.StringIO("\n".join(body))))
    deg = np.array([[float(r[f"{j}_deg"]) for j in JOINTS] for r in rows])
    rad = np.array([[float(r[f"{j}_rad"]) for j in JOINTS] for r in rows])
    assert np.allclose(np.rad2deg(rad), deg, atol=0.6e-4, rtol=0)
    parsed = [(r["kind"], q, int(r["pose"]) if r["pose"] else None) for r, q in zip(rows, rad, strict=True)]
    dwells = [(float(r["dwell_s"]), int(r["pose"])) for r in rows if r["kind"] == "pose"]
    _check(parsed, dwells, program, unit=lambda q: q, tol=1e-10)


def test_errors_and_files(program, tmp_path):
    with pytest.raises(ProgramError, match="'krl', 'rapid', 'tp', 'urscript', 'csv'"):
        program_texts(program, "jbi")
    seven = Program("t", JOINTS + ("j7",), np.zeros(7), np.zeros((1, 7)), np.array([0]), (), 1.0,
                    program.cycle_times, "lkh")
    with pytest.raises(ProgramError, match="use the csv format"):
        program_texts(seven, "rapid")
    paths = write_program(program, "krl", tmp_path / "out")
    assert sorted(p.name for p in paths) == ["calib_program.dat", "calib_program.src"]
    assert set(FORMATS) == {"krl", "rapid", "tp", "urscript", "csv"}


def test_csv_reads_back_for_the_viewer(program, tmp_path):
    from calib_oed.program.csv_format import read_program_csv

    (path,) = write_program(program, "csv", tmp_path)
    back = read_program_csv(tmp_path, JOINTS)  # the folder: its one CSV
    expected = _expected(program)
    assert back.path == path and back.kinds == tuple(k for k, _, _ in expected)
    assert np.allclose(back.q, [q for _, q, _ in expected], rtol=0, atol=1e-10)
    assert back.poses.tolist() == [p or 0 for _, _, p in expected]
    assert back.dwell.tolist() == [program.dwell if k == "pose" else 0.0 for k, _, _ in expected]
    with pytest.raises(ProgramError, match="joint_a1_deg"):
        read_program_csv(path, ("a", "b", "c", "d", "e", "f"))
    write_program(program, "krl", tmp_path / "krl")
    with pytest.raises(ProgramError, match="--format csv"):
        read_program_csv(tmp_path / "krl", JOINTS)


def test_fanuc_tp_has_the_controller_written_layout(program):
    """The layout of .ls files a FANUC controller writes itself (`OWNER = MNEDITOR`; e.g.
    ros-industrial/fanuc, fanuc_driver/TPE/ros.ls): `/PROG  NAME` (two spaces), then `/ATTR`
    with `KEY<tabs>= value;` lines, `/MN` with numbered statements `<4-wide number>:` each
    ending in `;`, `/POS` and `/END` last, in that order and each once."""
    text = program_texts(program, "tp", "calib_program")["calib_program.ls"]
    lines = text.splitlines()
    sections = [line.split()[0] for line in lines if line.startswith("/")]
    assert sections == ["/PROG", "/ATTR", "/MN", "/POS", "/END"] and lines[-1] == "/END"
    assert re.fullmatch(r"/PROG  [A-Z][A-Z0-9_]*", lines[0])
    attr = lines[lines.index("/ATTR") + 1:lines.index("/MN")]
    assert attr and all(re.fullmatch(r"[A-Z_]+\t+= .*;", line) for line in attr)
    mn = lines[lines.index("/MN") + 1:lines.index("/POS")]
    numbers = [int(re.match(r"\s*(\d+):", line).group(1)) for line in mn]
    assert numbers == list(range(1, len(mn) + 1))
    assert all(re.match(r"[ \d]{4}:  \S", line) and line.endswith(" ;") for line in mn)


@pytest.fixture(scope="module")
def built_program(kr16_scene, kr16_poses) -> Program:
    """A program of fms_kr16 with the timing's joint limits (6 poses)."""
    from calib_oed.program.build import build_program

    return build_program(kr16_scene, kr16_poses[:6])


@pytest.mark.parametrize("fmt, pattern", [("rapid", r"\\T:=" + NUM), ("urscript", r", t=" + NUM + r"\)")])
def test_written_move_times_are_the_estimate(built_program, fmt, pattern):
    """RAPID's \\T and URScript's t hold each move's estimated time, so the cycle the controller
    runs is the estimated one: written move times + dwells within 0.1 % of the estimate (issue 31's
    target: 5 %). Every move but the first (from wherever the robot stands) has one."""
    program = built_program
    text = next(iter(program_texts(program, fmt, "CalibProgram").values()))
    times = [float(t) for t in re.findall(pattern, text)]
    assert len(times) == len(steps(program)) - 1
    written = sum(times) + program.dwell * len(program.order)
    assert written == pytest.approx(program.cycle_times["optimised"], rel=1e-3)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # rapidchecker's own pyparsing calls
@pytest.mark.parametrize("handshake, expected", [
    (Handshake(output=3, input=4), {"krl": ["  $OUT[3]=TRUE ; measure pose {p}", "  WAIT FOR $IN[4]", "  $OUT[3]=FALSE"],
                                    "rapid": ["    SetDO do3, 1; ! measure pose {p}", "    WaitDI di4, 1;",
                                              "    SetDO do3, 0;"],
                                    "tp": ["DO[3]=ON ;", "WAIT DI[4]=ON ;", "DO[3]=OFF ;"],
                                    "urscript": ["  set_standard_digital_out(3, True)  # measure pose {p}",
                                                 "  while not get_standard_digital_in(4):", "    sync()", "  end",
                                                 "  set_standard_digital_out(3, False)"]}),
    (Handshake(routine="TrackerMeasure"), {"krl": ["  TRACKERMEASURE( ) ; measure pose {p}"],
                                           "rapid": ["    TrackerMeasure; ! measure pose {p}"],
                                           "tp": ["CALL TRACKERMEASURE ;"],
                                           "urscript": ["  TrackerMeasure()  # measure pose {p}"]}),
])
def test_handshake_replaces_the_dwell(program, handshake, expected):
    """After every measurement pose (in the tour's order) the handshake's lines, and no dwell."""
    import dataclasses

    from rapidchecker.cli import check_file

    prog = dataclasses.replace(program, handshake=handshake)
    poses = [s.pose for s in steps(prog) if s.kind == "pose"]
    for fmt, block in expected.items():
        files = program_texts(prog, fmt, "CalibProgram")
        text = files.get("CalibProgram.src") or next(iter(files.values()))
        lines = [re.sub(r"^\s*\d+:  ", "", line) if fmt == "tp" else line for line in text.splitlines()]
        assert not any(w in text for w in ("WAIT SEC", "WaitTime", "(sec)", "sleep("))
        stripped = [line.strip() for line in lines]
        for p in poses:
            want = [line.format(p=p).strip() for line in block]
            assert any(stripped[i:i + len(want)] == want for i in range(len(lines))), (fmt, p, want)
        assert "handshake" in text
        if fmt == "rapid":
            assert [str(e) for e in check_file(text)] == []


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # rapidchecker's own pyparsing calls
def test_tool_base_and_payload_are_declared(program):
    """program.tool/.base/.payload reach every format, and their values read back (mm, deg, kg)."""
    import dataclasses

    import pinocchio as pin
    from rapidchecker.cli import check_file

    from calib_oed.program.settings import FrameSpec, PayloadSpec

    tool = FrameSpec(2, np.array([0.01, -0.02, 0.05]), np.array([0.3, -0.2, 0.1]))
    base = FrameSpec(3, np.array([1.0, 0.5, 0.0]), np.array([0.0, 0.0, 0.5]))
    prog = dataclasses.replace(program, tool=tool, base=base,
                               payload=PayloadSpec(1.5, np.array([0.0, 0.0, 0.03]), 4))
    rot = pin.rpy.rpyToMatrix(*tool.rpy)
    krl = program_texts(prog, "krl", "cp")["cp.src"]
    m = re.search(r"\$TOOL=\{X {0},Y {0},Z {0},A {0},B {0},C {0}\}".replace("{0}", NUM), krl)
    x, y, z, a, b, c = (float(v) for v in m.groups())
    assert np.allclose([x, y, z], 1e3 * tool.xyz) and np.allclose(
        pin.rpy.rpyToMatrix(*np.deg2rad([c, b, a])), rot, atol=1e-6)
    assert "$LOAD.M=1.500" in krl and "$BASE={X 1000.000,Y 500.000" in krl
    assert krl.index("BAS (#INITMOV,0 )") < krl.index("$TOOL=") < krl.index("PTP")
    rapid = program_texts(prog, "rapid", "cp")["cp.mod"]
    assert [str(e) for e in check_file(rapid)] == []
    q = [float(v) for v in re.search(r"PERS tooldata tcp:=\[TRUE,\[\[[^]]*\],\[" + ",".join([NUM] * 4), rapid).groups()]
    assert np.allclose(pin.Quaternion(q[0], q[1], q[2], q[3]).toRotationMatrix(), rot, atol=1e-5)
    assert all(line.endswith("tcp\\WObj:=wcp; ! " + line.split("! ")[-1]) for line in rapid.splitlines()
               if "MoveAbsJ" in line)
    tp = program_texts(prog, "tp", "cp")["cp.ls"]
    assert "UFRAME_NUM=3 ;" in tp and "UTOOL_NUM=2 ;" in tp and "PAYLOAD[4] ;" in tp
    assert tp.count("UF : 3, UT : 2,") == tp.count("GP1:")
    ur = program_texts(prog, "urscript", "cp")["cp.script"]
    tcp = [float(v) for v in re.search(r"set_tcp\(p\[" + ", ".join([NUM] * 6) + r"\]\)", ur).groups()]
    assert np.allclose(tcp[:3], tool.xyz) and np.allclose(pin.exp3(np.array(tcp[3:])), rot, atol=1e-5)
    assert "set_payload(1.500, [0.000000, 0.000000, 0.030000])" in ur
    with pytest.raises(ProgramError, match="mass > 0"):
        program_texts(dataclasses.replace(prog, payload=None), "rapid", "cp")


def test_krl_pair_is_written_as_one(program, tmp_path):
    """A KRL .src and its .dat appear together or not at all: a .dat that cannot be written
    (a folder of its name) leaves no .src and no temporary file behind."""
    names = list(program_texts(program, "krl"))
    assert len(names) == 2
    (tmp_path / names[-1]).mkdir()                       # the file written last cannot be written
    with pytest.raises(ExportError, match=names[-1]):
        write_program(program, "krl", tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [names[-1]]     # no .src, no temporary file
    assert (tmp_path / names[-1]).is_dir()
