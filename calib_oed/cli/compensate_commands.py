"""The ``compensate`` command: a robot program with its targets corrected by a calibration
(docs/compensate.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib_oed.cli._common import EXIT_OK, _say
from calib_oed.exceptions import CompensationError


def add_compensate_parser(sub) -> None:
    """Register ``calib-oed compensate SCENE CALIBRATION PROGRAM [-o OUT]``."""
    p = sub.add_parser("compensate", help="correct the targets of a robot program (KRL, RAPID, TP, "
                       "URScript, CSV) with a calibration: the calibrated robot reaches them")
    p.add_argument("scene", help="shipped scene name or scene file path (the nominal robot)")
    p.add_argument("calibration", metavar="CALIBRATION", help="the folder `calib-oed identify -o DIR` "
                   "wrote (calibrated URDF, sensor YAML, identification.json), or its URDF")
    p.add_argument("program", metavar="PROGRAM", help="program file: .src/.dat (KRL), .mod (RAPID), "
                   ".ls (FANUC TP), .script (URScript) or .csv (targets)")
    p.add_argument("-o", "--output", metavar="OUT", help="folder for the compensated files, same names "
                   "(default: PROGRAM's folder/compensated); never the program's own folder")
    p.add_argument("--tool", metavar="X,Y,Z,RX,RY,RZ", help="TCP in the scene's tool frame [mm, deg; "
                   "R = Rz Ry Rx] unless the program declares it (default: the tool frame itself)")
    p.add_argument("--base", metavar="X,Y,Z,RX,RY,RZ", help="base frame of Cartesian targets in the robot "
                   "base [mm, deg] unless the program declares it (default: the robot base)")
    p.add_argument("--singular", type=float, default=None, metavar="SIGMA",
                   help="name targets whose smallest scaled Jacobian singular value is below this "
                   "(default 0.01, docs/compensate.md)")
    p.add_argument("--payload-kg", type=float, default=None, metavar="KG", dest="working_payload_kg",
                   help="payload on the tool while the program runs, for a calibration that identified joint "
                   "compliance (default: the scene's robot.compliance payload, else the one identified under; "
                   "the centre of mass stays the scene's, else the identified one)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_compensate, outputs={"output": "dir"})


def _payload_mass(mass: float | None) -> float | None:
    """``--payload-kg``: the payload mass the program runs with [kg], or None."""
    from calib_oed.scene.joint_keys import MAX_PAYLOAD_KG

    if mass is not None and not 0 <= mass <= MAX_PAYLOAD_KG:
        raise CompensationError(f"--payload-kg {mass:g}: give the payload mass from 0 to {MAX_PAYLOAD_KG:g} kg")
    return mass


def _deflection_text(loaded) -> str:
    """One line: what of the joints' deflection the compensation models, and the payload."""
    d = loaded.deflection
    if d is None:
        return ""
    parts = (["joint compliance under gravity, " + loaded.payload] if d.compliance is not None else []) + (
        [f"{len(d.gains)} joint gains and coupling ratios"] if d.gains is not None else [])
    return "compensated with " + "; ".join(parts)


def _note_negative_compliance(loaded, joint_names) -> None:
    """A note when the calibration's joint compliance is negative somewhere: a negative stiffness is
    not physical (identify calls it implausible), and its deflection can make the targets worse."""
    import warnings

    from calib_oed.exceptions import CalibOedNote

    c = None if loaded.deflection is None else loaded.deflection.compliance
    if c is None:
        return
    negative = [f"{name} ({1.0 / v:.3g} N·m/rad)" for name, v in zip(joint_names, c, strict=True) if v < 0]
    if negative:
        warnings.warn(CalibOedNote(
            f"the calibration's joint compliance is negative on {', '.join(negative)}: a negative stiffness is not "
            "physical (it absorbs an error the model has no term for), and compensating with it can move the "
            "targets the wrong way; identify without --compliance, or with more poses"), stacklevel=2)


def _frame(text: str | None, option: str):
    if text is None:
        return None
    from calib_oed.program.parse.poses import from_euler_mm_deg

    try:
        values = [float(s) for s in text.replace(" ", ",").split(",") if s]
    except ValueError:
        values = []
    if len(values) != 6 or not np.all(np.isfinite(values)):
        raise CompensationError(f"{option} {text!r}: give six numbers X,Y,Z,RX,RY,RZ in mm and degrees "
                                "(R = Rz(RZ) Ry(RY) Rx(RX))")
    return from_euler_mm_deg(*values)


def cmd_compensate(args) -> int:
    from calib_oed.calibration.compensation import SINGULAR_THRESHOLD
    from calib_oed.calibration.compensation_files import load_compensation
    from calib_oed.calibration.problem import CalibrationProblem
    from calib_oed.io.atomic import atomic_write_files
    from calib_oed.model.parameters import ParameterSpace
    from calib_oed.program.compensate import compensate_program
    from calib_oed.program.parse.files import program_files, read_program
    from calib_oed.scene.reader import load_scene

    scene = load_scene(args.scene)
    files = program_files(args.program)
    out = Path(args.output) if args.output else files[0].parent / "compensated"
    if out.resolve() == files[0].parent.resolve():
        raise CompensationError(f"-o {out}: that is the program's own folder; the compensated files keep "
                                "their names, so give another folder")
    threshold = SINGULAR_THRESHOLD if args.singular is None else args.singular
    if not threshold >= 0:
        raise CompensationError(f"--singular {args.singular}: give a threshold >= 0 (default 0.01)")
    problem = CalibrationProblem.from_scene(scene)
    space = problem.space      # the working payload: the scene's robot.compliance block's, even if disabled
    if scene.compliance is not None and space.compliance is None:
        space = ParameterSpace(space.robot, space.tracker_placement0, space.reflector_offsets0,
                               compliance=scene.compliance.payload)
    loaded = load_compensation(space, args.calibration, _payload_mass(args.working_payload_kg))
    if args.working_payload_kg is not None and not loaded.payload:
        raise CompensationError(f"--payload-kg {args.working_payload_kg:g}: the calibration {loaded.files['sensor']} "
                                "identified no joint compliance, so the payload changes nothing; leave it out")
    cal_files = loaded.files
    _note_negative_compliance(loaded, scene.robot.joint_names)
    parsed, encodings = read_program(args.program, scene.robot.joint_names)
    result = compensate_program(parsed, scene.robot, loaded.robot, uncertainty=loaded.uncertainty,
                                controller=scene.controller, tool=_frame(args.tool, "--tool"),
                                base=_frame(args.base, "--base"), home=problem.kpi.configurations[0],
                                singular_threshold=threshold, deflection=loaded.deflection,
                                joint_range=loaded.joint_range)
    out.mkdir(parents=True, exist_ok=True)
    written = [str(p) for p in atomic_write_files({out / name: text.encode(encodings[name])  # .src/.dat as a pair
                                                   for name, text in result.texts.items()})]
    if args.json:
        data = result.to_dict()
        data.update(scene=scene.name, calibration=cal_files, written=written,
                    joint_deflection=_deflection_text(loaded) or None)
        print(json.dumps(data, indent=2))
        return EXIT_OK
    _say(args, f"scene {scene.name!r}, calibration {cal_files['urdf']}")
    if loaded.deflection is not None:
        _say(args, _deflection_text(loaded))
    _say(args, result.summary())
    _say(args, f"wrote {', '.join(written)}")
    return EXIT_OK
