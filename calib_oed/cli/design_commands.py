"""The design commands: identifiability, design, evaluate, compare, view, feasibility, sequential."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from calib_oed.cli._common import (
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    _design,
    _iterate,
    _mesh_check,
    _model_error_warning,
    _note_deflection,
    _optimise,
    _problem,
    _say,
    _setup,
    _sqp_settings,
)


def cmd_identifiability(args) -> int:
    from calib_oed.calibration.report import format_identifiability, identifiability_dict

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


def cmd_design(args) -> int:
    from calib_oed.exceptions import DesignError
    from calib_oed.io.design_file import read_design_file
    from calib_oed.oed.result import write_design

    s = _setup(args.scene)
    controller = s.scene.controller
    if getattr(args, "controller", False) and (controller is None or not args.output):
        raise DesignError("controller", True, "needs -o DIR and a scene with a 'controller:' block "
                          "(docs/scenes.md)" if controller is None else "needs -o DIR to write to")
    start = args.start
    if args.start not in ("heuristic", "exchange"):
        start = read_design_file(args.start, s.problem.robot, controller=s.scene.controller)
        if args.n is not None and args.n != len(start):
            raise DesignError("n", args.n, f"--start {args.start} has {len(start)} poses and a start "
                              f"file sets the design's size: drop -n, or give a start of {args.n} poses")
        args.n = len(start)
    elif args.n is None:
        args.n = 60
    from calib_oed.calibration.report import KPI_SIGMA_COVERS
    from calib_oed.oed.model_error import default_criterion

    # the criterion: --criterion, else kpi_model if the scene gives robot.model_error, else kpi
    criterion = args.criterion or ("kpi" if args.aggregate == "max" else default_criterion(s.scene))
    # the KPI aggregate: --aggregate, else the scene's kpi.aggregate (for criterion kpi)
    aggregate = args.aggregate or (s.scene.kpi.aggregate if criterion == "kpi" else "mean")
    _note_deflection(s, criterion)
    result = _optimise(s, args, criterion, start, aggregate)
    paths = write_design(args.output, result, s.problem.robot) if args.output else {}
    code = EXIT_INTERRUPTED if result.interrupted else EXIT_OK
    if paths and result.interrupted:  # the CSV goes to the controller: say it there too
        from calib_oed.io.design_file import write_design_csv

        write_design_csv(paths["csv"], s.problem.robot, result.q, comment=(
            f"scene {result.scene}: INTERRUPTED {result.criterion}-optimal design of {result.n} poses, "
            "the best feasible design when the run was stopped (Ctrl-C or SIGTERM)"))
    if paths and getattr(args, "controller", False):  # the controller's angles beside design.csv
        from calib_oed.io.design_file import write_design_csv

        paths["controller_csv"] = write_design_csv(
            Path(args.output) / "design_controller.csv", s.problem.robot, result.q,
            comment=f"scene {result.scene}: {result.criterion}-optimal design of {result.n} poses"
            + (" (INTERRUPTED: the best feasible design when stopped)" if result.interrupted else ""),
            angle_unit=controller.angle, controller=controller)
    winding = _home_winding(s.scene, result.q)
    if args.json:
        data = result.to_dict()
        data["files"] = {k: str(v) for k, v in paths.items()}
        data["joint_window"] = s.pairs.window  # the design's joint ranges (feasibility/window.py)
        data["home_winding"] = winding
        print(json.dumps(data, indent=2))
        return code
    print(result.summary())
    print(KPI_SIGMA_COVERS)  # what the KPI sigma above covers (the measurement noise only)
    print("  " + s.pairs.window)
    if winding:
        print(f"warning: {winding}", file=sys.stderr)
    if paths:
        print(f"wrote {paths['yaml']} and {paths['csv']}"
              + (f" and {paths['controller_csv']} (controller joint values)"
                 if "controller_csv" in paths else "")
              + (" (marked interrupted in design.yaml)" if result.interrupted else ""))
    else:
        print("(no -o DIR given: nothing written)")
    if result.interrupted:
        print("interrupted: the best feasible design found so far"
              + (", written" if paths else "") + "; the certificate was skipped", file=sys.stderr)
    return code


def _home_winding(scene, q) -> str:
    """The program command's warning about poses home may not wind to, said by the design (issue 31)."""
    from calib_oed.exceptions import CalibOedError
    from calib_oed.program.build import home_winding_note
    from calib_oed.program.settings import ProgramSettings, program_settings_from_scene

    try:
        settings = program_settings_from_scene(scene)
    except CalibOedError:  # a bad program: block is the program command's to report
        settings = ProgramSettings()
    return home_winding_note(scene, q, settings)


def cmd_evaluate(args) -> int:
    from calib_oed.calibration.report import format_kpi_sigma
    from calib_oed.oed.design import evaluate_design

    s = _setup(args.scene)
    q, what = _design(s, args)
    result = evaluate_design(s, q, args.criterion, method="given", position_tol=1e-3 * args.position_tol)
    problem = s.problem
    estimable = problem.kpi_estimability()
    mesh = None if args.no_mesh_check else _mesh_check(s, q)
    plots = _evaluate_plots(s, q, args) if args.plot else {}
    certificate = None
    if args.certificate:
        from calib_oed.oed.certificate import certify

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
    print(result.distinct_line().strip())
    print(format_kpi_sigma(problem, result.kpi_sigma_mm * 1e-3, what))
    if len(result.kpi_names) > 1:
        print(f"{len(result.kpi_names)} KPI points: mean variance {result.kpi_variance:.5g} mm² "
              f"(weighted as the scene says), max {result.kpi_max_variance:.5g} mm² "
              f"(sigma {np.sqrt(result.kpi_max_variance):.5f} mm) at {result.kpi_worst}")
    unseen = {f.name for f in problem.identifiability.fixed if not f.redundant_with}
    for e in estimable:
        if not e.estimable and unseen.isdisjoint(e.gauge):
            print(f"  note: {e.label} is estimated relative to the robot base frame the calibration "
                  "defines (the gauge, `calib-oed identifiability`); sigma is relative to that frame")
        elif not e.estimable:
            print(f"  note: {e.label} is NOT estimable: it depends on "
                  f"{', '.join(n for n in e.gauge if n in unseen)}, which no measurement sees")
    print("criterion values (kpi, params: average variance [mm², params in mm and mrad]; D: log det C; "
          "E: largest eigenvalue [mm²]; O1..O5: observability indices, larger is better; kpi_model, "
          "kpi_kriging: mean squared KPI error per axis with the scene's model-error prior [mm²], of the "
          "fit and of the best linear predictor, docs/oed.md):")
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
    from calib_oed.viz.design_plots import plot_pose_contributions
    from calib_oed.viz.plots import plot_kpi_ellipsoids, save_figure

    folder = Path(args.plot)
    folder.mkdir(parents=True, exist_ok=True)
    return {
        "ellipsoid": save_figure(plot_kpi_ellipsoids(s, {"design": q}), folder / "kpi_ellipsoid.png"),
        "contributions": save_figure(plot_pose_contributions(s.problem, q, args.criterion),
                                     folder / "pose_contributions.png"),
    }


def cmd_compare(args) -> int:
    from calib_oed.calibration.report import KPI_SIGMA_COVERS
    from calib_oed.io.design_file import read_design_file
    from calib_oed.oed.design import evaluate_design
    from calib_oed.oed.result import design_label, format_criteria_table, format_design_table

    s = _setup(args.scene)
    labels = [design_label(p) for p in args.designs]
    if len(set(labels)) != len(labels):
        labels = [str(p) for p in args.designs]
    designs = {}
    for label, path in _iterate(args, list(zip(labels, args.designs, strict=True)), "designs"):
        designs[label] = evaluate_design(s, read_design_file(path, s.problem.robot, controller=s.scene.controller),
                                         "kpi", method="given")
    if args.plot:
        from calib_oed.viz.plots import plot_kpi_ellipsoids, save_figure

        save_figure(plot_kpi_ellipsoids(s, {k: d.q for k, d in designs.items()}), args.plot)
    if args.json:
        print(json.dumps({"scene": s.scene.name,
                          "designs": {k: {**d.to_dict(), "file": str(p)}
                                      for (k, d), p in zip(designs.items(), args.designs, strict=True)},
                          "plot": args.plot}, indent=2))
        return EXIT_OK
    print(f"scene {s.scene.name!r}: {len(designs)} designs (ratios relative to the first)")
    print(format_design_table(designs))
    print(KPI_SIGMA_COVERS)
    print()
    print(format_criteria_table(designs))
    if args.plot:
        print(f"wrote {args.plot}")
    return EXIT_OK


def cmd_view(args) -> int:
    import time

    from calib_oed.viz.sessions import open_viewer, write_static_html

    s = _setup(args.scene)
    q = None
    if args.design:
        from calib_oed.io.design_file import read_design_file

        q = read_design_file(args.design, s.problem.robot, controller=s.scene.controller)
    options = {"ellipsoid_scale": args.scale, "level": args.level, "robot_drawing": args.drawing}
    if args.program:
        from calib_oed.program.csv_format import read_program_csv

        robot = s.problem.robot
        options["program"] = read_program_csv(args.program, robot.joint_names, s.scene.controller)
    if args.html:
        view = write_static_html(args.html, s, q, **options)
        if args.json:
            print(json.dumps({"html": str(view.path), "poses": view.info.n_poses,
                              "ellipsoid_scale": view.info.ellipsoid_scale,
                              "ellipsoid_half_axes_mm": np.asarray(view.info.half_axes_mm).tolist(),
                              "notes": list(view.info.notes),
                              "program": None if view.info.program is None else {
                                  "targets": view.info.program.n_targets,
                                  "poses": view.info.program.n_poses, "via_points": view.info.program.n_via,
                                  "animation_s": view.info.program.duration}}, indent=2))
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


def cmd_feasibility(args) -> int:
    import time

    from calib_oed.feasibility.margins import format_margins, margin_report
    from calib_oed.io.design_file import write_design_csv

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


def _sequential_step(s, args, settings) -> int:
    """One step of a real sequential calibration: identify from the file, then stop or propose."""
    from calib_oed.calibration.sanity import check_measurements
    from calib_oed.calibration.workflow import identify_measurements, read_scene_measurements
    from calib_oed.io.atomic import atomic_write_text
    from calib_oed.io.design_file import write_design_csv
    from calib_oed.oed.sequential import SequentialDesigner

    units = {k: v for k, v in (("length_unit", args.length_unit), ("angle_unit", args.angle_unit)) if v}
    mset = read_scene_measurements(s, args.measured, **units)
    # the data fit the scene (units, axes, joint order) before a fit says stop or go on, as identify's
    check_measurements(s.problem.space, mset, args.max_registration_rms * 1e-3, s.reflector_names)
    _, first = np.unique(mset.q, axis=0, return_index=True)
    q = mset.q[np.sort(first)]  # the measured configurations, in measurement order
    result = identify_measurements(s, mset)
    p_hat = np.asarray(result.p)
    designer = SequentialDesigner(s, args.target_sigma, batch=args.batch, criterion=args.criterion,
                                  settings=settings, seed=args.seed + len(q))
    sigma = designer.predicted_sigma_mm(q, p_hat)
    done = bool(sigma.max() <= args.target_sigma)
    warning = _model_error_warning(result)
    data = {"scene": s.scene.name, "measurements": str(args.measured), "rows": int(mset.n),
            "configurations": len(q), "identification_converged": bool(result.converged),
            "target_sigma_mm": args.target_sigma, "kpi_names": list(s.problem.kpi.names),
            "sigma_mm": sigma.tolist(), "sigma_covers": "measurement noise only, the model taken as exact",
            "sigma0": result.sigma0, "model_error_warning": warning,
            "done": done, "next_q_rad": None, "files": {}}
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
        print(f"  predicted KPI sigma at {name}: {sg:.5f} mm (measurement noise only, the model taken as exact)")
    if warning:
        print(f"warning: {warning}")
    if done:
        print(f"target {args.target_sigma:g} mm reached: stop measuring"
              + (" (by the noise-only sigma; the model error above is not in it)" if warning else ""))
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

    from calib_oed.io.atomic import atomic_write_text
    from calib_oed.io.design_file import write_design_csv
    from calib_oed.oed.sequential import SEQUENTIAL_SQP
    from calib_oed.oed.sequential_run import run_sequential

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
