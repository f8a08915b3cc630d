"""The ``calib-oed`` command.

Exit codes: 0 success; 1 internal error (a bug: please report it with
``--debug`` output); 2 bad input (the message says what to fix).

The parser and ``main`` are here; the commands live in
:mod:`calib_oed.cli.design_commands` and :mod:`calib_oed.cli.calibration_commands`,
what they share in :mod:`calib_oed.cli._common`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import traceback

from threadpoolctl import threadpool_limits

from calib_oed.cli._common import (
    COMPLIANCE_COMMANDS,
    DEFAULT_SCENE,
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_VALIDATION_FAILED,
    _apply_compliance,
    _length_mm,
    _non_negative_int,
    _pose_count,
    _position_tol_mm,
    _positive_int,
    _seed,
    add_command,
    add_json_quiet,
)
from calib_oed.cli._contract import (
    EXIT_INTERRUPTED,
    OneLineParser,
    check_outputs,
    normalise_argv,
    notes_as_lines,
    sigterm_as_interrupt,
)
from calib_oed.cli.calibration_commands import (
    cmd_demo,
    cmd_identify,
    cmd_montecarlo,
    cmd_robots,
    cmd_scenes,
    cmd_simulate,
    cmd_study,
    cmd_validate,
)
from calib_oed.cli.checks import check_inputs
from calib_oed.cli.compensate_commands import add_compensate_parser
from calib_oed.cli.design_commands import (
    cmd_compare,
    cmd_design,
    cmd_evaluate,
    cmd_feasibility,
    cmd_identifiability,
    cmd_sequential,
    cmd_view,
)
from calib_oed.cli.import_command import add_import_parser
from calib_oed.cli.program_commands import add_program_parser
from calib_oed.cli.table_command import add_table_parser
from calib_oed.exceptions import CalibOedError

__all__ = ["EXIT_BAD_INPUT", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_VALIDATION_FAILED",
           "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="calib-oed",
        description="Optimum experimental design for robot kinematic calibration.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True)

    p = add_command(sub, "identifiability", cmd_identifiability, "which parameters are identifiable; KPI estimability")
    add_json_quiet(p)

    def design_args(p, positional=True):
        if positional:
            p.add_argument("design", nargs="?", metavar="DESIGN", help="design file: DIR/design.yaml or "
                           "a CSV (header = joint names, rad); default: -n random feasible poses")
        p.add_argument("--design", dest="design_option", metavar="FILE",
                       help="design file (same as DESIGN)" if positional else
                       "design file: design.yaml or CSV; default: -n random feasible poses")
        p.add_argument("-n", type=_pose_count, default=60, help="random feasible poses (default 60)")
        p.add_argument("--seed", type=_seed, default=0, help="seed of the random design (default 0)")

    p = add_command(sub, "demo", cmd_demo, "the whole job on a scene: design, simulated calibration, "
                    "export, Monte Carlo", scene=False, outputs={"output": "dir"})
    p.add_argument("scene", nargs="?", default=DEFAULT_SCENE, help=f"default {DEFAULT_SCENE}")
    design_args(p, positional=False)
    p.add_argument("--truth-seed", type=_seed, default=1, help="seed of the simulated robot (default 1)")
    p.add_argument("-N", "--runs", type=_positive_int, default=200, help="Monte Carlo runs (default 200)")
    p.add_argument("--mc-seed", type=_seed, default=0, help="Monte Carlo seed (default 0)")
    p.add_argument("--jobs", type=_positive_int, default=2, help="parallel workers (default 2)")
    p.add_argument("-o", "--output", default="demo_out", metavar="DIR", help="folder for the design "
                   "and the calibrated URDF, overwritten (default ./demo_out)")
    p.add_argument("--no-optimise", action="store_true", help="skip the design optimisation "
                   "(use the heuristic design)")
    p.add_argument("--pool", default="3000", metavar="N|FILE",
                   help="candidate pool of the designs' exchange start and certificate (default 3000)")
    p.add_argument("--iterations", type=_positive_int, help="limit the SQP iterations")
    p.add_argument("--quiet", action="store_true", help="no progress bars")

    from calib_oed.oed.criteria import CRITERIA

    p = add_command(sub, "design", cmd_design, "optimal measurement configurations: exchange start on a "
                    "feasible pool, SQP refinement, efficiency against a certified bound",
                    outputs={"output": "dir"})
    p.add_argument("-n", type=_pose_count, help="number of measurements (default 60, or the rows "
                   "of a --start design file)")
    p.add_argument("--criterion", default=None, choices=CRITERIA,
                   help="kpi (the paper's noise-only KPI A-criterion; the default unless the scene "
                   "gives robot.model_error), kpi_model (the predicted KPI error of the calibrated "
                   "robot under the model-error prior; the default with robot.model_error), "
                   "kpi_kriging (the same with kriging compensation), params (A on the parameter "
                   "covariance, mm and mrad), D, E, or an observability index O1..O5")
    p.add_argument("--start", default="exchange", metavar="exchange|heuristic|DESIGN",
                   help="start design: the exchange algorithm's best poses of the candidate pool "
                   "(default), random feasible poses (the paper's start), or a design file "
                   "(design.yaml or CSV)")
    p.add_argument("--pool", default="3000", metavar="N|FILE",
                   help="candidate pool of the exchange start and the certificate: N random "
                   "feasible poses (default 3000), or a design CSV/YAML of your own candidate "
                   "configurations (infeasible ones are dropped and counted)")
    p.add_argument("--no-refine", action="store_true",
                   help="no SQP refinement: pure selection from the pool (with --start exchange)")
    p.add_argument("--replicates", type=_positive_int, default=1, metavar="K",
                   help="each configuration may be measured up to K times (default 1: the "
                   "start's poses are distinct, though the refinement may bring two together); "
                   "the record says how many distinct poses")
    p.add_argument("--position-tol", type=_position_tol_mm, default=1.0, metavar="MM",
                   help="reflector positions closer than this [mm] count as one arm position in "
                   "the record's distinct_positions (default 1)")
    p.add_argument("--no-certificate", action="store_true",
                   help="skip the optimality certificate (the efficiency against a lower bound "
                   "valid for any feasible design of this size)")
    p.add_argument("--hessian", choices=("exact", "bfgs"), default="exact",
                   help="SQP curvature: the exact Lagrangian Hessian (default; criteria kpi, "
                   "params, D) or damped BFGS")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the pool and the start (default 0)")
    p.add_argument("--starts", type=_positive_int, default=1,
                   help="multi-start: keep the best of this many seeded starts (default 1)")
    p.add_argument("--no-collisions", action="store_true",
                   help="only joint limits and incidence (no capsule or beam constraints)")
    p.add_argument("--iterations", type=_positive_int, help="limit the SQP iterations")
    p.add_argument("--time-limit", type=float, metavar="SECONDS",
                   help="stop the SQP after this wall time (status time_limit)")
    p.add_argument("--aggregate", choices=("mean", "max"),
                   help="KPI of several points (criterion kpi): weighted mean variance, or the "
                   "worst-case variance max_i (epigraph SQP); default: the scene's kpi.aggregate")
    p.add_argument("--prior-from", metavar="JSON", help="kpi_model's joint-space model-error prior "
                   "from an earlier identification (the identification.json of `calib-oed identify`: "
                   "its fitted model error, compliances and gains; docs/scenes.md)")
    p.add_argument("-o", "--output", metavar="DIR", help="write DIR/design.yaml, DIR/design.csv and DIR/timing.yaml (the run's times)")
    p.add_argument("--controller", action="store_true", help="also write DIR/design_controller.csv "
                   "in the controller's joint values and angle unit (the scene's controller: block)")
    add_json_quiet(p, "no progress bar")

    p = add_command(sub, "evaluate", cmd_evaluate, "KPI sigma, criterion values, margins and mesh check of a design",
                    outputs={"plot": "dir"})
    p.add_argument("design", metavar="DESIGN", help="design file: DIR/design.yaml or a CSV")
    p.add_argument("--criterion", default="kpi", choices=CRITERIA, help="criterion of the "
                   "contribution plot (default kpi); all criterion values are always reported")
    p.add_argument("--no-mesh-check", action="store_true", help="skip the URDF mesh check")
    p.add_argument("--position-tol", type=_position_tol_mm, default=1.0, metavar="MM",
                   help="reflector positions closer than this [mm] count as one arm position "
                   "(default 1)")
    p.add_argument("--plot", metavar="DIR", help="write DIR/kpi_ellipsoid.png and DIR/pose_contributions.png")
    p.add_argument("--certificate", action="store_true", help="optimality certificate: a lower bound "
                   "on the criterion of any design of this many poses, and this design's efficiency "
                   "(criteria kpi, params, D; 10-60 s)")
    p.add_argument("--pool", type=_positive_int, default=3000,
                   help="feasible candidate poses of the certificate (default 3000)")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the certificate's pool (default 0)")
    add_json_quiet(p, "no progress bars")

    p = add_command(sub, "compare", cmd_compare, "designs side by side: KPI variance, criteria, feasibility",
                    outputs={"plot": "file"})
    p.add_argument("designs", nargs="+", metavar="DESIGN", help="design files (design.yaml or CSV)")
    p.add_argument("--plot", metavar="FILE", help="write the 95 %% KPI ellipsoid projections "
                   "(.png, .svg or .pdf)")
    add_json_quiet(p, "no progress bar")

    p = add_command(sub, "validate", cmd_validate, "residuals of a calibration on separate validation measurements")
    p.add_argument("calibrated", metavar="CALIBRATED", help="the folder `identify -o DIR` wrote "
                   "(calibrated URDF and sensor YAML), or its URDF")
    p.add_argument("measurements", help="validation measurement CSV (docs/data_format.md)")
    p.add_argument("--length-unit", choices=("m", "mm"), help="if the file states no units")
    p.add_argument("--angle-unit", choices=("rad", "deg"), help="if the file states no units")
    add_json_quiet(p)
    p.add_argument("--max-rms", type=float, metavar="MM", help="tolerance: fail (exit 3) above "
                   "this calibrated RMS position error [mm]")
    p.add_argument("--max-error", type=float, metavar="MM", help="tolerance: fail (exit 3) when "
                   "the largest calibrated position error exceeds this [mm]")
    p.add_argument("--compensate", action="store_true", help="add the fitted model error's mean "
                   "(from identification.json) to the calibrated predictions")
    p.add_argument("--max-registration-rms", type=float, default=10.0, metavar="MM",
                   help="stop (exit 2) when the tracker pose fitted alone leaves more [mm] (default 10)")

    p = add_command(sub, "view", cmd_view, "the scene and a design in the browser (meshcat), or a static HTML",
                    outputs={"html": "file"})
    p.add_argument("design", nargs="?", metavar="DESIGN", help="design file (design.yaml or CSV); "
                   "default: the scene alone")
    p.add_argument("--html", metavar="FILE", help="write a self-contained HTML page instead of serving")
    p.add_argument("--scale", type=float, metavar="F", help="drawing scale of the KPI ellipsoid "
                   "(default: a 1-2-5 number that makes it about 50 mm)")
    p.add_argument("--level", type=float, default=0.95, help="confidence level (default 0.95)")
    p.add_argument("--drawing", default="auto", choices=("auto", "visual", "capsules"),
                   help="robot drawn by its URDF geometry, its capsules, or auto (capsules when the "
                   "meshes of all poses would make the page too large)")
    p.add_argument("--for", dest="seconds", type=float, metavar="SECONDS",
                   help="serve for this long, then stop (default: until Ctrl-C)")
    p.add_argument("--program", metavar="DIR", help="animate the measurement program written by "
                   "`calib-oed program SCENE DESIGN --format csv -o DIR` (its CSV, or the CSV file)")
    p.add_argument("--json", action="store_true", help="machine-readable output (with --html)")

    p = add_command(sub, "feasibility", cmd_feasibility, "constraint pairs, a feasible design, margins, mesh check",
                    outputs={"output": "file"})
    design_args(p)
    p.add_argument("-o", "--output", metavar="CSV", help="write the design (joint names, rad)")
    p.add_argument("--no-mesh-check", action="store_true", help="skip the URDF mesh check")
    add_json_quiet(p)

    p = add_command(sub, "simulate", cmd_simulate, "simulated tracker measurements of a random true robot",
                    outputs={"output": "file", "truth": "file"})
    design_args(p)
    p.add_argument("--truth-seed", type=_seed, default=1, help="seed of the simulated robot (default 1)")
    p.add_argument("-o", "--output", required=True, metavar="CSV", help="measurement file to write")
    p.add_argument("--truth", metavar="YAML", help="where to write the true parameters "
                   "(default: <output>_truth.yaml)")
    p.add_argument("--realistic", action="store_true",
                   help="a realistic truth: gravity compliance, transmission errors, J2 balancer, tracker "
                   "systematics on top of the geometric errors (docs/identification.md)")
    p.add_argument("--level", type=float, default=None, metavar="L",
                   help="with --realistic: scale of the unmodelled errors (default 1, or the scene's "
                   "realistic.level)")
    p.add_argument("--without", action="append", default=[], metavar="COMPONENT",
                   choices=("geometric", "compliance", "transmission", "balancer", "tracker", "gains"),
                   help="with --realistic: switch a component off (repeatable)")
    p.add_argument("--thermal", action="store_true", help="with --realistic: add thermal drift")
    p.add_argument("--gross-errors", type=_non_negative_int, default=None, metavar="K",
                   help="with --realistic: K measurements with a 5 mm gross error")
    add_json_quiet(p, "print nothing")

    p = add_command(sub, "identify", cmd_identify, "identify the parameters from a measurement file",
                    outputs={"output": "dir", "plot": "file", "adopt_registration": "file"})
    p.add_argument("measurements", help="measurement CSV (docs/data_format.md)")
    p.add_argument("-o", "--output", metavar="DIR", help="write calibrated URDF, sensor YAML, report")
    p.add_argument("--loss", default="robust", choices=("robust", "linear"),
                   help="robust (default: rows flagged against noise + model error; gross errors "
                   "left out, flags that look like model error kept; docs/identification.md) or "
                   "linear (every row kept, flags only reported)")
    p.add_argument("--drop-flagged", action="store_true", help="leave every flagged row out, "
                   "also those reported as likely model error")
    p.add_argument("--max-registration-rms", type=float, default=10.0, metavar="MM",
                   help="stop (exit 2) when the tracker pose fitted alone leaves more [mm] (default 10)")
    p.add_argument("--cv", type=_positive_int, metavar="K", help="K-fold cross-validation over the "
                   "poses: the predicted error on unseen poses")
    p.add_argument("--length-unit", choices=("m", "mm"), help="if the file states no units")
    p.add_argument("--angle-unit", choices=("rad", "deg"), help="if the file states no units")
    p.add_argument("--truth", metavar="YAML", help="true parameters of a simulation: report TCP errors")
    p.add_argument("--plot", metavar="FILE", help="write the residual plot (.png, .svg or .pdf)")
    p.add_argument("--adopt-registration", metavar="SCENE_FILE", help="fit the tracker pose and the "
                   "reflector offsets to the measurements, write the scene with them to SCENE_FILE "
                   "and identify with it")
    add_json_quiet(p)

    p = add_command(sub, "montecarlo", cmd_montecarlo, "simulated calibrations against the predicted KPI covariance")
    design_args(p)
    p.add_argument("-N", "--runs", type=_positive_int, default=500, help="runs (default 500)")
    p.add_argument("--mc-seed", type=_seed, default=0, help="Monte Carlo seed (default 0)")
    p.add_argument("--jobs", type=_positive_int, default=2, help="parallel workers (default 2)")
    add_json_quiet(p, "no progress bar")

    p = add_command(sub, "study", cmd_study, "a study over robots, scenes, criteria and seeds (the paper's tables)",
                    scene=False, outputs={"output": "dir"})
    p.add_argument("config", metavar="CONFIG", help="study file (YAML), or a shipped study: "
                   "kuka, notional90, smoke")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="results folder; a rerun resumes it (finished cases are not recomputed)")
    p.add_argument("--jobs", type=_positive_int, help="parallel local workers (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run the cases on this Dask scheduler "
                   "(needs the calib_oed[dask] extra)")
    p.add_argument("--no-report", action="store_true", help="skip DIR/report.md and the figures")
    p.add_argument("--no-figures", action="store_true", help="report without figures")
    add_json_quiet(p, "no progress bar")

    p = add_command(sub, "sequential", cmd_sequential, "sequential calibration of a simulated robot to a KPI "
                    "precision target, next to fixed and heuristic designs", outputs={"output": "dir"})
    p.add_argument("--target-sigma", required=True, type=_length_mm, metavar="LENGTH",
                   help="stop when every working configuration's predicted KPI sigma is at most this: "
                   "0.02mm, 20um or 0.02 (mm)")
    p.add_argument("--batch", type=_positive_int, default=5, help="poses per proposal (default 5)")
    p.add_argument("--measured", metavar="MEASUREMENTS", help="a real calibration, one step: identify "
                   "from this measurement file, then say whether the target is reached or write the "
                   "next --batch poses to DIR/next.csv (no simulation)")
    p.add_argument("--length-unit", choices=("m", "mm"), help="with --measured: if the file states no units")
    p.add_argument("--angle-unit", choices=("rad", "deg"), help="with --measured: if the file states no units")
    p.add_argument("--max-registration-rms", type=float, default=10.0, metavar="MM",
                   help="with --measured: as identify's, the plausibility limit of the tracker "
                   "registration before the fit (default 10 mm)")
    p.add_argument("--initial", type=_positive_int, default=15,
                   help="poses measured first (default 15)")
    p.add_argument("--initial-design", default="heuristic", choices=("heuristic", "optimal"),
                   help="the first poses: random feasible (default) or the KPI-optimal design of "
                   "that size at nominal")
    p.add_argument("--max-measurements", type=_positive_int, default=120,
                   help="stop after this many measured poses (default 120)")
    p.add_argument("--criterion", default="kpi", choices=CRITERIA, help="criterion of the proposals "
                   "(default kpi)")
    p.add_argument("--truth-seed", type=_seed, default=1, help="seed of the simulated robot and its "
                   "noise (default 1)")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the designs and candidate pools (default 0)")
    p.add_argument("--follow-pose", action="store_true",
                   help="draw each batch's candidates near the last measured pose")
    p.add_argument("--no-compare", action="store_true", help="skip the fixed KPI-optimal and heuristic "
                   "designs of the comparison")
    p.add_argument("--reference", type=_non_negative_int, default=60, metavar="N",
                   help="also report the predicted sigma of a fixed KPI-optimal and a heuristic "
                   "design of N poses at the final estimate (default 60; 0: skip)")
    p.add_argument("--grid-step", type=_positive_int, default=5, help="sizes of the fixed designs "
                   "compared: the multiples of this from the fewest poses that identify the "
                   "parameters up to --max-measurements (default 5)")
    p.add_argument("--iterations", type=_positive_int, help="limit the SQP iterations of every design")
    p.add_argument("-o", "--output", metavar="DIR", help="write DIR/measured.csv and DIR/sequential.json")
    add_json_quiet(p, "no progress lines")

    add_program_parser(sub)
    add_compensate_parser(sub)
    add_import_parser(sub)
    add_table_parser(sub)

    p = add_command(sub, "scenes", cmd_scenes, "list the shipped scenes", scene=False)
    add_json_quiet(p)
    p = add_command(sub, "robots", cmd_robots, "list the robots loadable by name", scene=False)
    add_json_quiet(p)
    for p in sub.choices.values():  # --quiet wherever --json is accepted
        dests = {a.dest for a in p._actions}
        if "json" in dests and "quiet" not in dests:
            p.add_argument("--quiet", action="store_true", help="no progress output")
    for name in COMPLIANCE_COMMANDS:
        p = sub.choices[name]
        p.add_argument("--compliance", action="store_true", help="model joint compliance under "
                       "gravity: one compliance parameter per joint, with the scene's "
                       "robot.compliance payload (docs/scenes.md)")
        p.add_argument("--payload-kg", type=float, metavar="KG", help="payload mass of the "
                       "compliance model (implies --compliance; centre of mass from the scene)")
        p.add_argument("--joint-gains", metavar="JOINTS", help="model a gain joint<i>.gain of "
                       "every joint (bare, or 'all'), or of the joints listed (e.g. 2,3), as a scene's "
                       "robot.joint_gains block does (docs/scenes.md); the next argument is taken "
                       "as JOINTS only when it is 'all' or joint numbers")
    return parser


def main(argv: list[str] | None = None, *, as_command: bool | None = None) -> int:
    """Run the command line; returns the exit code (docs/cli.md).

    Args:
        argv: The arguments; ``None`` reads ``sys.argv``, as the console script and
            ``python -m calib_oed`` do.
        as_command: Whether this process is the command, so that SIGTERM and
            SIGINT handlers may be installed (:func:`sigterm_as_interrupt`).
            Default: only when ``argv`` is ``None``. A test that calls
            ``main([...])`` in its own process keeps the process's handlers, so a
            time limit that sends SIGTERM to pytest stops pytest.
    """
    if as_command is None:
        as_command = argv is None
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(normalise_argv(argv, parser))
    args.argv = argv
    signals = sigterm_as_interrupt() if as_command else contextlib.nullcontext()
    try:
        # one BLAS thread for the whole command, not only inside the design driver: what a command
        # writes after the solve (a design's criterion values, a fit's report) must not depend on
        # OPENBLAS_NUM_THREADS or the core count (docs/benchmarks.md, "Reproducible designs")
        with signals, notes_as_lines(), threadpool_limits(limits=1):
            check_outputs(args)  # before any work: a bad path costs nothing
            check_inputs(args)
            _apply_compliance(args)
            return args.func(args)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM; a command that saves work says so itself
        if args.debug:
            traceback.print_exc()
        print("calib-oed: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
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
            f"calib-oed: internal error: {type(exc).__name__}: {_one_line(str(exc))} (rerun with --debug)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


def _one_line(text: str) -> str:
    return "; ".join(part.strip() for part in text.splitlines() if part.strip())


if __name__ == "__main__":
    sys.exit(main())
