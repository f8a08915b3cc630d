"""The ``program`` command: an ordered, collision-checked measurement program in a
controller's language (docs/program.md)."""

from __future__ import annotations

import json

import numpy as np

from calib_oed.cli._common import EXIT_OK, _say, add_command, add_json_quiet
from calib_oed.exceptions import ProgramError

#: Formats of ``--format`` (those of :data:`calib_oed.program.formats.FORMATS`).
FORMAT_CHOICES = ("krl", "rapid", "tp", "urscript", "csv")


def add_program_parser(sub) -> None:
    """Register ``calib-oed program SCENE DESIGN [--format F] [--home Q] [-o DIR]``."""
    p = add_command(sub, "program", cmd_program, "an ordered, collision-checked measurement program "
                    "(KUKA KRL, ABB RAPID, FANUC TP, URScript or CSV)", outputs={"output": "dir"})
    p.add_argument("design", metavar="DESIGN", help="design file: DIR/design.yaml or a CSV")
    p.add_argument("--format", default="csv", choices=FORMAT_CHOICES,
                   help="controller language of the program (default csv)")
    p.add_argument("--home", metavar="Q", help="home configuration, comma-separated joint angles "
                   "in degrees (default: the scene's program.home, else its first KPI working "
                   "configuration); write --home=-9,-73,... when it starts with a minus")
    p.add_argument("--dwell", type=float, metavar="SECONDS", help="settle and measure time per "
                   "pose (default: the scene's program.dwell, else 2 s)")
    p.add_argument("--planner-iterations", type=int, metavar="N", help="RRT-Connect iterations per "
                   "blocked move (default: the scene's program.planner_iterations, else 20000); "
                   "a count, not seconds, so the same input gives the same program under any load")
    p.add_argument("--strict", action="store_true", help="stop with an error when a pose cannot "
                   "be reached from home (default: leave it out, named in the output and the files)")
    p.add_argument("--wrap", action="store_true", help="measure each pose at the joint values whole "
                   "turns away that are nearest home (same robot geometry; joints with more than "
                   "360 deg of range)")
    p.add_argument("--name", default="calib_program", help="program/module name (default "
                   "calib_program)")
    p.add_argument("-o", "--output", metavar="DIR", help="write the program files into DIR")
    add_json_quiet(p, "no progress lines")


def _home(text: str | None, robot) -> np.ndarray | None:
    if text is None:
        return None
    parts = [s for s in text.replace(" ", ",").split(",") if s]
    try:
        values = np.array([float(s) for s in parts])
    except ValueError:
        values = None
    n = len(robot.joint_names)
    if values is None or len(values) != n or not np.all(np.isfinite(values)):
        raise ProgramError("--home", text, f"expected {n} comma-separated joint angles in degrees "
                           f"({', '.join(robot.joint_names)})")
    q = np.deg2rad(values)
    outside = [f"{name} = {v:.6g} deg not in [{np.rad2deg(lo):.6g}, {np.rad2deg(hi):.6g}]"
               for name, v, lo, hi, x in zip(robot.joint_names, values, robot.lower, robot.upper, q,
                                             strict=True) if not lo <= x <= hi]
    if outside:
        raise ProgramError("--home", text, "outside the joint limits: " + "; ".join(outside))
    return q


def cmd_program(args) -> int:
    from calib_oed.io.design_file import read_design_file
    from calib_oed.program.build import build_program
    from calib_oed.program.formats import program_texts, write_program
    from calib_oed.program.settings import program_settings_from_scene
    from calib_oed.scene.reader import load_scene

    scene = load_scene(args.scene)
    if not args.name.isidentifier():
        raise ProgramError("--name", args.name, "a program name must be an identifier "
                           "(letters, digits, _)")
    if args.format == "krl":  # the controller's rules for a module name, before the work
        from calib_oed.program.krl import check_module_name

        check_module_name(args.name)
    if args.dwell is not None and not (np.isfinite(args.dwell) and args.dwell >= 0):
        raise ProgramError("--dwell", args.dwell, "expected a settle and measure time in seconds >= 0")
    q = read_design_file(args.design, scene.robot, controller=scene.controller)
    settings = program_settings_from_scene(scene, home=_home(args.home, scene.robot), dwell=args.dwell,
                                           planner_iterations=args.planner_iterations,
                                           skip_unreachable=not args.strict, wrap=args.wrap)
    _say(args, f"ordering and checking {len(q)} poses of {args.design} in scene {scene.name!r} ...")
    program = build_program(scene, q, settings)
    program_texts(program, args.format, args.name)  # the format's checks, before writing
    paths = write_program(program, args.format, args.output, args.name) if args.output else []
    if args.json:
        data = {"scene": scene.name, "design_file": str(args.design), "format": args.format,
                "poses": len(q), "order": [int(k) + 1 for k in program.order],
                "cycle_time_s": program.cycle_times, "solver": program.solver,
                "dwell_s": program.dwell, "stats": program.stats,
                "not_measured": [{"pose": k + 1, "why": why} for k, why in program.skipped],
                "files": [str(p) for p in paths]}
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(program.summary())
    if paths:
        print("wrote " + ", ".join(str(p) for p in paths))
    else:
        print("(no -o DIR given: nothing written)")
    return EXIT_OK
