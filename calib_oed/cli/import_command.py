"""The ``import`` command: a laser tracker's export into a calib_oed measurement file
(docs/data_format.md#tracker-exports), ready for ``identify``."""

from __future__ import annotations

import json

from calib_oed.cli._common import EXIT_OK, _say, _setup, add_command, add_json_quiet
from calib_oed.cli.checks import ArgumentError


def add_import_parser(sub) -> None:
    """Register ``calib-oed import SCENE EXPORT -o CSV [--layout] [--design] [--smrs] [--columns]``."""
    p = add_command(sub, "import", cmd_import, "a laser tracker's export (a pose array or a point export) "
                    "into a measurement file for identify", outputs={"output": "file"})
    p.add_argument("export", metavar="EXPORT", help="the tracker's export file")
    p.add_argument("-o", "--output", required=True, metavar="CSV", help="measurement file to write")
    p.add_argument("--layout", default="auto", choices=("auto", "poses", "points"),
                   help="poses: headerless rows of joint values then each SMR's x, y, z; points: "
                   "one point per row under a header (target id, X, Y, Z, U95, ...); auto (default): "
                   "numbers on the first line mean poses")
    p.add_argument("--design", metavar="DESIGN", help="points layout: the design the robot ran "
                   "(its rows are the poses the target ids count from 1)")
    p.add_argument("--smrs", metavar="LIST", help="poses: the scene reflectors of the file's x, y, z "
                   "triplets in file order (default: all, in scene order); points: the file's SMR ids "
                   "in scene-reflector order, or ID=NAME pairs")
    p.add_argument("--columns", metavar="LIST", help="poses: a name for every column (joint names, "
                   "<smr>.x, <smr>.y, <smr>.z, skip); points: ROLE=HEADER pairs for headers the "
                   "defaults miss (roles: target, x, y, z, u95, temperature, pressure, time, qw..qz)")
    p.add_argument("--target-pattern", metavar="REGEX", help="points: how a target id names its "
                   "pose and SMR, groups (?P<pose>...) and (?P<smr>...) (default: the first number is "
                   "the pose, what follows a separator the SMR: P001_A, pose12-smr0)")
    p.add_argument("--length-unit", choices=("mm", "m"), default="mm", help="the file's length unit (default mm)")
    p.add_argument("--angle-unit", choices=("deg", "rad"), default="deg", help="poses: the joint "
                   "angles' unit (default deg)")
    p.add_argument("--joints", choices=("controller", "urdf"), help="poses: the joint values are the "
                   "controller's (mapped by the scene's controller: block) or URDF joint values (default: "
                   "controller when the scene has the block, else urdf)")
    add_json_quiet(p, "print nothing")


def _pairs(text: str, option: str) -> dict[str, str]:
    out = {}
    for item in (s.strip() for s in text.split(",") if s.strip()):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ArgumentError(f"{option}: expected ID=NAME pairs separated by commas, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def _options(args, names: list[str], layout: str, controller=None) -> dict:
    opts: dict = {"length_unit": args.length_unit}
    if layout == "poses":
        if args.target_pattern or args.design:
            raise ArgumentError("import: --target-pattern and --design belong to the points layout; "
                                "a pose array carries its joint values")
        if args.joints == "controller" and controller is None:
            raise ArgumentError("--joints controller: the scene has no controller: block; add one "
                                "(docs/scenes.md) or give --joints urdf")
        opts["angle_unit"] = args.angle_unit
        opts["controller"] = controller if args.joints != "urdf" else None
        if args.smrs:
            opts["smrs"] = [s.strip() for s in args.smrs.split(",") if s.strip()]
        if args.columns:
            opts["columns"] = [s.strip() for s in args.columns.split(",")]
        return opts
    if args.joints:
        raise ArgumentError("import: --joints belongs to the poses layout; a design file states its "
                            "own convention (# joints: controller)")
    if args.smrs:
        if "=" in args.smrs:
            opts["smrs"] = _pairs(args.smrs, "--smrs")
        else:
            ids = [s.strip() for s in args.smrs.split(",") if s.strip()]
            if len(ids) > len(names):
                raise ArgumentError(f"--smrs: {len(ids)} SMR ids for the scene's {len(names)} "
                                    f"reflectors {', '.join(names)}")
            opts["smrs"] = dict(zip(ids, names, strict=False))
    if args.columns:
        opts["columns"] = _pairs(args.columns, "--columns")
    if args.target_pattern:
        opts["target_pattern"] = args.target_pattern
    return opts


def cmd_import(args) -> int:
    from calib_oed.calibration.workflow import write_measurement_file
    from calib_oed.io.tracker_import import detect_layout, read_tracker_export

    s = _setup(args.scene)
    robot, names = s.problem.robot, s.reflector_names
    design_q = None
    if args.design:
        from calib_oed.io.design_file import read_design_file

        design_q = read_design_file(args.design, robot, controller=s.scene.controller)
    layout = detect_layout(args.export) if args.layout == "auto" else args.layout
    options = _options(args, names, layout, s.scene.controller)
    result = read_tracker_export(args.export, robot, names, layout=layout, design_q=design_q, **options)
    joints = f"controller {options['controller'].name}" if options.get("controller") else "urdf"
    write_measurement_file(s, args.output, result.mset,
                           f"imported by calib_oed from {args.export} ({result.layout} layout): "
                           f"{result.summary()}")
    if args.json:
        print(json.dumps({"measurements": str(args.output), "rows": int(len(result.mset.q)),
                          "poses": result.poses, "skipped": result.skipped, "layout": result.layout,
                          "sigma_column": result.mset.sigma is not None,
                          "joints": joints if layout == "poses" else "design"}, indent=2))
        return EXIT_OK
    _say(args, f"{result.summary()}{f'; joint values: {joints}' if layout == 'poses' else ''}\nwrote {args.output}")
    return EXIT_OK
