"""The ``calib-oed`` command.

Exit codes: 0 success; 1 internal error (a bug: please report it with
``--debug`` output); 2 bad input (the message says what to fix).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import traceback

from calib_oed.exceptions import CalibOedError

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2

DEFAULT_SCENE = "fms_kr16"


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text}")
    return value


def _problem(scene_ref: str):
    from calib_oed.problem import CalibrationProblem
    from calib_oed.scene import load_scene

    scene = load_scene(scene_ref)
    return scene, CalibrationProblem.from_scene(scene)


def cmd_identifiability(args) -> int:
    from calib_oed.report import format_identifiability, identifiability_dict

    scene, problem = _problem(args.scene)
    report = problem.identifiability
    est = problem.kpi_estimability()
    if args.json:
        data = identifiability_dict(problem, report, est)
        data["scene"] = scene.name
        print(json.dumps(data, indent=2))
    else:
        print(format_identifiability(problem, report, est, title=f"scene {scene.name!r}"))
    return EXIT_OK


def cmd_demo(args) -> int:
    from calib_oed.report import format_identifiability, format_kpi_sigma

    scene, problem = _problem(args.scene)
    q = problem.robot.random_configurations(args.n, args.seed)
    sigma = problem.kpi_sigma(q)
    print(format_identifiability(problem, problem.identifiability, problem.kpi_estimability(),
                                 title=f"scene {scene.name!r}"))
    print()
    print(format_kpi_sigma(
        problem, sigma,
        f"a random {args.n}-pose design (uniform in the joint limits, seed {args.seed}; "
        "feasibility constraints are not yet applied)",
    ))
    return EXIT_OK


def cmd_scenes(args) -> int:
    from calib_oed.scene import scene_names

    for name in scene_names():
        print(name)
    return EXIT_OK


def cmd_robots(args) -> int:
    from calib_oed.robot_registry import robot_names

    for name in robot_names():
        print(name)
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="calib-oed",
        description="Optimum experimental design for robot kinematic calibration.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("identifiability", help="which parameters are identifiable; KPI estimability")
    p.add_argument("scene", help="shipped scene name or scene file path")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_identifiability)

    p = sub.add_parser("demo", help="identifiability and KPI sigma of a random design")
    p.add_argument("scene", nargs="?", default=DEFAULT_SCENE, help=f"default {DEFAULT_SCENE}")
    p.add_argument("-n", type=_positive_int, default=60,
                   help="number of random poses (default 60)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random design (default 0)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("scenes", help="list the shipped scenes")
    p.set_defaults(func=cmd_scenes)
    p = sub.add_parser("robots", help="list the robots loadable by name")
    p.set_defaults(func=cmd_robots)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - silence the flush at exit
        return EXIT_OK
    except CalibOedError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"calib-oed: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # noqa: BLE001 - last-resort message, traceback on --debug
        if args.debug:
            traceback.print_exc()
        print(
            f"calib-oed: internal error: {type(exc).__name__}: {exc} (rerun with --debug)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
