r"""Compensate a robot program: the same files with only the target values changed.

For a parsed program (:mod:`calib_oed.program.parse`) every target becomes nominal
joints :math:`q^0` (URDF, rad): joint targets through the language's unit and the scene's
controller convention (:math:`q = Ac + b`, :mod:`calib_oed.model.controller`), Cartesian
targets :math:`P` (in the base frame) by the nominal inverse kinematics seeded at the
previous target's :math:`q^0` (the first at ``home``; a target whose inverse kinematics
failed is skipped as a seed), so the branch is the one the program moves along. Then :func:`calib_oed.calibration.compensation.compensate_joints`
gives :math:`\hat q` (with the calibration's joint compliance and gains when given a
``deflection``: the commanded joints) and, for Cartesian targets, the pose :math:`P'` the nominal
controller must be given. Joint targets are rewritten with :math:`\hat q` (back in the
controller's convention and unit), Cartesian targets with :math:`P'` in the language's
convention (angles the representation nearest the original, status/turn/confdata as
written). A target whose inverse kinematics did not converge is left as written and
named; one near a singularity or outside the calibrated joint range is compensated and
named. Each target gets a comment with its predicted residual. A move whose point the
parser does not read (a relative move, an undeclared name, a register; the language modules)
is left as written and named in the parser's notes (``file:line``, why), which the report and
``to_dict`` carry.

**Controller configuration.** A KRL, RAPID or TP Cartesian target carries the
configuration the controller solves it in (KUKA's ``S``/``T``, ABB's ``confdata``, FANUC's
configuration string), written as it was. If the compensated joints :math:`\hat q` have
another configuration than :math:`q^0` (:mod:`calib_oed.model.arm_configuration`: a joint
near a turn boundary, or the arm near a singularity), the controller would not reach
:math:`\hat q` from :math:`P'` and those bits: the target is named with what changes.
KRL's ``S``/``T`` are also read: the nominal solution is moved to the declared elbow, wrist
and turns (:func:`_declared_branch`), and a target still on another branch is named.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.calibration.compensation import (
    SINGULAR_THRESHOLD,
    CalibrationUncertainty,
    Compensation,
    calibrated_kinematics,
    compensate_joints,
)
from calib_oed.exceptions import ProgramError
from calib_oed.model.arm_configuration import (
    VENDORS,
    ConfigurationKinematics,
    abb_confdata,
    configuration_changes,
    kuka_status,
)
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.deflected_kinematics import JointDeflection
from calib_oed.model.inverse_kinematics import IkSettings, TcpKinematics
from calib_oed.model.robot import Robot
from calib_oed.program.format_common import CONTROLLER_VALUES, URDF_VALUES
from calib_oed.program.parse.targets import ParsedProgram, Target, rewrite


@dataclass(frozen=True, eq=False)
class CompensatedProgram:
    """A compensated program.

    Attributes:
        parsed: The program as read.
        texts: ``{file name: new text}``.
        compensation: The compensation of every target (in program order).
        changed: Whether each target was rewritten (False: inverse kinematics failed).
        shift_mm: :math:`\\lVert \\hat t(q^0) - t^0(q^0)\\rVert` [mm]: how far the calibrated model
            (deflected, with a ``deflection``) puts the TCP from the target without compensation (n,).
        sources: Where the tool and base came from (``file``, ``given``, ``none``).
        configuration: Per target, what of the controller configuration :math:`\\hat q` changes
            against :math:`q^0` (Cartesian KRL, RAPID and TP targets; empty: nothing).
        branch: Per target, how the configuration the file declares differs from that of the
            nominal solution :math:`q^0` (KRL ``S``/``T``; empty: the same, or none declared).
        limits: Per target, the compensated joints beyond the robot's joint limits (empty: none),
            which the controller refuses.
    """

    parsed: ParsedProgram
    texts: dict[str, str]
    compensation: Compensation
    changed: np.ndarray
    shift_mm: np.ndarray
    sources: dict[str, str]
    configuration: tuple[tuple[str, ...], ...] = ()
    branch: tuple[str, ...] = ()
    limits: tuple[str, ...] = ()

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.parsed.targets]

    def _configuration(self, i: int) -> tuple[str, ...]:
        return self.configuration[i] if self.configuration else ()

    def issues(self) -> list[str]:
        flagged = np.flatnonzero(self.compensation.flagged)
        lines = dict(zip(flagged, self.compensation.issues(self.names), strict=True))
        out = []
        for i, name in enumerate(self.names):
            line = lines.get(i)
            if line is not None and not self.changed[i]:
                line += "; NOT compensated (left as written)"
            if self.branch and self.branch[i]:
                line = (line + "; " if line else f"{name}: ") + self.branch[i]
            if self.limits and self.limits[i]:
                line = (line + "; " if line else f"{name}: ") + self.limits[i]
            if self._configuration(i):
                line = (line + "; " if line else f"{name}: ") + (
                    "the controller configuration changes (" + "; ".join(self._configuration(i))
                    + "): the status, turn or confdata as written would not select the compensated joints")
            if line:
                out.append(line)
        return out

    def to_dict(self) -> dict:
        c = self.compensation
        return {
            "language": self.parsed.language.name, "files": sorted(self.texts), "tool": self.sources["tool"],
            "base": self.sources["base"], "notes": list(self.parsed.notes), "issues": self.issues(),
            "targets": [{"name": t.name, "kind": t.kind, "changed": bool(self.changed[i]),
                         "shift_mm": float(self.shift_mm[i]),
                         "predicted_residual_mm": None if c.predicted_mm is None else float(c.predicted_mm[i]),
                         "joint_correction_deg": float(np.degrees(np.abs(c.correction[i]).max())),
                         "sigma_min": float(c.sigma_min[i]), "in_range": bool(c.in_range[i]),
                         "configuration_changes": list(self._configuration(i)),
                         "beyond_joint_limits": (self.limits[i] or None) if self.limits else None,
                         "declared_configuration": (self.branch[i] or None) if self.branch else None}
                        for i, t in enumerate(self.parsed.targets)],
        }

    def summary(self) -> str:
        c = self.compensation
        n = len(self.names)
        lines = [f"{n} targets ({sum(t.kind == 'joint' for t in self.parsed.targets)} joint, "
                 f"{sum(t.kind == 'pose' for t in self.parsed.targets)} Cartesian) in "
                 f"{', '.join(sorted(self.texts))}; tool from {self.sources['tool']}, base from {self.sources['base']}",
                 f"  {'target':24s} {'kind':5s} {'shift mm':>9s} {'pred. mm':>9s} {'max dq deg':>10s}"]
        for i, t in enumerate(self.parsed.targets):
            pred = "n/a" if c.predicted_mm is None else f"{c.predicted_mm[i]:.4f}"
            lines.append(f"  {t.name[:24]:24s} {t.kind:5s} {self.shift_mm[i]:9.4f} {pred:>9s} "
                         f"{np.degrees(np.abs(c.correction[i]).max()):10.4f}")
        if c.predicted_mm is None:
            lines.append("  no predicted residual: the calibration folder has no identification.json")
        else:
            lines.append(f"  predicted residual after compensation (RMS position error, mm): RMS "
                         f"{np.sqrt(np.mean(c.predicted_mm ** 2)):.4f}, max {c.predicted_mm.max():.4f}")
        lines += [f"  note: {note}" for note in self.parsed.notes]
        lines += [f"  NAMED {line}" for line in self.issues()]
        return "\n".join(lines)


def _unit(target: Target, parsed: ParsedProgram) -> str:
    return target.unit or parsed.language.joint_unit


def _joints_from(target: Target, parsed: ParsedProgram, controller, nq: int) -> np.ndarray:
    v = target.values[:nq]
    c = np.radians(v) if _unit(target, parsed) == "deg" else v
    return controller.to_model(c) if controller is not None else c


def _joints_to(q: np.ndarray, target: Target, parsed: ParsedProgram, controller) -> np.ndarray:
    c = controller.to_controller(q) if controller is not None else q
    unit = _unit(target, parsed)
    return {"deg": np.degrees(c), "rad": c, "rad+deg": np.r_[c, np.degrees(c)]}[unit]


def _comment(name: str, predicted: float | None, flags: list[str], short: bool) -> str:
    if short:       # FANUC TP: 32 characters a line, no ";"
        text = f"{name} " + ("res n/a" if predicted is None else f"res {predicted:.3f}mm")
        return " ".join([text, *flags])
    text = (f"calib_oed: {name} compensated, predicted residual "
            + ("n/a (no identification.json)" if predicted is None else f"{predicted:.4f} mm"))
    return text + "".join(f"; {f}" for f in flags)


def compensate_program(parsed: ParsedProgram, nominal: Robot, calibrated: Robot, *,
                       uncertainty: CalibrationUncertainty | None = None,
                       controller: ControllerConvention | None = None, tool: pin.SE3 | None = None,
                       base: pin.SE3 | None = None, home: np.ndarray | None = None,
                       settings: IkSettings | None = None,
                       singular_threshold: float = SINGULAR_THRESHOLD,
                       deflection: JointDeflection | None = None,
                       joint_range: tuple[np.ndarray, np.ndarray] | None = None) -> CompensatedProgram:
    """Compensate every target of ``parsed`` (module docstring).

    Args:
        tool, base: :math:`T_{F,E}`, :math:`T_{W,B}` unless the program declares them.
        home: Seed of the first Cartesian target (nq,) [rad]; None: the joint-range middle.
        joint_range: ``(lower, upper)`` (nq,) each, the calibrated range (the training joint
            ranges): targets outside it are named; None: the joint limits.
        deflection: The calibration's joint compliance (with the scene's payload) and gains,
            or None (:func:`~calib_oed.calibration.compensation.compensate_joints`).

    Raises:
        ProgramError: a program ``calib-oed program`` wrote for other joints or the other joint
            convention (:func:`check_written_for`).
    """
    check_written_for(parsed, nominal.joint_names, controller)
    settings = settings or IkSettings()
    sources = {"tool": "file" if parsed.tool is not None else "given" if tool is not None else "none (the tool frame)",
               "base": "file" if parsed.base is not None else "given" if base is not None else "none (the world)"}
    tool = parsed.tool or tool or pin.SE3.Identity()
    base = parsed.base or base or pin.SE3.Identity()
    lang, nq = parsed.language, nominal.nq
    nom = TcpKinematics(nominal, tool)
    seed = (nominal.lower + nominal.upper) / 2 if home is None else np.asarray(home, float)
    n = len(parsed.targets)
    q0, ok = np.empty((n, nq)), np.ones(n, bool)
    arm = None
    for i, target in enumerate(parsed.targets):
        if target.kind == "joint":
            q0[i] = _joints_from(target, parsed, controller, nq)
        else:
            pose = base * lang.pose_from(target.values)
            q0[i], err, _, _ = nom.solve(pose, seed, settings)
            if lang.name == "krl" and target.declared and err <= settings.tolerance and nq == 6:
                arm = arm or ConfigurationKinematics(nominal, controller)
                q0[i] = _declared_branch(nom, arm, pose, q0[i], dict(target.declared), settings)
            ok[i] = err <= settings.tolerance
        if ok[i]:       # a failed solve's end point is no branch to follow
            seed = q0[i]
    comp = compensate_joints(nominal, calibrated, q0, tool=tool, base=base, uncertainty=uncertainty,
                             settings=settings, singular_threshold=singular_threshold, deflection=deflection,
                             joint_range=joint_range)
    comp = Compensation(**{**comp.__dict__, "converged": comp.converged & ok})
    cal = calibrated_kinematics(calibrated, deflection, tool, nom.length)
    shift = np.array([1e3 * np.linalg.norm(cal.compute_pose(q).translation - nom.compute_pose(q).translation)
                      for q in q0])
    configuration, branch = _configuration_checks(parsed, nominal, q0, comp, controller)
    limits = tuple(_beyond_limits(nominal, comp.q[i]) if comp.converged[i] else "" for i in range(n))
    values, comments = {}, {}
    short = lang.name == "tp"
    for i, target in enumerate(parsed.targets):
        flags = [] if comp.converged[i] else ["NOT compensated: inverse kinematics failed"]
        if limits[i]:
            flags.append("beyond a joint limit" if not short else "LIMIT")
        if configuration[i]:
            flags.append("CONF" if short else "controller configuration changes: " + ", ".join(configuration[i]))
        if branch[i]:
            flags.append(branch[i].split(":")[0])
        if comp.near_singular[i]:
            flags.append("near singularity" if not short else "SING")
        if not comp.in_range[i]:
            flags.append("outside calibrated range" if not short else "RANGE")
        if comp.converged[i]:
            values[i] = (_joints_to(comp.q[i], target, parsed, controller) if target.kind == "joint"
                         else lang.pose_to(comp.commanded[i], target.values))
        elif short:
            flags = ["NOT COMPENSATED"]
        pred = None if comp.predicted_mm is None else float(comp.predicted_mm[i])
        comments[i] = _comment(target.name, pred, flags, short)
    texts = rewrite(parsed, values, comments)
    return CompensatedProgram(parsed, texts, comp, comp.converged.copy(), shift, sources, configuration, branch,
                              limits)


#: The header line of a program calib_oed wrote (:func:`~calib_oed.program.format_common.header_lines`).
_WRITTEN = re.compile(rf"joint values: ({URDF_VALUES}|{CONTROLLER_VALUES}) in [^,\n]+, in the order ([^\n]+?)\s*$",
                      re.MULTILINE)
_CONTROLLER = re.compile(r"by the scene's controller (\S+)")


def check_written_for(parsed: ParsedProgram, joint_names, controller) -> None:
    """A program calib_oed wrote says in its header which robot's joints it lists and in which
    convention (URDF angles or a controller's values): both must be this scene's, or its joint
    values would be read as other joints or in another convention (tens of mm off, no error).
    A header without that line (another writer, or edited out) is not checked.

    Raises:
        ProgramError: another robot's joints, or the other convention, named with the fix.
    """
    for file, text in parsed.texts.items():
        m = _WRITTEN.search(text)
        if m is None:
            continue
        written = [n.strip() for n in m.group(2).split(",")]
        if written != list(joint_names):
            raise ProgramError("program", file, f"written for a robot with the joints {', '.join(written)}, "
                               f"not this scene's ({', '.join(joint_names)}): compensate it with the scene "
                               "it was written for")
        said = _CONTROLLER.search(text)
        if m.group(1) == CONTROLLER_VALUES and controller is None:
            name = said.group(1) if said else "?"
            raise ProgramError("program", file, f"its joint values are those of controller {name}, and this scene has "
                               "no controller: block to map them to URDF angles: use the scene it was written with")
        if m.group(1) == URDF_VALUES and controller is not None:
            raise ProgramError("program", file, "its joint values are URDF joint angles, and this scene's "
                               f"controller {controller.name} would read them as its own: use the scene it "
                               "was written with")
        if said is not None and controller is not None and said.group(1) != controller.name:
            raise ProgramError("program", file, f"its joint values are those of controller {said.group(1)}, not of "
                               f"this scene's controller {controller.name}: use the scene it was written with")


def _beyond_limits(robot: Robot, q: np.ndarray) -> str:
    """The joints of ``q`` [rad] beyond ``robot``'s limits, as a note (empty: none)."""
    out = [f"{name} {np.degrees(v):.3f} deg {'<' if v < lo else '>'} {np.degrees(lo if v < lo else hi):.3f} deg"
           for name, v, lo, hi in zip(robot.joint_names, q, robot.lower, robot.upper, strict=True)
           if not lo - 1e-12 <= v <= hi + 1e-12]
    return ("compensated joints beyond the robot's joint limits (" + ", ".join(out)
            + "): the controller refuses this target") if out else ""


def _declared_branch(nom: TcpKinematics, arm: ConfigurationKinematics, pose: pin.SE3, q: np.ndarray,
                     declared: dict, settings: IkSettings) -> np.ndarray:
    """The nominal solution of ``pose`` nearest the branch a KRL target's ``S``/``T`` declare, if
    ``q`` (the one next to the previous target) is not in it: the other elbow as ``S`` bit 1
    says (:meth:`~calib_oed.model.arm_configuration.ConfigurationKinematics.compute_elbow_flip`,
    solved), the wrist flipped (A4 + 180 deg, -A5, A6 + 180 deg: the same pose for a spherical
    wrist) as ``S`` bit 2 says, and each joint turned by 360 deg to the sign ``T`` gives where
    that stays inside its limits; solved again from there and kept if it is inside the limits
    and differs from the declared bits in fewer bits than ``q``. The shoulder (``S`` bit 0) is
    not changed: a target declared in another, or whose declared branch is beyond a limit, is
    named."""
    masks = {"S": 0b111, "T": 0b111111}
    want = {k: v & masks[k] for k, v in declared.items() if k in masks}
    nominal, controller = arm.robot, arm.controller

    def wrong(row) -> int:
        s, t = kuka_status(arm.compute(row))
        ours = {"S": int(s[0]), "T": int(t[0])}
        return sum(bin(ours[k] ^ v).count("1") for k, v in want.items())

    def sign_ok(row, j) -> bool:
        c = controller.to_controller(row) if controller is not None else row
        return (c[j] < 0) == bool(want["T"] >> j & 1)

    before = wrong(q)
    if before == 0:
        return q
    cand = q.copy()
    if "S" in want and (want["S"] >> 1 & 1) != (arm.compute(q).elbow[0] >= 0):
        flipped, err, _, _ = nom.solve(pose, arm.compute_elbow_flip(q), settings)
        cand = flipped if err <= settings.tolerance else cand
    if "S" in want and (want["S"] >> 2 & 1) != (arm.compute(cand).wrist[0] <= 0):
        cand[3], cand[4], cand[5] = cand[3] + np.pi, -cand[4], cand[5] + np.pi
    for j in range(6):
        options = [cand[j] + 2 * np.pi * k for k in (-1, 0, 1)]
        options = [v for v in options if nominal.lower[j] <= v <= nominal.upper[j]] or [cand[j]]
        trial = [np.r_[cand[:j], v, cand[j + 1:]] for v in options]
        good = [t for t in trial if "T" in want and sign_ok(t, j)]
        cand = min(good or trial, key=lambda t: abs(t[j] - cand[j]))
    q_new, err, _, _ = nom.solve(pose, cand, settings)
    inside = bool(np.all((q_new >= nominal.lower) & (q_new <= nominal.upper)))
    return q_new if inside and err <= settings.tolerance and wrong(q_new) < before else q


def _configuration_checks(parsed: ParsedProgram, nominal: Robot, q0: np.ndarray, comp: Compensation,
                          controller) -> tuple[tuple[tuple[str, ...], ...], tuple[str, ...]]:
    r"""Per target, the configuration bits of its language that :math:`\hat q` changes (Cartesian
    targets of KRL, RAPID, TP on a 6-axis arm), and how a KRL target's declared ``S``/``T``
    differ from those of :math:`q^0`, and a RAPID target's declared ``confdata`` (module docstring)."""
    vendor = VENDORS.get(parsed.language.name)
    n = len(parsed.targets)
    poses = [i for i, t in enumerate(parsed.targets) if t.kind == "pose" and comp.converged[i]]
    changes: list[tuple[str, ...]] = [()] * n
    branch = [""] * n
    if vendor is None or not poses or nominal.nq != 6:
        return tuple(changes), tuple(branch)
    arm = ConfigurationKinematics(nominal, controller)
    before, after = arm.compute(q0[poses]), arm.compute(comp.q[poses])
    for i, found in zip(poses, configuration_changes(before, after, vendor, nominal.joint_names), strict=True):
        changes[i] = tuple(found)
    if vendor in ("kuka", "abb"):
        ours_all = _vendor_bits(vendor, before)
        masks = {"S": 0b111, "T": 0b111111}
        for k, i in enumerate(poses):
            declared = dict(parsed.targets[i].declared)
            ours = ours_all[k]
            keys = [key for key in ours if key in declared]
            if any((declared[key] & masks.get(key, -1)) != ours[key] for key in keys):
                said = ", ".join(f"{key} {declared[key]}" for key in keys)
                got = ", ".join(f"{key} {ours[key]}" for key in keys)
                joints = ", ".join(f"{v:.1f}" for v in np.degrees(before.joints[k]))
                branch[i] = (f"declared {said}, the nominal solution compensated has {got}: the controller "
                             "reaches this pose on another branch (another shoulder, elbow, wrist or turn, or beyond "
                             f"the joint limits) than the joints compensated ({joints} deg); give a joint target or "
                             f"the {'S and T' if vendor == 'kuka' else 'confdata'} of that branch")
    return tuple(changes), tuple(branch)


def _vendor_bits(vendor: str, cfg) -> list[dict[str, int]]:
    """Per row, the configuration a ``vendor`` target declares for these joints: KUKA's ``S``,
    ``T``; ABB's ``cf1``, ``cf4``, ``cf6``, ``cfx``."""
    if vendor == "kuka":
        status, turn = kuka_status(cfg)
        return [{"S": int(s), "T": int(t)} for s, t in zip(status, turn, strict=True)]
    return [dict(zip(("cf1", "cf4", "cf6", "cfx"), map(int, row), strict=True)) for row in abb_confdata(cfg)]


__all__ = ["CompensatedProgram", "compensate_program"]
