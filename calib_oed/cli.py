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
from pathlib import Path

import numpy as np

from calib_oed.exceptions import CalibOedError

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2

DEFAULT_SCENE = "fms_kr16"


def _non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text}")
    return value


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text}")
    return value


def _problem(scene_ref):
    from calib_oed.problem import CalibrationProblem
    from calib_oed.scene import load_scene

    scene = load_scene(scene_ref) if isinstance(scene_ref, (str, os.PathLike)) else scene_ref
    return scene, CalibrationProblem.from_scene(scene)


#: Commands with --compliance / --payload-kg (joint compliance under gravity).
COMPLIANCE_COMMANDS = ("identifiability", "demo", "design", "evaluate", "compare", "simulate",
                       "identify", "montecarlo", "sequential")


def _apply_compliance(args) -> None:
    """``--compliance`` / ``--payload-kg``: replace ``args.scene`` by the scene with compliance on."""
    if not (getattr(args, "compliance", False) or getattr(args, "payload_kg", None) is not None):
        return
    import dataclasses

    from calib_oed.compliance import Compliance
    from calib_oed.scene import ComplianceSpec, load_scene

    scene = load_scene(args.scene)
    payload = scene.compliance.payload if scene.compliance is not None else Compliance()
    if args.payload_kg is not None:
        if not args.payload_kg >= 0:
            raise CalibOedError(f"--payload-kg: expected a mass >= 0 kg, got {args.payload_kg:g}")
        payload = Compliance(args.payload_kg, payload.payload_com)
    args.scene = dataclasses.replace(scene, compliance=ComplianceSpec(True, payload))


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


def _setup(scene_ref):
    from calib_oed.scene import load_scene
    from calib_oed.workflow import setup

    return setup(load_scene(scene_ref) if isinstance(scene_ref, (str, os.PathLike)) else scene_ref)


def _design(s, args):
    """The design of a command: a design file (YAML or CSV), or n heuristic feasible poses."""
    from calib_oed.design_result import read_design_file
    from calib_oed.workflow import heuristic_design

    path = getattr(args, "design", None) or getattr(args, "design_option", None)
    if path:
        return read_design_file(path, s.problem.robot), f"design file {path}"
    q = heuristic_design(s, args.n, args.seed)
    return q, f"{args.n} random feasible poses (seed {args.seed})"


def _say(args, text: str = "") -> None:
    if not getattr(args, "quiet", False) and not getattr(args, "json", False):
        print(text)


def cmd_demo(args) -> int:
    """The whole job on one scene: feasible design, simulated data, identification,
    export with round trip, Monte Carlo validation."""
    import tempfile
    import time

    from calib_oed.design import evaluate_design
    from calib_oed.design_result import format_design_table, write_design
    from calib_oed.montecarlo import monte_carlo
    from calib_oed.report import format_identifiability, format_kpi_sigma
    from calib_oed.workflow import (
        export_result,
        identify_measurements,
        round_trip_error,
        simulated_measurements,
        tcp_errors,
    )

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
        designs["C_p-optimal"] = _optimise(s, args, "params", q_start)
        designs["KPI-optimal"] = _optimise(s, args, "kpi", q_start)
    print(format_design_table(designs))
    final = designs["KPI-optimal" if not args.no_optimise else "heuristic"]
    q = final.q
    what = f"{final.method} {final.criterion} design of {final.n} poses"
    print(format_kpi_sigma(problem, problem.kpi_sigma(q), what))
    out = args.output or tempfile.mkdtemp(prefix="calib_oed_demo_")
    files = write_design(out, final, problem.robot)
    print(f"wrote {files['yaml']} and {files['csv']}")
    print()
    mset, p_true = simulated_measurements(s, q, args.truth_seed)
    result = identify_measurements(s, mset)
    before = np.linalg.norm(tcp_errors(s, p_true, None), axis=1)
    after = np.linalg.norm(tcp_errors(s, p_true, result.p), axis=1)
    print(f"one simulated calibration (truth seed {args.truth_seed}): {result.status.value}, "
          f"{result.nfev} evaluations, residual RMS {result.rms_mm:.4f} mm")
    for name, b, a in zip(problem.kpi.names, before, after, strict=True):
        print(f"  {name}: TCP error before {b * 1e3:.4f} mm, after {a * 1e3:.4f} mm")
    paths = export_result(s, result, out)
    err = round_trip_error(s, result.p, paths["urdf"])
    print(f"exported {paths['urdf']} and {paths['sensor']}; round trip: "
          f"largest tool difference {err * 1e9:.3g} nm")
    print()
    mc = monte_carlo(problem, q, args.runs, args.mc_seed, n_jobs=args.jobs, progress=not args.quiet)
    print(mc.summary())
    return EXIT_OK


def _sqp_settings(args):
    from dataclasses import replace

    from calib_oed.design import DESIGN_SQP

    settings = DESIGN_SQP
    if getattr(args, "iterations", None):
        settings = replace(settings, max_iterations=args.iterations)
    if getattr(args, "time_limit", None):
        settings = replace(settings, time_limit=args.time_limit)
    return settings


def _progress(args, what: str):
    """An SQP iteration callback drawing a tqdm bar (None when quiet)."""
    if getattr(args, "quiet", False) or getattr(args, "json", False):
        return None, None
    from tqdm import tqdm

    bar = tqdm(desc=what, unit=" it", leave=False, file=sys.stderr)

    def callback(record):
        bar.update(1)
        bar.set_postfix(objective=f"{record.objective:.4g}", violation=f"{record.violation:.1e}")

    return callback, bar


def _optimise(s, args, criterion: str, start, aggregate: str = "mean"):
    from calib_oed.design import design

    what = f"{criterion}{'-max' if aggregate == 'max' else ''}-optimal design"
    callback, bar = _progress(args, what)
    try:
        return design(s, args.n, criterion, start=start, seed=args.seed,
                      n_starts=getattr(args, "starts", 1), collisions=not getattr(args, "no_collisions", False),
                      settings=_sqp_settings(args), callback=callback, aggregate=aggregate)
    finally:
        if bar is not None:
            bar.close()


def cmd_design(args) -> int:
    from calib_oed.design_file import read_design_csv
    from calib_oed.design_result import write_design

    s = _setup(args.scene)
    start = args.start
    if args.start not in ("heuristic", "exchange"):
        start = read_design_csv(args.start, s.problem.robot)
        args.n = len(start)
    # the KPI aggregate: --aggregate, else the scene's kpi.aggregate (for criterion kpi)
    aggregate = args.aggregate or (s.scene.kpi.aggregate if args.criterion == "kpi" else "mean")
    result = _optimise(s, args, args.criterion, start, aggregate)
    paths = write_design(args.output, result, s.problem.robot) if args.output else {}
    if args.json:
        data = result.to_dict()
        data["files"] = {k: str(v) for k, v in paths.items()}
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(result.summary())
    if paths:
        print(f"wrote {paths['yaml']} and {paths['csv']}")
    else:
        print("(no -o DIR given: nothing written)")
    return EXIT_OK


def _mesh_check(s, q):
    """The independent check of design ``q`` against the URDF collision meshes."""
    from calib_oed.feasibility.mesh_check import check_design_meshes

    scene = s.scene
    return check_design_meshes(
        scene.robot, q, scene.cell,
        tracker_position=scene.tracker.placement().translation,
        reflector_offsets=np.array([r.offset for r in scene.reflectors]),
        beam_radius=scene.feasibility.beam_radius,
        excluded_pairs=scene.feasibility.excluded_pairs,
    )


def cmd_evaluate(args) -> int:
    from calib_oed.design import evaluate_design
    from calib_oed.report import format_kpi_sigma

    s = _setup(args.scene)
    q, what = _design(s, args)
    result = evaluate_design(s, q, args.criterion, method="given")
    problem = s.problem
    estimable = problem.kpi_estimability()
    mesh = None if args.no_mesh_check else _mesh_check(s, q)
    plots = _evaluate_plots(s, q, args) if args.plot else {}
    certificate = None
    if args.certificate:
        from calib_oed.certificate import certify

        certificate = certify(s, q, args.criterion, pool=args.pool, seed=args.seed)
    # the certificate is for A-type criteria: with a worst-case KPI it certifies the mean, and says so
    certificate_note = (None if certificate is None or args.criterion != "kpi"
                        or s.scene.kpi.aggregate != "max" else
                        "the scene's KPI aggregate is max (worst case), which has no certificate: "
                        "the certificate bounds the weighted mean KPI variance (criterion kpi)")
    if args.json:
        data = result.to_dict()
        data["certificate"] = None if certificate is None else certificate.to_dict()
        data["certificate_note"] = certificate_note
        data.update(design_file=what, kpi_estimability=[e.to_dict() for e in estimable],
                    mesh_feasible=None if mesh is None else int(mesh.feasible.sum()),
                    mesh_min_distance_mm=None if mesh is None else float(mesh.min_distance.min() * 1e3),
                    plots={k: str(v) for k, v in plots.items()})
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(f"scene {s.scene.name!r}: {what}, {result.n} poses")
    print(format_kpi_sigma(problem, result.kpi_sigma_mm * 1e-3, what))
    if len(result.kpi_names) > 1:
        print(f"{len(result.kpi_names)} KPI points: mean variance {result.kpi_variance:.5g} mm² "
              f"(weighted as the scene says), max {result.kpi_max_variance:.5g} mm² "
              f"(sigma {np.sqrt(result.kpi_max_variance):.5f} mm) at {result.kpi_worst}")
    for e in estimable:
        if not e.estimable:
            print(f"  note: {e.label} is not estimable: its value depends on the gauge parameters "
                  f"{', '.join(e.gauge[:6])}{' ...' if len(e.gauge) > 6 else ''} "
                  "(`calib-oed identifiability`); C_s is relative to that gauge")
    print("criterion values (kpi, params: average variance [mm², params in mm and mrad]; D: log det C; "
          "E: largest eigenvalue [mm²]; O1..O5: observability indices, larger is better):")
    print("  " + ", ".join(f"{k} {v:.5g}" for k, v in result.criteria.items()))
    print(f"feasible (every constraint of the capsule model, margins included): {result.feasible}")
    from calib_oed.feasibility.margins import format_margins

    print(format_margins(list(result.margins)))
    if mesh is not None:
        print("independent check against the URDF collision meshes:")
        print(mesh.summary())
    if certificate is not None:
        print(certificate.summary())
        if certificate_note:
            print(f"note: {certificate_note}")
    for k, v in plots.items():
        print(f"wrote {k} plot {v}")
    return EXIT_OK


def _evaluate_plots(s, q, args) -> dict[str, Path]:
    from calib_oed.plots import plot_kpi_ellipsoids, plot_pose_contributions, save_figure

    folder = Path(args.plot)
    folder.mkdir(parents=True, exist_ok=True)
    return {
        "ellipsoid": save_figure(plot_kpi_ellipsoids(s.problem, {"design": q}), folder / "kpi_ellipsoid.png"),
        "contributions": save_figure(plot_pose_contributions(s.problem, q, args.criterion),
                                     folder / "pose_contributions.png"),
    }


def cmd_compare(args) -> int:
    from calib_oed.design import evaluate_design
    from calib_oed.design_result import (
        design_label,
        format_criteria_table,
        format_design_table,
        read_design_file,
    )

    s = _setup(args.scene)
    labels = [design_label(p) for p in args.designs]
    if len(set(labels)) != len(labels):
        labels = [str(p) for p in args.designs]
    designs = {}
    for label, path in _iterate(args, list(zip(labels, args.designs, strict=True)), "designs"):
        designs[label] = evaluate_design(s, read_design_file(path, s.problem.robot), "kpi", method="given")
    if args.plot:
        from calib_oed.plots import plot_kpi_ellipsoids, save_figure

        save_figure(plot_kpi_ellipsoids(s.problem, {k: d.q for k, d in designs.items()}), args.plot)
    if args.json:
        print(json.dumps({"scene": s.scene.name,
                          "designs": {k: {**d.to_dict(), "file": str(p)}
                                      for (k, d), p in zip(designs.items(), args.designs, strict=True)},
                          "plot": args.plot}, indent=2))
        return EXIT_OK
    print(f"scene {s.scene.name!r}: {len(designs)} designs (ratios relative to the first)")
    print(format_design_table(designs))
    print()
    print(format_criteria_table(designs))
    if args.plot:
        print(f"wrote {args.plot}")
    return EXIT_OK


def _iterate(args, items, what: str):
    """``items`` with a progress bar unless quiet or JSON."""
    if getattr(args, "quiet", False) or getattr(args, "json", False) or len(items) < 2:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=what, leave=False, file=sys.stderr)


def cmd_validate(args) -> int:
    from calib_oed.validation import validate_calibration
    from calib_oed.workflow import read_scene_measurements

    s = _setup(args.scene)
    units = {k: v for k, v in (("length_unit", args.length_unit), ("angle_unit", args.angle_unit)) if v}
    mset = read_scene_measurements(s, args.measurements, **units)
    result = validate_calibration(s.scene, args.calibrated, mset)
    if args.json:
        print(json.dumps(result.to_dict(), indent=2))
    else:
        print(result.summary())
    return EXIT_OK


def cmd_view(args) -> int:
    import time

    from calib_oed.viewer import open_viewer, write_static_html

    s = _setup(args.scene)
    q = None
    if args.design:
        from calib_oed.design_result import read_design_file

        q = read_design_file(args.design, s.problem.robot)
    options = {"ellipsoid_scale": args.scale, "level": args.level, "robot_drawing": args.drawing}
    if args.html:
        view = write_static_html(args.html, s, q, **options)
        if args.json:
            print(json.dumps({"html": str(view.path), "poses": view.info.n_poses,
                              "ellipsoid_scale": view.info.ellipsoid_scale,
                              "ellipsoid_half_axes_mm": np.asarray(view.info.half_axes_mm).tolist(),
                              "notes": list(view.info.notes)}, indent=2))
            return EXIT_OK
        print(view.info.summary())
        print(f"wrote {view.path} (self-contained: opens offline in a browser)")
        return EXIT_OK
    with open_viewer(s, q, **options) as live:
        print(live.info.summary())
        print(f"meshcat viewer at {live.url} (open it in a browser); "
              + ("Ctrl-C stops it" if args.seconds is None else f"stopping in {args.seconds:g} s"),
              flush=True)
        try:
            if args.seconds is None:
                while True:
                    time.sleep(3600)
            time.sleep(args.seconds)
        except KeyboardInterrupt:
            pass
    return EXIT_OK


def cmd_study(args) -> int:
    from calib_oed.study import run_study
    from calib_oed.study_config import load_study_config
    from calib_oed.study_report import write_report

    config = load_study_config(args.config)
    command = "calib-oed " + " ".join(args.argv)
    result = run_study(config, args.output, n_jobs=args.jobs, scheduler=args.scheduler,
                       progress=not (args.quiet or args.json), command=command)
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


def cmd_feasibility(args) -> int:
    import time

    from calib_oed.design_file import write_design_csv
    from calib_oed.feasibility.margins import format_margins, margin_report

    s = _setup(args.scene)
    t0 = time.perf_counter()
    q, what = _design(s, args)
    elapsed = time.perf_counter() - t0
    res = s.feasibility.compute(q, jacobian=False)
    scene = s.scene
    mesh = None if args.no_mesh_check else _mesh_check(s, q)
    margins = margin_report(s.feasibility, res.values)
    if args.output:
        write_design_csv(args.output, scene.robot, q, comment=f"scene {scene.name}: {what}")
    if args.json:
        data = {
            "scene": scene.name, "design": what, "n": int(len(q)), "seconds": elapsed,
            "constraints_per_pose": s.feasibility.count_per_pose(),
            "paper_self_pairs": s.pairs.paper_count,
            "dropped_pairs": [
                {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in vars(d).items()}
                for d in s.pairs.dropped
            ],
            "feasible": int(res.feasible.sum()),
            "margins": [vars(m) for m in margins],
            "mesh_feasible": None if mesh is None else int(mesh.feasible.sum()),
            "mesh_min_distance_mm": None if mesh is None else float(mesh.min_distance.min() * 1e3),
        }
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(f"scene {scene.name!r}: capsule pairs")
    print(s.pairs.summary())
    print()
    print(f"design: {what} ({elapsed:.2f} s); {int(res.feasible.sum())} of {len(q)} feasible")
    print("smallest margin per constraint kind:")
    print(format_margins(margins))
    if mesh is not None:
        print()
        print("independent check against the URDF collision meshes:")
        print(mesh.summary())
    if args.output:
        print(f"wrote {args.output}")
    return EXIT_OK


def cmd_simulate(args) -> int:
    from calib_oed.workflow import simulated_measurements, write_measurement_file, write_truth

    s = _setup(args.scene)
    q, what = _design(s, args)
    mset, p_true = simulated_measurements(s, q, args.truth_seed)
    write_measurement_file(s, args.output, mset,
                           f"simulated by calib_oed: scene {s.scene.name}, {what}, truth seed {args.truth_seed}")
    truth = args.truth or str(Path(args.output).with_suffix("")) + "_truth.yaml"
    write_truth(truth, s, p_true, args.truth_seed)
    if args.json:
        print(json.dumps({"scene": s.scene.name, "design": what, "n": int(len(q)),
                          "measurements": str(args.output), "truth": str(truth),
                          "truth_seed": args.truth_seed}, indent=2))
        return EXIT_OK
    _say(args, f"wrote {len(q)} simulated measurements per reflector to {args.output}; the truth to {truth}")
    return EXIT_OK


def cmd_identify(args) -> int:
    from calib_oed.workflow import (
        export_result,
        identify_measurements,
        read_scene_measurements,
        read_truth,
        round_trip_error,
        tcp_errors,
    )

    s = _setup(args.scene)
    units = {k: v for k, v in (("length_unit", args.length_unit), ("angle_unit", args.angle_unit)) if v}
    mset = read_scene_measurements(s, args.measurements, **units)
    result = identify_measurements(s, mset, loss=args.loss)
    data = result.to_dict()
    if args.truth:
        p_true = read_truth(args.truth, s)
        data["tcp_error_mm"] = {
            "before": (np.linalg.norm(tcp_errors(s, p_true, None), axis=1) * 1e3).tolist(),
            "after": (np.linalg.norm(tcp_errors(s, p_true, result.p), axis=1) * 1e3).tolist(),
        }
    if args.output:
        paths = export_result(s, result, args.output)
        data["files"] = {k: str(v) for k, v in paths.items()}
        data["round_trip_m"] = round_trip_error(s, result.p, paths["urdf"])
        from calib_oed.io_utils import atomic_write_text

        atomic_write_text(Path(args.output) / "identification.json", json.dumps(data, indent=2))
    if args.plot:
        from calib_oed.plots import plot_residuals, save_figure

        data["plot"] = str(save_figure(plot_residuals(result), args.plot))
    if args.json:
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(result.summary())
    if args.truth:
        for name, b, a in zip(s.problem.kpi.names, data["tcp_error_mm"]["before"],
                              data["tcp_error_mm"]["after"], strict=True):
            print(f"TCP error at {name} against the truth: before {b:.4f} mm, after {a:.4f} mm")
    if args.output:
        print(f"wrote {data['files']['urdf']}, {data['files']['sensor']} and identification.json; "
              f"round trip of the URDF: {data['round_trip_m'] * 1e9:.3g} nm")
    if args.plot:
        print(f"wrote the residual plot {data['plot']}")
    return EXIT_OK


def cmd_montecarlo(args) -> int:
    from calib_oed.montecarlo import monte_carlo

    s = _setup(args.scene)
    q, what = _design(s, args)
    mc = monte_carlo(s.problem, q, args.runs, args.mc_seed, n_jobs=args.jobs,
                     progress=not (args.quiet or args.json))
    if args.json:
        data = mc.to_dict()
        data.update(scene=s.scene.name, design=what)
        print(json.dumps(data, indent=2))
    else:
        print(f"scene {s.scene.name!r}, {what}")
        print(mc.summary())
    return EXIT_OK


_LENGTH_UNITS_MM = {"mm": 1.0, "um": 1e-3, "µm": 1e-3, "m": 1e3}


def _length_mm(text: str) -> float:
    """A length such as ``0.02mm``, ``20um`` or ``0.02`` (mm) in mm, > 0."""
    raw = text.strip()
    unit = next((u for u in sorted(_LENGTH_UNITS_MM, key=len, reverse=True) if raw.endswith(u)), None)
    number = raw[: -len(unit)].strip() if unit else raw
    try:
        value = float(number) * _LENGTH_UNITS_MM[unit or "mm"]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a length like 0.02mm, 20um or 0.02 (mm); units {', '.join(_LENGTH_UNITS_MM)}; "
            f"got {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a length > 0, got {text!r}")
    return value


def _sequential_step(s, args, settings) -> int:
    """One step of a real sequential calibration: identify from the file, then stop or propose."""
    from calib_oed.design_file import write_design_csv
    from calib_oed.io_utils import atomic_write_text
    from calib_oed.sequential import SequentialDesigner
    from calib_oed.workflow import identify_measurements, read_scene_measurements

    units = {k: v for k, v in (("length_unit", args.length_unit), ("angle_unit", args.angle_unit)) if v}
    mset = read_scene_measurements(s, args.measured, **units)
    _, first = np.unique(mset.q, axis=0, return_index=True)
    q = mset.q[np.sort(first)]  # the measured configurations, in measurement order
    result = identify_measurements(s, mset)
    p_hat = np.asarray(result.p)
    designer = SequentialDesigner(s, args.target_sigma, batch=args.batch, criterion=args.criterion,
                                  settings=settings, seed=args.seed + len(q))
    sigma = designer.predicted_sigma_mm(q, p_hat)
    done = bool(sigma.max() <= args.target_sigma)
    data = {"scene": s.scene.name, "measurements": str(args.measured), "rows": int(mset.n),
            "configurations": len(q), "identification_converged": bool(result.converged),
            "target_sigma_mm": args.target_sigma, "kpi_names": list(s.problem.kpi.names),
            "sigma_mm": sigma.tolist(), "done": done, "next_q_rad": None, "files": {}}
    if not done:
        prop = designer.plan(q, p_hat, current_pose=q[-1] if args.follow_pose else None)
        after = designer.predicted_sigma_mm(np.vstack([q, prop.q]), p_hat)
        data.update(next_q_rad=prop.q.tolist(), sigma_after_mm=after.tolist(), method=prop.method)
        if args.output:
            folder = Path(args.output)
            folder.mkdir(parents=True, exist_ok=True)
            data["files"]["csv"] = str(write_design_csv(
                folder / "next.csv", s.problem.robot, prop.q,
                comment=f"next {len(prop.q)} poses after {len(q)} measured of {args.measured}"))
    if args.output:
        folder = Path(args.output)
        folder.mkdir(parents=True, exist_ok=True)
        data["files"]["json"] = str(atomic_write_text(folder / "sequential_step.json",
                                                      json.dumps(data, indent=2) + "\n"))
    if args.json:
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(f"scene {s.scene.name!r}: {len(q)} configurations measured ({mset.n} rows of {args.measured}); "
          f"identification {'converged' if result.converged else 'NOT converged'}")
    for name, sg in zip(s.problem.kpi.names, sigma, strict=True):
        print(f"  predicted KPI sigma at {name}: {sg:.5f} mm")
    if done:
        print(f"target {args.target_sigma:g} mm reached: stop measuring")
        return EXIT_OK
    print(f"target {args.target_sigma:g} mm not reached: measure {len(prop.q)} more poses "
          f"(predicted sigma after them: {after.max():.5f} mm)")
    if data["files"].get("csv"):
        print(f"wrote {data['files']['csv']}; append their measurements to {args.measured} and rerun")
    else:
        for row in np.degrees(prop.q):
            print("  " + " ".join(f"{v:9.3f}" for v in row) + "  [deg]")
    return EXIT_OK


def cmd_sequential(args) -> int:
    from dataclasses import replace

    from calib_oed.design_file import write_design_csv
    from calib_oed.io_utils import atomic_write_text
    from calib_oed.sequential import SEQUENTIAL_SQP, run_sequential

    s = _setup(args.scene)
    settings = SEQUENTIAL_SQP if not args.iterations else replace(SEQUENTIAL_SQP, max_iterations=args.iterations)
    if args.measured:
        return _sequential_step(s, args, settings)

    def progress(step):
        _say(args, f"  {step.n_measurements:>4} measured ({step.method}): predicted KPI sigma max "
                   f"{step.sigma_mm.max():.5f} mm, TCP error max {step.tcp_error_mm.max():.5f} mm")

    _say(args, f"scene {s.scene.name!r}: sequential calibration of a simulated robot (truth seed "
               f"{args.truth_seed}) to a KPI sigma of {args.target_sigma:g} mm")
    d = sum(m.dim for m in s.problem.models)
    n_min = -(-len(s.problem.identifiability.free_indices) // d)  # fewest poses that can identify
    grid = [n for n in range(args.grid_step, args.max_measurements + 1, args.grid_step) if n >= n_min]
    result = run_sequential(s, args.target_sigma, batch=args.batch, initial=args.initial, grid=grid,
                            truth_seed=args.truth_seed, max_measurements=args.max_measurements,
                            criterion=args.criterion, settings=settings, seed=args.seed,
                            follow_pose=args.follow_pose, compare=not args.no_compare,
                            compare_settings=_sqp_settings(args), callback=progress,
                            initial_design=args.initial_design, reference_n=args.reference or None)
    paths = {}
    if args.output:
        folder = Path(args.output)
        folder.mkdir(parents=True, exist_ok=True)
        paths["csv"] = write_design_csv(folder / "measured.csv", s.problem.robot, result.q,
                                        comment=f"sequential calibration of {s.scene.name}, "
                                        "configurations in measurement order")
        paths["json"] = atomic_write_text(folder / "sequential.json",
                                          json.dumps(result.to_dict(), indent=2) + "\n")
    if args.json:
        data = result.to_dict()
        data["files"] = {k: str(v) for k, v in paths.items()}
        print(json.dumps(data, indent=2))
    else:
        print(result.summary())
        if paths:
            print(f"wrote {paths['csv']} and {paths['json']}")
    if result.check():
        return EXIT_INTERNAL
    return EXIT_OK


def cmd_scenes(args) -> int:
    from calib_oed.scene import scene_names

    if args.json:
        print(json.dumps(scene_names()))
        return EXIT_OK
    for name in scene_names():
        print(name)
    return EXIT_OK


def cmd_robots(args) -> int:
    from calib_oed.robot_registry import robot_names

    if args.json:
        print(json.dumps(robot_names()))
        return EXIT_OK
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

    def scene_arg(p):
        p.add_argument("scene", help="shipped scene name or scene file path")

    def design_args(p, positional=True):
        if positional:
            p.add_argument("design", nargs="?", metavar="DESIGN", help="design file: DIR/design.yaml or "
                           "a CSV (header = joint names, rad); default: -n random feasible poses")
        p.add_argument("--design", dest="design_option", metavar="FILE",
                       help="design file (same as DESIGN)" if positional else
                       "design file: design.yaml or CSV; default: -n random feasible poses")
        p.add_argument("-n", type=_positive_int, default=60, help="random feasible poses (default 60)")
        p.add_argument("--seed", type=int, default=0, help="seed of the random design (default 0)")

    p = sub.add_parser("demo", help="the whole job on a scene: design, simulated calibration, "
                       "export, Monte Carlo")
    p.add_argument("scene", nargs="?", default=DEFAULT_SCENE, help=f"default {DEFAULT_SCENE}")
    design_args(p, positional=False)
    p.add_argument("--truth-seed", type=int, default=1, help="seed of the simulated robot (default 1)")
    p.add_argument("-N", "--runs", type=_positive_int, default=200, help="Monte Carlo runs (default 200)")
    p.add_argument("--mc-seed", type=int, default=0, help="Monte Carlo seed (default 0)")
    p.add_argument("--jobs", type=_positive_int, default=2, help="parallel workers (default 2)")
    p.add_argument("-o", "--output", help="folder for the design and the calibrated URDF "
                   "(default: a temporary folder)")
    p.add_argument("--no-optimise", action="store_true", help="skip the design optimisation "
                   "(use the heuristic design)")
    p.add_argument("--iterations", type=_positive_int, help="limit the SQP iterations")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_demo)

    from calib_oed.criteria import CRITERIA

    p = sub.add_parser("design", help="optimal measurement configurations (SQP from a heuristic start)")
    scene_arg(p)
    p.add_argument("-n", type=_positive_int, default=60, help="number of poses (default 60)")
    p.add_argument("--criterion", default="kpi", choices=CRITERIA,
                   help="kpi (default: the paper's KPI A-criterion), params (A on the parameter "
                   "covariance, mm and mrad), D, E, or an observability index O1..O5")
    p.add_argument("--start", default="heuristic", metavar="heuristic|exchange|CSV",
                   help="start design: random feasible poses (default), the exchange algorithm's "
                   "best poses of a 3000-pose feasible pool (better designs), or a design CSV")
    p.add_argument("--seed", type=int, default=0, help="seed of the heuristic start (default 0)")
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
    p.add_argument("-o", "--output", metavar="DIR", help="write DIR/design.yaml and DIR/design.csv")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_design)

    p = sub.add_parser("evaluate", help="KPI sigma, criterion values, margins and mesh check of a design")
    scene_arg(p)
    p.add_argument("design", metavar="DESIGN", help="design file: DIR/design.yaml or a CSV")
    p.add_argument("--criterion", default="kpi", choices=CRITERIA, help="criterion of the "
                   "contribution plot (default kpi); all criterion values are always reported")
    p.add_argument("--no-mesh-check", action="store_true", help="skip the URDF mesh check")
    p.add_argument("--plot", metavar="DIR", help="write DIR/kpi_ellipsoid.png and DIR/pose_contributions.png")
    p.add_argument("--certificate", action="store_true", help="optimality certificate: a lower bound "
                   "on the criterion of any design of this many poses, and this design's efficiency "
                   "(criteria kpi, params, D; 10-60 s)")
    p.add_argument("--pool", type=_positive_int, default=3000,
                   help="feasible candidate poses of the certificate (default 3000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the certificate's pool (default 0)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("compare", help="designs side by side: KPI variance, criteria, feasibility")
    scene_arg(p)
    p.add_argument("designs", nargs="+", metavar="DESIGN", help="design files (design.yaml or CSV)")
    p.add_argument("--plot", metavar="FILE", help="write the 95 %% KPI ellipsoid projections "
                   "(.png, .svg or .pdf)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("validate", help="residuals of a calibration on separate validation measurements")
    scene_arg(p)
    p.add_argument("calibrated", metavar="CALIBRATED", help="the folder `identify -o DIR` wrote "
                   "(calibrated URDF and sensor YAML), or its URDF")
    p.add_argument("measurements", help="validation measurement CSV (docs/data_format.md)")
    p.add_argument("--length-unit", choices=("m", "mm"), help="if the file states no units")
    p.add_argument("--angle-unit", choices=("rad", "deg"), help="if the file states no units")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("view", help="the scene and a design in the browser (meshcat), or a static HTML")
    scene_arg(p)
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
    p.add_argument("--json", action="store_true", help="machine-readable output (with --html)")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("feasibility", help="constraint pairs, a feasible design, margins, mesh check")
    scene_arg(p)
    design_args(p)
    p.add_argument("-o", "--output", metavar="CSV", help="write the design (joint names, rad)")
    p.add_argument("--no-mesh-check", action="store_true", help="skip the URDF mesh check")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_feasibility)

    p = sub.add_parser("simulate", help="simulated tracker measurements of a random true robot")
    scene_arg(p)
    design_args(p)
    p.add_argument("--truth-seed", type=int, default=1, help="seed of the simulated robot (default 1)")
    p.add_argument("-o", "--output", required=True, metavar="CSV", help="measurement file to write")
    p.add_argument("--truth", metavar="YAML", help="where to write the true parameters "
                   "(default: <output>_truth.yaml)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--quiet", action="store_true", help="print nothing")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("identify", help="identify the parameters from a measurement file")
    scene_arg(p)
    p.add_argument("measurements", help="measurement CSV (docs/data_format.md)")
    p.add_argument("-o", "--output", metavar="DIR", help="write calibrated URDF, sensor YAML, report")
    p.add_argument("--loss", default="linear", choices=("linear", "huber", "soft_l1"),
                   help="linear (default; Levenberg-Marquardt), or a robust loss")
    p.add_argument("--length-unit", choices=("m", "mm"), help="if the file states no units")
    p.add_argument("--angle-unit", choices=("rad", "deg"), help="if the file states no units")
    p.add_argument("--truth", metavar="YAML", help="true parameters of a simulation: report TCP errors")
    p.add_argument("--plot", metavar="FILE", help="write the residual plot (.png, .svg or .pdf)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("montecarlo", help="simulated calibrations against the predicted KPI covariance")
    scene_arg(p)
    design_args(p)
    p.add_argument("-N", "--runs", type=_positive_int, default=500, help="runs (default 500)")
    p.add_argument("--mc-seed", type=int, default=0, help="Monte Carlo seed (default 0)")
    p.add_argument("--jobs", type=_positive_int, default=2, help="parallel workers (default 2)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_montecarlo)

    p = sub.add_parser("study", help="a study over robots, scenes, criteria and seeds (the paper's tables)")
    p.add_argument("config", metavar="CONFIG", help="study file (YAML), or a shipped study: "
                   "kuka, notional90, smoke")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="results folder; a rerun resumes it (finished cases are not recomputed)")
    p.add_argument("--jobs", type=_positive_int, help="parallel local workers (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run the cases on this Dask scheduler "
                   "(needs the calib_oed[dask] extra)")
    p.add_argument("--no-report", action="store_true", help="skip DIR/report.md and the figures")
    p.add_argument("--no-figures", action="store_true", help="report without figures")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_study)

    p = sub.add_parser("sequential", help="sequential calibration of a simulated robot to a KPI "
                       "precision target, next to fixed and heuristic designs")
    scene_arg(p)
    p.add_argument("--target-sigma", required=True, type=_length_mm, metavar="LENGTH",
                   help="stop when every working configuration's predicted KPI sigma is at most this: "
                   "0.02mm, 20um or 0.02 (mm)")
    p.add_argument("--batch", type=_positive_int, default=5, help="poses per proposal (default 5)")
    p.add_argument("--measured", metavar="MEASUREMENTS", help="a real calibration, one step: identify "
                   "from this measurement file, then say whether the target is reached or write the "
                   "next --batch poses to DIR/next.csv (no simulation)")
    p.add_argument("--length-unit", choices=("m", "mm"), help="with --measured: if the file states no units")
    p.add_argument("--angle-unit", choices=("rad", "deg"), help="with --measured: if the file states no units")
    p.add_argument("--initial", type=_positive_int, default=15,
                   help="poses measured first (default 15)")
    p.add_argument("--initial-design", default="heuristic", choices=("heuristic", "optimal"),
                   help="the first poses: random feasible (default) or the KPI-optimal design of "
                   "that size at nominal")
    p.add_argument("--max-measurements", type=_positive_int, default=120,
                   help="stop after this many measured poses (default 120)")
    p.add_argument("--criterion", default="kpi", choices=CRITERIA, help="criterion of the proposals "
                   "(default kpi)")
    p.add_argument("--truth-seed", type=int, default=1, help="seed of the simulated robot and its "
                   "noise (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the designs and candidate pools (default 0)")
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
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_sequential)

    p = sub.add_parser("scenes", help="list the shipped scenes")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_scenes)
    p = sub.add_parser("robots", help="list the robots loadable by name")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_robots)
    for name in COMPLIANCE_COMMANDS:
        p = sub.choices[name]
        p.add_argument("--compliance", action="store_true", help="model joint compliance under "
                       "gravity: one compliance parameter per joint, with the scene's "
                       "robot.compliance payload (docs/scenes.md)")
        p.add_argument("--payload-kg", type=float, metavar="KG", help="payload mass of the "
                       "compliance model (implies --compliance; centre of mass from the scene)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = argv
    try:
        _apply_compliance(args)
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
