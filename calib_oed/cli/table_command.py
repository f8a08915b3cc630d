"""The ``table`` command: a robot (nominal or calibrated) as a DH, modified DH or Hayati parameter
table, and a table (a vendor data sheet, a controller backup) as a URDF
(docs/parameter_tables.md, docs/cli.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib_oed.cli._common import EXIT_OK, _say
from calib_oed.exceptions import ParameterTableError

#: ``--convention`` values: the names of :data:`calib_oed.model.dh.CONVENTIONS` and two short ones.
CONVENTION_NAMES = {"classic_dh": "classic_dh", "dh": "classic_dh", "modified_dh": "modified_dh",
                    "mdh": "modified_dh", "hayati": "hayati"}

#: Largest round-trip difference [m, rad] a table may have without being named (issue 32).
EXACT = 1e-9

#: Random configurations (seed 0) of the round-trip checks.
CHECK_CONFIGURATIONS = 50


def add_table_parser(sub) -> None:
    """Register ``calib-oed table [SCENE [CALIBRATION]] [--convention C] [--to-urdf TABLE] [-o FILE]``."""
    p = sub.add_parser("table", help="the scene's robot, or its calibration, as a DH, modified DH or "
                       "Hayati parameter table (YAML); with --to-urdf, a table as a URDF")
    p.add_argument("scene", nargs="?", help="shipped scene name or scene file path (the robot and its "
                   "tool frame); with --to-urdf, optional: the robot the table is compared with")
    p.add_argument("calibration", nargs="?", metavar="CALIBRATION", help="the folder `calib-oed identify "
                   "-o DIR` wrote, or its URDF: the table of the calibrated robot (default: the nominal one)")
    p.add_argument("--convention", default=None, choices=tuple(CONVENTION_NAMES),
                   help="classic_dh (dh), modified_dh (mdh, Craig; default) or hayati (classic rows, "
                   "Hayati's where consecutive axes are nearly parallel)")
    p.add_argument("--parallel-angle", type=float, default=None, metavar="DEG", help="hayati: axes within "
                   "this angle get a Hayati row (default 5.73 deg = 0.1 rad)")
    p.add_argument("--to-urdf", metavar="TABLE", help="write the parameter table file TABLE (YAML, "
                   "docs/parameter_tables.md) as a URDF to -o FILE.urdf instead")
    p.add_argument("-o", "--output", metavar="FILE", help="file to write: the table (.yaml or .yml), or "
                   "with --to-urdf the URDF (.urdf); without it the table is printed")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_table, outputs={"output": "file"})


def _check_arguments(args) -> None:
    out = Path(args.output) if args.output else None
    if args.to_urdf:
        if args.calibration:
            raise ParameterTableError("table --to-urdf: a CALIBRATION is exported as a table, not "
                                      "imported; leave out CALIBRATION (or --to-urdf)")
        if out is None or out.suffix.lower() != ".urdf":
            raise ParameterTableError("table --to-urdf: give the URDF to write, -o FILE.urdf")
        if Path(args.to_urdf).resolve() == out.resolve():
            raise ParameterTableError(f"-o {out} is the table --to-urdf reads; give another file")
        if args.parallel_angle is not None or args.convention is not None:
            raise ParameterTableError("table --to-urdf: the table file states its convention; leave out "
                                      "--convention and --parallel-angle")
        return
    if not args.scene:
        raise ParameterTableError("table: give SCENE (the robot to write as a table) or --to-urdf TABLE")
    if out is not None and out.suffix.lower() not in (".yaml", ".yml"):
        raise ParameterTableError(f"-o {out}: a parameter table is YAML; give a .yaml or .yml file "
                                  "(a URDF is written with --to-urdf)")
    args.convention = args.convention or "modified_dh"
    if args.parallel_angle is not None and (CONVENTION_NAMES[args.convention] != "hayati"
                                            or not 0 < args.parallel_angle < 90):
        raise ParameterTableError(f"--parallel-angle {args.parallel_angle:g}: give an angle in (0, 90) deg, "
                                  "with --convention hayati")


def _f(value: float, width: int = 0) -> str:
    """``value`` with 6 decimals, no ``-0.000000``."""
    text = f"{value:.6f}"
    return (text.lstrip("-") if float(text) == 0 else text).rjust(width)


def _row_lines(table) -> list[str]:
    """The table in mm and degrees, one line per joint."""
    deg, mm = np.degrees, 1e3
    pose = lambda v: (f"xyz [mm] {', '.join(_f(mm * x) for x in v[:3])}; "  # noqa: E731
                      f"rpy [deg] {', '.join(_f(deg(x)) for x in v[3:])}")
    w = max(16, *(len(r.joint) for r in table.rows))
    lines = [f"  base (T_W,0): {pose(table.base)}",
             f"  {'joint':<{w}} {'kind':<6} {'alpha deg':>12} {'a mm':>14} {'theta deg':>12} {'d mm':>14} "
             f"{'beta deg':>10}"]
    for r in table.rows:
        lines.append(f"  {r.joint:<{w}} {r.kind:<6} {_f(deg(r.alpha), 12)} {_f(mm * r.a, 14)} "
                     f"{_f(deg(r.theta), 12)} {_f(mm * r.d, 14)} {_f(deg(r.beta), 10)}")
    lines.append(f"  tool (T_n,{table.tool_frame}): {pose(table.tool)}")
    return lines


def _residual_note(dp: float, dr: float, what: str) -> str | None:
    if dp <= EXACT and dr <= EXACT:
        return None
    return (f"NAMED: {what} misses the model by {dp:.2g} m and {dr:.2g} rad (> {EXACT:g}): the convention "
            "cannot hold these axes exactly (nearly parallel axes put DH's common normal far away); "
            "use --convention hayati")


def _far_rows(table, robot) -> tuple[list[str], str | None]:
    """Rows whose a or d exceed the arm's stretched length, and the note that names them (None:
    none): nearly parallel axes put DH's common normal far away, so such a table can reproduce the
    model in floating point only through huge lengths that cancel."""
    from calib_oed.model.inverse_kinematics import characteristic_length

    length = characteristic_length(robot)
    far = [r for r in table.rows if max(abs(r.a), abs(r.d)) > length]
    if not far:
        return [], None
    worst = max(max(abs(r.a), abs(r.d)) for r in far)
    return [r.joint for r in far], (
        f"NAMED: {', '.join(r.joint for r in far)}: a or d beyond the arm's stretched length "
        f"({length:.3g} m; up to {worst:.3g} m): nearly parallel axes put DH's common normal far away, "
        "and lengths like these cancel only in floating point, not on a controller; use --convention hayati")


def _export(args) -> int:
    from calib_oed.calibration.compensation_files import load_calibration
    from calib_oed.calibration.problem import CalibrationProblem
    from calib_oed.io.parameter_table import table_yaml_text, write_parameter_table
    from calib_oed.model.dh import PARALLEL_ANGLE, compute_table
    from calib_oed.scene.reader import load_scene

    scene = load_scene(args.scene)
    robot, source = scene.robot, "nominal"
    if args.calibration:
        space = CalibrationProblem.from_scene(scene).space
        robot, _, files = load_calibration(space, args.calibration)
        source = f"calibrated: {files['urdf']}"
    convention = CONVENTION_NAMES[args.convention]
    angle = PARALLEL_ANGLE if args.parallel_angle is None else float(np.radians(args.parallel_angle))
    table = compute_table(robot, convention, parallel_angle=angle, check=CHECK_CONFIGURATIONS, seed=0)
    note = _residual_note(table.residual_m, table.residual_rad, f"the {convention} table")
    far, far_note = _far_rows(table, robot)
    written = str(write_parameter_table(args.output, table)) if args.output else None
    if args.json:
        import yaml

        print(json.dumps({"scene": scene.name, "robot": source, "table": yaml.safe_load(table_yaml_text(table)),
                          "exact": note is None, "far_rows": far, "written": written}, indent=2))
        return EXIT_OK
    _say(args, f"{convention} table of {robot.name} ({source}), tool frame {table.tool_frame}; "
               "T_W,F(q) = base * prod A_i(q_i) * tool, theta_i = q_i + theta")
    for line in _row_lines(table):
        _say(args, line)
    _say(args, f"  round trip: the table reproduces the model to {table.residual_m:.2g} m and "
               f"{table.residual_rad:.2g} rad ({CHECK_CONFIGURATIONS} random configurations, seed 0)")
    for n in (note, far_note):
        if n:
            _say(args, f"  {n}")
    if written:
        _say(args, f"wrote {written}")
    return EXIT_OK


def _to_urdf(args) -> int:
    from calib_oed.io.atomic import atomic_write_text
    from calib_oed.io.parameter_table import read_parameter_table
    from calib_oed.model.dh_urdf import table_urdf_text
    from calib_oed.model.robot import load_robot

    table = read_parameter_table(args.to_urdf)
    written = atomic_write_text(args.output, table_urdf_text(table))
    robot = load_robot(str(written), tool_frame=table.tool_frame)
    q = robot.random_configurations(CHECK_CONFIGURATIONS, 0)
    dp, dr = table.compute_difference(robot, q)        # the URDF as Pinocchio reads it vs the table
    out = {"table": str(args.to_urdf), "convention": table.convention, "joints": len(table.rows),
           "written": str(written), "round_trip_m": dp, "round_trip_rad": dr}
    notes = [n for n in [_residual_note(dp, dr, "the URDF written")] if n]
    if args.scene:
        from calib_oed.scene.reader import load_scene

        scene = load_scene(args.scene)
        if len(scene.robot.joint_names) != len(table.rows):
            raise ParameterTableError(f"{args.to_urdf}: {len(table.rows)} joints, the scene robot "
                                      f"{scene.robot.name!r} {len(scene.robot.joint_names)}: not its table")
        out["scene_difference_m"], out["scene_difference_rad"] = table.compute_difference(
            scene.robot, scene.robot.random_configurations(CHECK_CONFIGURATIONS, 0))
    if args.json:
        print(json.dumps(out, indent=2))
        return EXIT_OK
    _say(args, f"{table.convention} table {args.to_urdf} ({len(table.rows)} joints, tool frame "
               f"{table.tool_frame}) as a URDF; read back by Pinocchio it reproduces the table to "
               f"{dp:.2g} m and {dr:.2g} rad ({CHECK_CONFIGURATIONS} random configurations, seed 0)")
    if args.scene:
        _say(args, f"  against the scene robot {scene.robot.name!r} ({scene.robot.tool_frame}): TCP differs by "
                   f"up to {1e3 * out['scene_difference_m']:.4g} mm and "
                   f"{1e3 * out['scene_difference_rad']:.4g} mrad (same joint values)")
    for n in notes:
        _say(args, f"  {n}")
    _say(args, f"wrote {written}")
    return EXIT_OK


def cmd_table(args) -> int:
    _check_arguments(args)
    return _to_urdf(args) if args.to_urdf else _export(args)


__all__ = ["CONVENTION_NAMES", "add_table_parser", "cmd_table"]
