"""The calibration commands: demo, simulate, identify, validate, montecarlo, study, scenes, robots."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from calib_oed.cli._common import (
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_VALIDATION_FAILED,
    _adopt,
    _bars,
    _design,
    _note_infeasible,
    _optimise,
    _round_trip_text,
    _say,
    _scene,
    _setup,
)
from calib_oed.exceptions import CalibOedError


def cmd_demo(args) -> int:
    """The whole job on one scene: feasible design, simulated data, identification,
    export with round trip, Monte Carlo validation."""
    import time

    from calib_oed.calibration.montecarlo import monte_carlo
    from calib_oed.calibration.report import format_identifiability, format_kpi_sigma
    from calib_oed.calibration.workflow import (
        export_result,
        identify_measurements,
        round_trip_error,
        simulated_measurements,
        tcp_errors,
    )
    from calib_oed.oed.design import evaluate_design
    from calib_oed.oed.result import format_design_table, write_design

    s = _setup(args.scene)
    problem = s.problem
    print(format_identifiability(problem, problem.identifiability, problem.kpi_estimability(),
                                 title=f"scene {s.scene.name!r}"))
    print()
    t0 = time.perf_counter()
    q_start, what = _design(s, args)
    print(f"start: {what}, sampled in {time.perf_counter() - t0:.2f} s; feasible: "
          f"{bool(s.feasibility.compute(q_start, jacobian=False).feasible.all())}")
    designs = {"heuristic": evaluate_design(s, q_start, "kpi", method="heuristic", seed=args.seed)}
    if not args.no_optimise:
        # the default pipeline (exchange start on a feasible pool, SQP, certificate),
        # or a refinement of the design the user gave
        given = getattr(args, "design", None) or getattr(args, "design_option", None)
        start = q_start if given else "exchange"
        designs["C_p-optimal"] = _optimise(s, args, "params", start)
        designs["KPI-optimal"] = _optimise(s, args, "kpi", start)
    print(format_design_table(designs))
    for name, d in designs.items():
        if d.certificate:
            print(f"{name}:{d.efficiency_line().strip()[len('efficiency:'):]}")
    final = designs["KPI-optimal" if not args.no_optimise else "heuristic"]
    q = final.q
    what = f"{final.method} {final.criterion} design of {final.n} poses"
    print(format_kpi_sigma(problem, problem.kpi_sigma(q), what))
    out = args.output
    files = write_design(out, final, problem.robot)
    print(f"wrote {files['yaml']} and {files['csv']}")
    print()
    mset, p_true = simulated_measurements(s, q, args.truth_seed)
    result = identify_measurements(s, mset)
    # in the design's KPI frame, as its sigma: a parametric truth keeps the gauge nominal
    before = np.linalg.norm(tcp_errors(s, p_true, None, problem.kpi.frame), axis=1)
    after = np.linalg.norm(tcp_errors(s, p_true, result.p, problem.kpi.frame), axis=1)
    print(f"one simulated calibration (truth seed {args.truth_seed}): {result.status.value}, "
          f"{result.nfev} evaluations, residual RMS {result.rms_mm:.4f} mm")
    for name, b, a in zip(problem.kpi.names, before, after, strict=True):
        print(f"  {name}: TCP error before {b * 1e3:.4f} mm, after {a * 1e3:.4f} mm")
    paths = export_result(s, result, out)
    err = round_trip_error(s, result.p, paths["urdf"])
    print(f"exported {paths['urdf']} and {paths['sensor']}; round trip: "
          f"largest tool difference {_round_trip_text(err)}")
    print()
    mc = monte_carlo(problem, q, args.runs, args.mc_seed, n_jobs=args.jobs, progress=_bars(args))
    print(mc.summary())
    print(f"\nthe demo's files are in {Path(out).resolve()} (overwritten by the next run)")
    return EXIT_OK


def cmd_simulate(args) -> int:
    from calib_oed.calibration.workflow import (
        simulated_measurements,
        write_measurement_file,
        write_truth,
    )

    s = _setup(args.scene)
    settings = _realistic_settings(args)
    q, what = _design(s, args)
    _note_infeasible(s, q, what)
    kind = "realistic truth" if settings is not None else "truth"
    truth = args.truth or str(Path(args.output).with_suffix("")) + "_truth.yaml"
    if settings is None:
        mset, p_true = simulated_measurements(s, q, args.truth_seed)
    else:
        from calib_oed.calibration.realistic_measure import write_realistic_truth
        from calib_oed.calibration.workflow import realistic_measurements

        mset, real, meas = realistic_measurements(s, q, args.truth_seed, settings)
    write_measurement_file(s, args.output, mset,
                           f"simulated by calib_oed: scene {s.scene.name}, {what}, {kind} seed {args.truth_seed}")
    if settings is None:
        write_truth(truth, s, p_true, args.truth_seed)
    else:
        write_realistic_truth(truth, real, s.scene.name, args.truth_seed, meas)
    if args.json:
        print(json.dumps({"scene": s.scene.name, "design": what, "n": int(len(q)),
                          "measurements": str(args.output), "truth": str(truth),
                          "truth_seed": args.truth_seed, "realistic": settings is not None}, indent=2))
        return EXIT_OK
    _say(args, f"wrote {len(q)} simulated measurements per reflector to {args.output}; the truth to {truth}")
    return EXIT_OK


def _realistic_settings(args):
    """The :class:`RealisticSettings` of ``simulate --realistic`` (the scene's ``realistic:`` block
    with the options on top), or None without ``--realistic``."""
    extras = args.level is not None or args.without or args.thermal or args.gross_errors is not None
    if not args.realistic:
        if extras:
            raise CalibOedError("--level, --without, --thermal and --gross-errors need --realistic")
        return None
    import dataclasses

    from calib_oed.calibration.realistic_defaults import realistic_settings_from_scene

    base = realistic_settings_from_scene(_scene(args.scene))
    changes = {name: False for name in args.without}
    if args.level is not None:
        changes["level"] = args.level
    if args.thermal:
        changes["thermal"] = True
    if args.gross_errors is not None:
        changes["gross_errors"] = args.gross_errors
    return dataclasses.replace(base, **changes)


def _identify_fit(s, mset, args):
    """Sanity registration, then the fit with the model error; nothing written.
    Returns (sanity, blocks, robust)."""
    from calib_oed.calibration.model_error import start_prior
    from calib_oed.calibration.robust import identify_robust
    from calib_oed.calibration.sanity import check_measurements

    problem = s.problem
    sanity = check_measurements(problem.space, mset, args.max_registration_rms * 1e-3,
                                s.reflector_names)
    blocks = mset.blocks(error_model=s.scene.error_model())
    drop = "all" if args.drop_flagged else ("gross" if args.loss == "robust" else "none")
    return sanity, blocks, identify_robust(problem.space, blocks, problem.identifiability,
                                           model_error=start_prior(s.scene, problem), drop=drop)


def _scene_and_measurements(args):
    """The set-up of ``args.scene`` and ``args.measurements`` read in its units (``identify``,
    ``validate``), after checking ``--max-registration-rms``."""
    from calib_oed.calibration.workflow import read_scene_measurements
    from calib_oed.exceptions import ParameterError

    if not args.max_registration_rms > 0:
        raise ParameterError(f"--max-registration-rms must be a positive length in mm, got "
                             f"{args.max_registration_rms:g}")
    s = _setup(args.scene)
    units = {k: v for k, v in (("length_unit", args.length_unit), ("angle_unit", args.angle_unit)) if v}
    return s, read_scene_measurements(s, args.measurements, **units)


def cmd_identify(args) -> int:
    from calib_oed.calibration.crossval import cross_validate
    from calib_oed.calibration.fit_report import (
        fit_dict,
        fit_report,
        format_fit,
        per_row,
        write_residuals_csv,
    )
    from calib_oed.calibration.joint_prior_choice import joint_prior
    from calib_oed.calibration.trust import assess
    from calib_oed.calibration.workflow import (
        export_result,
        read_truth,
        round_trip_error,
        tcp_errors,
    )

    s, mset = _scene_and_measurements(args)
    p_true = read_truth(args.truth, s) if args.truth else None  # checked before the fit: bad input exits at once
    if args.cv:  # the folds' bound before any fit (a bad --cv is bad input, not a late failure)
        from calib_oed.calibration.crossval import pose_index
        from calib_oed.exceptions import ParameterError

        n_poses = int(np.unique(pose_index(mset.q)).size)
        if not 2 <= args.cv <= n_poses:
            raise ParameterError(f"--cv: K must be between 2 and the number of poses ({n_poses}), "
                                 f"got {args.cv}")
    if args.adopt_registration:  # the fitted tracker pose (and offsets) into a new scene, used from here on
        s = _adopt(s, mset, args)
        p_true = read_truth(args.truth, s) if args.truth else None
    sanity, blocks, robust = _identify_fit(s, mset, args)
    result = robust.result
    report = fit_report(s.problem.space, mset, blocks, sanity, robust, s.reflector_names)
    cv = None
    if args.cv:
        cv = cross_validate(s.problem.space, mset, s.problem.identifiability, args.cv,
                            error_model=s.scene.error_model(),
                            model_error=robust.model_error.prior,
                            gross=None if robust.dropped is None else per_row(mset, robust, robust.dropped))
    trust = assess(s.problem, robust, s.feasibility, blocks,
                   joint_prior=joint_prior(s.problem, getattr(s.scene, "joint_error", None)))
    data = result.to_dict()
    data["fit"] = fit_dict(report, robust, sanity)
    data["model_error"] = robust.model_error.to_dict()
    data.update(trust.to_dict())
    data["outliers"] = data["fit"]["outliers"]  # by file line; the fit's own a-priori list is not used
    del data["noise_factor_inliers"]  # nor its sigma0 without that list (one rule: fit.flag_rule)
    if cv is not None:
        data["cross_validation"] = cv.to_dict()
    if args.truth:
        data["tcp_error_mm"] = {
            "before": (np.linalg.norm(tcp_errors(s, p_true, None), axis=1) * 1e3).tolist(),
            "after": (np.linalg.norm(tcp_errors(s, p_true, result.p), axis=1) * 1e3).tolist(),
            "frame": "tracker",
            "world": {"before": (np.linalg.norm(tcp_errors(s, p_true, None, "world"), axis=1) * 1e3).tolist(),
                      "after": (np.linalg.norm(tcp_errors(s, p_true, result.p, "world"), axis=1) * 1e3).tolist()},
        }
    if args.output:
        paths = export_result(s, result, args.output)
        data["files"] = {k: str(v) for k, v in paths.items()}
        data["round_trip_m"] = round_trip_error(s, result.p, paths["urdf"])
        from calib_oed.io.atomic import atomic_write_text

        data["files"]["residuals"] = str(write_residuals_csv(Path(paths["urdf"]).parent / "residuals.csv",
                                                             report))
        data["files"]["report"] = str(Path(args.output) / "identification.json")
        atomic_write_text(data["files"]["report"], json.dumps(data, indent=2))
    if args.plot:
        from calib_oed.viz.plots import plot_residuals, save_figure

        flagged = [(int(robust.block[i]), int(robust.row[i])) for i in np.flatnonzero(robust.flagged)]
        rule = f"noise + model error, chi-square {1 - robust.alpha:g}"
        data["plot"] = str(save_figure(plot_residuals(result, flagged, rule, s.reflector_names),
                                       args.plot))
    if args.json:
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(result.summary(outliers=False))
    print(format_fit(report, robust, sanity))
    print("\n".join(trust.lines()))
    if cv is not None:
        print(cv.summary())
    if args.truth:
        err = data["tcp_error_mm"]
        for name, b, a, wb, wa in zip(s.problem.kpi.names, err["before"], err["after"], err["world"]["before"],
                                      err["world"]["after"], strict=True):
            print(f"TCP error at {name} against the truth (tracker frame): before {b:.4f} mm, "
                  f"after {a:.4f} mm")
            print(f"TCP error at {name} against the truth (world frame, the robot base): before {wb:.4f} mm, "
                  f"after {wa:.4f} mm")
    if args.output:
        print(f"wrote {data['files']['urdf']}, {data['files']['sensor']}, "
              f"{data['files']['residuals']} and {data['files']['report']}; "
              f"round trip of the URDF: {_round_trip_text(data['round_trip_m'])}")
    if args.plot:
        print(f"wrote the residual plot {data['plot']}")
    return EXIT_OK


def cmd_validate(args) -> int:
    from calib_oed.calibration.sanity import check_measurements
    from calib_oed.calibration.validation import validate_calibration
    from calib_oed.calibration.verdict import (
        judge,
        pose_lines,
        pose_table,
        read_identification,
        validation_prediction,
    )
    s, mset = _scene_and_measurements(args)
    check_measurements(s.problem.space, mset, args.max_registration_rms * 1e-3, s.reflector_names)
    result = validate_calibration(s.scene, args.calibrated, mset, compensated=args.compensate)
    ident = read_identification(result.files)
    pred = result.predicted
    verdict = judge(result.calibrated.position_mm, args.max_rms, args.max_error,
                    *validation_prediction(pred, ident, args.compensate))
    table = pose_table(mset.q, result.calibrated.position_mm, mset.lines, mset.joint_names,
                       (ident or {}).get("training_joint_ranges"),
                       None if pred is None else pred.rms_mm, None if pred is None else pred.inside)
    shared, poses = _poses_in_training(mset.q, ident)
    if args.json:
        data = result.to_dict()
        data["compensated"] = bool(args.compensate)
        data["verdict"] = verdict.to_dict()
        data["poses"] = table
        data["poses_in_training"] = shared
        print(json.dumps(data, indent=2))
    else:
        print(result.summary())
        print("\n".join(pose_lines(table)))
        if shared:
            print(f"warning: {shared} of {poses} validation poses are poses the identification was fitted "
                  f"to (joint values within {TRAINING_POSE_TOL:g} rad): their errors are the fit's "
                  "residuals, not an independent validation; measure separate poses")
        print("\n".join(verdict.lines()))
    return EXIT_VALIDATION_FAILED if verdict.passed is False else EXIT_OK


#: Joint values [rad] within which a validation pose counts as a pose of the identification's data.
TRAINING_POSE_TOL = 1e-6


def _poses_in_training(q: np.ndarray, ident: dict | None) -> tuple[int, int]:
    """How many of the distinct validation configurations ``q`` are configurations the
    identification was fitted to (``prediction_data`` of ``identification.json``), and how many
    there are; 0 when the identification records none."""
    poses = np.unique(np.asarray(q, dtype=float), axis=0)
    try:
        train = np.asarray(ident["prediction_data"]["configurations_rad"], dtype=float)
    except (TypeError, KeyError, ValueError):
        return 0, len(poses)
    if train.ndim != 2 or train.shape[1] != poses.shape[1]:
        return 0, len(poses)
    near = np.abs(poses[:, None, :] - train[None, :, :]).max(axis=2) <= TRAINING_POSE_TOL
    return int(near.any(axis=1).sum()), len(poses)


def cmd_montecarlo(args) -> int:
    from calib_oed.calibration.montecarlo import monte_carlo

    s = _setup(args.scene)
    q, what = _design(s, args)
    mc = monte_carlo(s.problem, q, args.runs, args.mc_seed, n_jobs=args.jobs,
                     progress=_bars(args))
    if args.json:
        data = mc.to_dict()
        data.update(scene=s.scene.name, design=what)
        print(json.dumps(data, indent=2))
    else:
        print(f"scene {s.scene.name!r}, {what}")
        print(mc.summary())
    return EXIT_OK


def cmd_study(args) -> int:
    from calib_oed.study.loader import load_study_config
    from calib_oed.study.report import write_report
    from calib_oed.study.runner import run_study

    config = load_study_config(args.config)
    command = "calib-oed " + " ".join(args.argv)
    result = run_study(config, args.output, n_jobs=args.jobs, scheduler=args.scheduler,
                       progress=_bars(args), command=command)
    paths = {} if args.no_report else write_report(result, figures=not args.no_figures)
    if args.json:
        data = result.summary()
        data["files"] = {k: str(v) for k, v in paths.items()}
        print(json.dumps(data, indent=2))
    else:
        print(f"study {config.name!r}: {len(result.cases)} of {len(config.specs)} cases done "
              f"({len(result.computed)} computed now, {len(result.loaded)} loaded from {args.output}) "
              f"in {result.wall_seconds:.0f} s")
        for k, v in paths.items():
            print(f"wrote {k}: {v}")
    for failure in result.failures:
        print(f"calib-oed: case {failure.case_id} failed: {failure.error} (a rerun retries it; "
              "--debug shows nothing more: the traceback is in summary.json)", file=sys.stderr)
    return EXIT_INTERNAL if result.failures else EXIT_OK


def _print_names(args, names) -> int:
    """``names`` one per line, or as a JSON list with ``--json``."""
    print(json.dumps(list(names)) if args.json else "\n".join(names))
    return EXIT_OK


def cmd_scenes(args) -> int:
    from calib_oed.scene.reader import scene_names

    return _print_names(args, scene_names())


def cmd_robots(args) -> int:
    from calib_oed.model.registry import robot_names

    return _print_names(args, robot_names())
