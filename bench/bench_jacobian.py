"""Benchmark: the weighted sensitivity matrix F1 for 60 poses, analytic vs finite differences.

Run from the repository root:

    .venv/bin/python bench/bench_jacobian.py [--poses 60] [--repeat 7]

Both methods run side by side in one process on the same configurations; the
ratio is the result (a lone time depends on the machine). Results and the
command are recorded in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import functools
import platform

import numpy as np
import pinocchio as pin
from _timing import timed  # bench/ is the script folder, first on sys.path

from calib_oed import load_robot
from calib_oed.measurement import TrackerPosition, evaluate_setup
from calib_oed.measurement.sensitivity import stacked_values, weighted_jacobian
from calib_oed.model.parameters import ParameterSpace


def finite_difference_f1(space, models, q, eps=1e-6):
    """Central differences of Sigma^-1 h over every parameter (2 n_p model evaluations)."""
    sigma = np.concatenate([np.tile(m.sigma, len(q)) for m in models])
    p0 = space.zeros()
    cols = []
    for k in range(space.size):
        dp = np.zeros(space.size)
        dp[k] = eps
        plus = stacked_values(models, evaluate_setup(space, p0 + dp, q, jacobian=False))
        minus = stacked_values(models, evaluate_setup(space, p0 - dp, q, jacobian=False))
        cols.append((plus - minus) / (2 * eps) / sigma)
    return np.column_stack(cols)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    print(f"python {platform.python_version()}, pinocchio {pin.__version__}, "
          f"numpy {np.__version__}, {platform.machine()}, {args.poses} poses, "
          f"best of {args.repeat} samples (analytic: 50 calls per sample)")
    print()
    print("| robot | n_p | analytic F1 [ms] | central FD F1 [ms] | FD / analytic | max rel. diff |")
    print("|---|---|---|---|---|---|")
    for name in ("kr16", "ur5"):
        robot = load_robot(name)
        tracker = pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.17, 1.57), np.array([0.6, -2.6, 1.3]))
        space = ParameterSpace(robot, tracker, np.array([[0.0, 0.0, 0.05]]))
        models = [TrackerPosition(0, 1e-5)]
        q = robot.random_configurations(args.poses, 0)
        weighted_jacobian(space, models, q)  # warm-up
        analytic = functools.partial(weighted_jacobian, space, models, q)
        numeric = functools.partial(finite_difference_f1, space, models, q)
        t_an, f_an = timed(analytic, args.repeat, number=50)
        t_fd, f_fd = timed(numeric, args.repeat, number=1)
        diff = np.abs(f_an - f_fd).max() / np.abs(f_an).max()
        print(f"| {name} | {space.size} | {t_an * 1e3:.3f} | {t_fd * 1e3:.1f} | "
              f"{t_fd / t_an:.0f}x | {diff:.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
