"""Compensated programs: only the target numbers change, and the calibrated robot reaches the targets.

For every language, programs written by the project's writers and by hand (vendor style,
tests/program/parse/samples.py) are compensated against a perturbed kr16 (0.5 mm, 0.5 mrad).
Checks: (1) putting the original numbers back and dropping the added comment lines gives the
input byte for byte; (2) the calibrated robot at the new joint targets is where the nominal
robot was at the old ones, and the nominal controller's inverse kinematics of a new Cartesian
target (seeded at the nominal solution) is a configuration where the calibrated robot reaches
the original target; both to the rounding of the written numbers.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import random_parameters

from calib_oed import load_robot
from calib_oed.calibration.compensation import calibrated_robot
from calib_oed.exceptions import ProgramError
from calib_oed.model.inverse_kinematics import IkSettings, TcpKinematics
from calib_oed.model.parameters import ParameterSpace
from calib_oed.program.compensate import compensate_program
from calib_oed.program.continuous import MoveCheck
from calib_oed.program.formats import program_texts
from calib_oed.program.parse import csv_targets, fanuc_tp, krl, rapid, urscript
from calib_oed.program.parse.poses import from_euler_mm_deg
from calib_oed.program.records import Move, Program
from tests.program.parse import samples

PARSERS = {"krl": krl.parse, "rapid": rapid.parse, "tp": fanuc_tp.parse, "urscript": urscript.parse}
TOOL = from_euler_mm_deg(12.5, 0.0, 180.0, 0.0, 0.0, 0.0)
BASE = from_euler_mm_deg(1000.0, -200.0, 0.0, 0.0, 0.0, 90.0)
COMMENT_MARK = {"krl": "; calib_oed:", "rapid": "! calib_oed:", "urscript": "# calib_oed:", "csv": "# calib_oed:"}


@pytest.fixture(scope="module")
def robots():
    out = {}
    for name in ("kr16", "ur5"):
        robot = load_robot(name)
        space = ParameterSpace(robot, pin.SE3.Identity(), np.zeros((1, 3)))
        out[name] = (robot, calibrated_robot(space, random_parameters(space, 7)))
    return out


def _parse(lang, texts, robot):
    return csv_targets.parse(texts, robot.joint_names) if lang == "csv" else PARSERS[lang](texts)


def _writer_program(robot) -> Program:
    home = np.radians([0.0, -90.0, 90.0, 0.0, 30.0, 0.0])
    poses = np.radians([[10, -80, 95, 0, 30, 0], [20, -70, 100, 15, 50, -30], [-15, -100, 110, -20, 40, 60]])
    ok = MoveCheck(True, False, 3, 0.1, "self:a|b")
    nodes = [0, 1, 2, 3, 0]
    moves = tuple(Move(a, b, np.vstack([home if a == 0 else poses[a - 1], home if b == 0 else poses[b - 1]]),
                       1.0, ok) for a, b in zip(nodes[:-1], nodes[1:], strict=True))
    return Program("test", robot.joint_names, home, poses, np.arange(3), moves, 1.5,
                   {"design order": 20.0, "nearest neighbour": 12.0, "optimised": 10.0}, "lkh")


def _check_bytes(lang, parsed, result):
    """Original numbers back, added comments out: the input, byte for byte."""
    again = _parse(lang, result.texts, parsed_robot[0])
    assert [t.kind for t in again.targets] == [t.kind for t in parsed.targets]
    for name, text in result.texts.items():
        for new, old in sorted(((n, o) for a, b in zip(again.targets, parsed.targets, strict=True)
                                if a.file == name for n, o in zip(a.numbers, b.numbers, strict=True)),
                               key=lambda e: -e[0].start):
            text = text[: new.start] + old.text + text[new.end:]
        if lang == "tp":
            lines = text.splitlines(keepends=True)
            added = [ln for ln in lines if ln.strip().split(":", 1)[-1].strip().startswith("!")
                     and ln not in parsed.texts[name]]
            assert all(len(ln.split(":", 1)[1].strip()) <= 34 and ";" not in ln.split("!", 1)[1][:-3]
                       for ln in added)
            text = "".join(ln for ln in lines if ln not in added)
            text = text.replace(f"LINE_COUNT\t= {5 + len(added)};", "LINE_COUNT\t= 5;")
        else:
            text = "".join(ln for ln in text.splitlines(keepends=True)
                           if not ln.lstrip().startswith(COMMENT_MARK[lang]))
        assert text == parsed.texts[name]


parsed_robot = [None]


def _check_reached(lang, parsed, result, robot, cal, tool, base, tol=2e-5):
    again = _parse(lang, result.texts, robot)
    nom, calk = TcpKinematics(robot, tool), TcpKinematics(cal, tool)
    comp = result.compensation
    for i, (old, new) in enumerate(zip(parsed.targets, again.targets, strict=True)):
        assert result.changed[i]
        if old.kind == "joint":
            unit = old.unit or parsed.language.joint_unit
            q_old, q_new = old.values[:robot.nq], new.values[:robot.nq]
            if unit == "deg":
                q_old, q_new = np.radians(q_old), np.radians(q_new)
            goal = nom.compute_pose(q_old)
            reached = calk.compute_pose(q_new)
        else:
            goal = base * parsed.language.pose_from(old.values)
            commanded = base * parsed.language.pose_from(new.values)
            q_ctrl, err, _, _ = nom.solve(commanded, comp.q_nominal[i], IkSettings())
            assert err < 1e-10
            assert np.abs(q_ctrl - comp.q[i]).max() < 1e-3       # the controller lands on q-hat's branch
            reached = calk.compute_pose(q_ctrl)
        assert np.linalg.norm(reached.translation - goal.translation) < tol, (lang, old.name)
        assert np.linalg.norm(pin.log3(reached.rotation.T @ goal.rotation)) < tol, (lang, old.name)
    shift = result.shift_mm
    assert np.all(shift > 0.05)                                 # the correction is not nothing


@pytest.mark.parametrize("lang", ["krl", "rapid", "tp", "urscript", "csv"])
def test_project_writer_programs(lang, robots):
    robot, cal = robots["kr16"]
    parsed_robot[0] = robot
    texts = program_texts(_writer_program(robot), lang)
    parsed = _parse(lang, texts, robot)
    assert sum(t.kind == "joint" for t in parsed.targets) >= 4
    result = compensate_program(parsed, robot, cal)
    _check_bytes(lang, parsed, result)
    _check_reached(lang, parsed, result, robot, cal, pin.SE3.Identity(), pin.SE3.Identity())


@pytest.mark.parametrize("lang, texts, given", [
    ("krl", {"weld_demo.src": samples.KRL_SRC, "weld_demo.dat": samples.KRL_DAT}, False),
    ("rapid", {"WeldDemo.mod": samples.RAPID_MOD}, False),
    ("tp", {"WELD_DEMO.ls": samples.TP_LS}, True),
    ("csv", {"path.csv": samples.CSV_POSES}, True),
])
def test_vendor_programs_with_cartesian_targets(lang, texts, given, robots):
    robot, cal = robots["kr16"]
    parsed_robot[0] = robot
    parsed = _parse(lang, texts, robot)
    assert {t.kind for t in parsed.targets} >= {"pose"}
    if not given:                                               # the file declares tool and base
        assert np.allclose(parsed.tool.homogeneous, TOOL.homogeneous, atol=1e-9)
        assert np.allclose(parsed.base.homogeneous, BASE.homogeneous, atol=1e-9)
    home = np.radians([10.0, -80.0, 95.0, 0.0, 30.0, 0.0])
    result = compensate_program(parsed, robot, cal, tool=TOOL if given else None, base=BASE if given else None,
                                home=home)
    assert result.sources["tool"] == ("given" if given else "file")
    _check_bytes(lang, parsed, result)
    _check_reached(lang, parsed, result, robot, cal, TOOL, BASE)


def test_urscript_with_tcp_variables_and_poses(robots):
    robot, cal = robots["ur5"]
    parsed_robot[0] = robot
    parsed = urscript.parse({"pick_demo.script": samples.UR_SCRIPT})
    assert [t.name for t in parsed.targets] == ["home", "approach", "line 6", "line 8"]
    assert [t.kind for t in parsed.targets] == ["joint", "pose", "joint", "pose"]
    tool = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.15]))
    assert np.allclose(parsed.tool.homogeneous, tool.homogeneous)
    result = compensate_program(parsed, robot, cal, home=np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.4]))
    _check_bytes("urscript", parsed, result)
    _check_reached("urscript", parsed, result, robot, cal, tool, pin.SE3.Identity(), tol=5e-6)


def test_controller_joint_values_fanuc_j2_j3(robots):
    """A TP program in FANUC joint values (J3 from the horizontal: q3 = J3 + J2, a sign flip on J1):
    mapped to URDF angles, compensated, mapped back."""
    from dataclasses import replace

    from calib_oed.model.controller import controller_from_mapping

    robot, cal = robots["kr16"]
    ctrl = controller_from_mapping({"name": "fanuc", "angle": "deg", "joints": [{"sign": -1}] + [{}] * 5,
                                    "couplings": [{"joint": 3, "from": 2, "ratio": 1}]}, 6)
    program = replace(_writer_program(robot), controller=ctrl)
    texts = program_texts(program, "tp")
    parsed = fanuc_tp.parse(texts)
    result = compensate_program(parsed, robot, cal, controller=ctrl)
    again = fanuc_tp.parse(result.texts)
    nom, calk = TcpKinematics(robot), TcpKinematics(cal)
    for old, new in zip(parsed.targets, again.targets, strict=True):
        q_old = ctrl.to_model(np.radians(old.values))
        q_new = ctrl.to_model(np.radians(new.values))
        assert abs(q_old[2] - np.radians(old.values[2] + old.values[1])) < 1e-12      # the coupling is applied
        goal, reached = nom.compute_pose(q_old), calk.compute_pose(q_new)
        assert np.linalg.norm(reached.translation - goal.translation) < 2e-5


def test_a_target_the_robot_cannot_reach_is_left_as_written_and_named(robots):
    robot, cal = robots["kr16"]
    text = samples.CSV_POSES + "far,5000.0,0.0,0.0,0.0,0.0,0.0\n"
    parsed = csv_targets.parse({"p.csv": text}, robot.joint_names)
    result = compensate_program(parsed, robot, cal, tool=TOOL, base=BASE,
                                home=np.radians([10.0, -80.0, 95.0, 0.0, 30.0, 0.0]))
    assert not result.changed[-1] and result.changed[:-1].all()
    assert result.texts["p.csv"].splitlines()[-2] == "far,5000.0,0.0,0.0,0.0,0.0,0.0"
    assert "NOT compensated" in result.texts["p.csv"].splitlines()[-1]
    assert any(line.startswith("far:") and "left as written" in line for line in result.issues())


def test_a_krl_target_is_solved_on_its_declared_elbow_and_wrist():
    """Two KRL targets of one pose: the first taught on one elbow, the second declared (S, T) on the
    other elbow and wrist; the nominal solution next to the first is the first's, so without S/T the second
    would be compensated on the wrong branch. With them it is solved on its own and nothing is named."""
    from calib_oed.calibration.compensation import calibrated_robot
    from calib_oed.calibration.problem import CalibrationProblem
    from calib_oed.model.arm_configuration import ConfigurationKinematics, kuka_status
    from calib_oed.model.inverse_kinematics import IkSettings, TcpKinematics
    from calib_oed.program.compensate import compensate_program
    from calib_oed.program.parse import krl
    from calib_oed.program.parse.poses import to_euler_mm_deg
    from calib_oed.scene.reader import load_scene

    scene = load_scene("fms_kr16")
    space = CalibrationProblem.from_scene(scene).space
    robot, nom = scene.robot, TcpKinematics(scene.robot)
    arm = ConfigurationKinematics(robot)
    q_up = np.radians([20, -70, 10, 15, 50, -30])       # A3 13 deg past the stretched arm
    pose = nom.compute_pose(q_up)
    q_other, err, _, _ = nom.solve(pose, arm.compute_elbow_flip(q_up), IkSettings())
    q_other[3], q_other[4], q_other[5] = q_other[3] + np.pi, -q_other[4], q_other[5] - np.pi    # and the wrist
    assert err < 1e-11 and np.allclose(nom.compute_pose(q_other).homogeneous, pose.homogeneous, atol=1e-9)
    assert np.all((q_other > robot.lower) & (q_other < robot.upper))
    (s1, s2), (t1, t2) = kuka_status(arm.compute(np.stack([q_up, q_other])))
    assert s1 != s2
    xyz, (rx, ry, rz) = to_euler_mm_deg(pose)
    values = f"X {xyz[0]:.6f},Y {xyz[1]:.6f},Z {xyz[2]:.6f},A {rz:.6f},B {ry:.6f},C {rx:.6f}"
    dat = (f"DEFDAT P\nDECL E6POS XA={{{values},S {s1},T {t1}}}\nDECL E6POS XB={{{values},S {s2},T {t2}}}\n"
           "ENDDAT\n")
    parsed = krl.parse({"p.dat": dat})
    out = compensate_program(parsed, robot, calibrated_robot(space, space.zeros()), home=q_up)
    assert np.allclose(out.compensation.q_nominal, np.stack([q_up, q_other]), atol=1e-6)
    assert not any(out.branch) and out.issues() == []


def test_a_failed_target_does_not_seed_the_next(robots, monkeypatch):
    """The inverse kinematics of the target after an unreachable one starts from the last
    target that was found, not from where the failed solve stopped."""
    robot, cal = robots["kr16"]
    text = samples.CSV_POSES + "far,5000.0,0.0,0.0,0.0,0.0,0.0\nc,-237.6,-18.8,620.4,-173.08,14.24,49.54\n"
    parsed = csv_targets.parse({"p.csv": text}, robot.joint_names)
    seeds, solve = [], TcpKinematics.solve

    def spy(self, goal, seed, settings):
        seeds.append(np.array(seed, float))
        return solve(self, goal, seed, settings)

    monkeypatch.setattr(TcpKinematics, "solve", spy)
    result = compensate_program(parsed, robot, cal, tool=TOOL, base=BASE,
                                home=np.radians([10.0, -80.0, 95.0, 0.0, 30.0, 0.0]))
    assert result.changed.tolist() == [True, True, False, True]
    q0 = result.compensation.q_nominal
    assert np.abs(q0[2] - q0[1]).max() > 1e-3                  # the failed solve moved away from b
    np.testing.assert_array_equal(seeds[3], q0[1])


def test_both_points_of_a_circular_move_are_compensated(robots):
    """KRL CIRC {via},{end}: the via and the end point are each rewritten so the calibrated robot
    reaches them (the end point is not left as written)."""
    robot, cal = robots["kr16"]
    parsed_robot[0] = robot
    src = samples.KRL_SRC.replace("LIN {X -237.6", "CIRC {X -16.4,Y -227.4,Z 889.6,A 80.0,B 45.0,C 180.0,"
                                  "S 6,T 50},{X -237.6")
    parsed = krl.parse({"weld_demo.src": src, "weld_demo.dat": samples.KRL_DAT})
    assert [t.name for t in parsed.targets][-2:] == ["weld_demo.src line 18 (via)", "weld_demo.src line 18 (end)"]
    result = compensate_program(parsed, robot, cal, home=np.radians([10.0, -80.0, 95.0, 0.0, 30.0, 0.0]))
    _check_bytes("krl", parsed, result)
    _check_reached("krl", parsed, result, robot, cal, TOOL, BASE)


def test_a_target_compensated_beyond_a_joint_limit_is_named_as_such(robots):
    """A joint target at the robot's limit may be corrected past it: the controller would refuse
    it, and the program says so (not only "outside the calibrated range")."""
    robot, cal = robots["kr16"]
    rows = []
    for j in range(6):
        for limit in (robot.lower, robot.upper):
            q = (robot.lower + robot.upper) / 2
            q[j] = limit[j]
            rows.append(q)
    text = "step," + ",".join(f"{j}_rad" for j in robot.joint_names) + "\n" + "".join(
        f"{k + 1}," + ",".join(f"{v:.12f}" for v in q) + "\n" for k, q in enumerate(rows))
    result = compensate_program(csv_targets.parse({"p.csv": text}, robot.joint_names), robot, cal)
    beyond = [(i, line) for i, line in enumerate(result.limits) if line]
    assert beyond  # some correction crosses a limit (the joint offsets of a random calibration)
    for i, line in beyond:
        q = result.compensation.q[i]
        assert np.any((q < robot.lower) | (q > robot.upper)) and "the controller refuses this target" in line
        assert any(f"{i + 1}: " in issue and "beyond the robot's joint limits" in issue for issue in result.issues())
    inside = [i for i, line in enumerate(result.limits) if not line and result.changed[i]]  # compensated ones
    q_in = result.compensation.q[inside]
    assert np.all((q_in >= robot.lower - 1e-12) & (q_in <= robot.upper + 1e-12))
    assert result.to_dict()["targets"][beyond[0][0]]["beyond_joint_limits"] == beyond[0][1]


def test_a_program_calib_oed_wrote_is_checked_against_the_scene(tmp_path):
    """The header names the joints and the convention: another robot's program, or controller values
    read as URDF angles (or the reverse), are refused instead of moving the robot elsewhere."""
    from calib_oed.model.controller import controller_from_mapping
    from calib_oed.program.compensate import check_written_for
    from calib_oed.program.parse.files import read_program

    JOINTS = tuple(f"joint_a{i}" for i in range(1, 7))

    def program(convention):
        path = tmp_path / "p.script"
        path.write_text(f"# calib_oed measurement program, scene s: 1 poses\n# joint values: {convention}\n"
                        "movej([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])\n")
        return read_program(path, JOINTS)[0]

    urdf = program(f"URDF joint angles in radians, in the order {', '.join(JOINTS)}")
    ctrl = program(f"controller joint values in radians, in the order {', '.join(JOINTS)}\n"
                   "# from the URDF angles q by the scene's controller kuka (q = A c + b: identity)")
    kuka, fanuc = controller_from_mapping({"name": "kuka"}, 6), controller_from_mapping({"name": "fanuc"}, 6)
    check_written_for(urdf, JOINTS, None)
    with pytest.raises(ProgramError, match="written for a robot with the joints joint_a1, .*not this scene's"):
        check_written_for(urdf, tuple(f"j{i}" for i in range(6)), None)
    with pytest.raises(ProgramError, match="those of controller kuka, and this scene has no controller"):
        check_written_for(ctrl, JOINTS, None)
    check_written_for(ctrl, JOINTS, kuka)
    with pytest.raises(ProgramError, match="URDF joint angles, and this scene's controller kuka"):
        check_written_for(urdf, JOINTS, kuka)
    with pytest.raises(ProgramError, match="those of controller kuka, not of this scene's controller fanuc"):
        check_written_for(ctrl, JOINTS, fanuc)
    unmarked = tmp_path / "q.script"
    unmarked.write_text("movej([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])\n")
    check_written_for(read_program(unmarked, JOINTS)[0], ("a", "b", "c", "d", "e", "f"), None)  # not ours: unchecked
