"""Compensated programs (issue 32): 1000 targets compensated in <= 2 s.

For fms_kr16 a simulated calibration (truth seed 1, 60 random poses) is written as
``identify -o`` writes it; then programs of N targets are compensated and timed: a KRL
module of N ``E6AXIS`` joint targets (the project's writer), a CSV of N Cartesian
targets (the nominal TCP there) and a KRL module of the same N poses as ``E6POS`` targets
with the status and turn of the configurations they were taught at (and the checks of
KUKA's status and turn); the configurations are a path, a random walk of 3 deg
steps per joint (reflected 5 deg inside the limits) from the scene's first working configuration, as consecutive targets of a
program are near each other (each Cartesian target is solved from the one before). Each is timed for the whole
``compensate`` work (read, parse, inverse kinematics, predicted residual, rewrite; not
the scene and calibration loading, which are timed apart), CPU and wall time, median and
best of ``--repeat`` runs of the same work (CPU time: the figure a shared machine does not
change much). It also reports how many targets were named and the
true TCP error after compensation on the well-conditioned ones against the prediction.

With ``--deflection`` the same follows, in the same run, for a calibration that identified joint
compliance (16 kg payload 0.1 m out on the tool) and every joint's gain (a simulated truth with
them), compensated with the joint deflection (``load_compensation``).

    .venv/bin/python bench/bench_compensate.py [-n 1000] [--repeat 3] [--deflection]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from calib_oed.calibration.compensation import calibrated_kinematics, calibrated_robot
from calib_oed.calibration.compensation_files import load_compensation
from calib_oed.calibration.export import export_calibration
from calib_oed.calibration.identification import identify
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.model.arm_configuration import compute_arm_configuration, kuka_status
from calib_oed.model.deflected_kinematics import JointDeflection
from calib_oed.model.inverse_kinematics import TcpKinematics
from calib_oed.program.compensate import compensate_program
from calib_oed.program.parse.files import read_program
from calib_oed.program.parse.poses import to_euler_mm_deg
from calib_oed.scene.reader import load_scene
from tests.calibration.test_compensation import deflecting_scene


def _krl(q_deg: np.ndarray) -> tuple[str, str]:
    src = ["DEF BENCH( )"] + [f"  PTP XP{i}" for i in range(len(q_deg))] + ["END"]
    dat = ["DEFDAT BENCH"] + [
        f"DECL E6AXIS XP{i}={{{','.join(f'A{k + 1} {v:.4f}' for k, v in enumerate(row))},E1 0.0,E2 0.0,"
        "E3 0.0,E4 0.0,E5 0.0,E6 0.0}" for i, row in enumerate(q_deg)] + ["ENDDAT"]
    return "\n".join(src) + "\n", "\n".join(dat) + "\n"


def _krl_poses(poses, status, turn) -> tuple[str, str]:
    """A KRL module of Cartesian E6POS targets (A, B, C = rz, ry, rx of R = Rz Ry Rx), S/T as taught."""
    src = ["DEF BENCHP( )"] + [f"  LIN XC{i}" for i in range(len(poses))] + ["END"]
    dat = ["DEFDAT BENCHP"]
    for i, m in enumerate(poses):
        xyz, (rx, ry, rz) = to_euler_mm_deg(m)
        dat.append(f"DECL E6POS XC{i}={{X {xyz[0]:.4f},Y {xyz[1]:.4f},Z {xyz[2]:.4f},A {rz:.4f},B {ry:.4f},"
                   f"C {rx:.4f},S {status[i]},T {turn[i]},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}")
    return "\n".join(src) + "\n", "\n".join(dat + ["ENDDAT"]) + "\n"


def _csv(poses) -> str:
    lines = ["name,x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg"]
    for i, m in enumerate(poses):
        xyz, rpy = to_euler_mm_deg(m)
        lines.append(f"t{i}," + ",".join(f"{v:.4f}" for v in (*xyz, *rpy)))
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--deflection", action="store_true", help="also (after the rigid calibration, in the same "
                    "run) a calibration with joint compliance (16 kg) and joint gains, compensated with them")
    args = ap.parse_args()
    for deflected in (False, True) if args.deflection else (False,):
        run(args, deflected)


def run(args, deflected: bool) -> None:
    """Time the three programs for a rigid calibration or one with joint compliance and gains."""
    scene = deflecting_scene() if deflected else load_scene("fms_kr16")
    problem = CalibrationProblem.from_scene(scene)
    space, robot = problem.space, scene.robot
    rng = np.random.default_rng(1)
    p_true = draw_true_parameters(space, problem.identifiability.free_indices, rng)
    blocks = simulate_observations(space, problem.models, robot.random_configurations(60, 0), p_true, rng)
    result = identify(space, blocks, problem.identifiability)
    steps = np.random.default_rng(2).normal(scale=np.radians(3.0), size=(args.n, robot.nq))
    lo, hi = robot.lower + np.radians(5.0), robot.upper - np.radians(5.0)
    walk = problem.kpi.configurations[0] + np.cumsum(steps, axis=0) - lo
    span = hi - lo                                      # reflected at 5 deg inside the limits
    q = lo + span - np.abs(np.mod(walk, 2 * span) - span)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        export_calibration(space, result.p, folder)
        (folder / "identification.json").write_text(json.dumps(result.to_dict()))
        t0 = time.perf_counter()
        loaded = load_compensation(space, folder)
        calibrated, unc = loaded.robot, loaded.uncertainty
        load_s = time.perf_counter() - t0
        src, dat = _krl(np.degrees(q))
        (folder / "bench.src").write_text(src)
        (folder / "bench.dat").write_text(dat)
        nominal = TcpKinematics(robot)
        poses = [nominal.compute_pose(row) for row in q]
        (folder / "bench.csv").write_text(_csv(poses))
        src, dat = _krl_poses(poses, *kuka_status(compute_arm_configuration(robot, q)))
        (folder / "benchp.src").write_text(src)
        (folder / "benchp.dat").write_text(dat)
        truth = calibrated_kinematics(calibrated_robot(space, p_true), JointDeflection.from_space(space, p_true))
        print(f"fms_kr16, {args.n} targets, {'joint compliance and gains' if deflected else 'rigid'} calibration; "
              f"loaded in {load_s:.2f} s (shared 2-core machine)")
        for label, path in (("KRL joint targets", "bench.src"), ("CSV Cartesian targets", "bench.csv"),
                            ("KRL Cartesian targets (configuration checked)", "benchp.src")):
            times, cpu = [], []
            for _ in range(args.repeat):
                t0, c0 = time.perf_counter(), time.process_time()
                parsed, _ = read_program(folder / path, robot.joint_names)
                out = compensate_program(parsed, robot, calibrated, uncertainty=unc, home=problem.kpi.configurations[0],
                                         deflection=loaded.deflection)
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            c = out.compensation
            ok = ~c.flagged
            goal = np.array([nominal.compute_pose(row).translation for row in c.q_nominal])
            err = np.linalg.norm(np.array([truth.compute_pose(row).translation for row in c.q]) - goal, axis=1)
            before = np.linalg.norm(np.array([truth.compute_pose(row).translation for row in c.q_nominal]) - goal,
                                    axis=1)
            rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
            print(f"  {label}: CPU median {np.median(cpu):.2f} s (min {min(cpu):.2f}), wall median "
                  f"{np.median(times):.2f} s (min {min(times):.2f})")
            print(f"    named {int(c.flagged.sum())} of {c.n} (not converged {int((~c.converged).sum())}, near a "
                  f"singularity {int(c.near_singular.sum())}, outside the range {int((~c.in_range).sum())}); "
                  f"the others: true TCP error RMS {1e3 * rms(err[ok]):.4f} mm, predicted "
                  f"{rms(c.predicted_mm[ok]):.4f} mm, uncompensated {1e3 * rms(before[ok]):.3f} mm; "
                  f"controller configuration changed: {sum(bool(x) for x in out.configuration)}, "
                  f"declared S/T not the nominal solution's: {sum(bool(x) for x in out.branch)}")


if __name__ == "__main__":
    main()
