r"""Compensate a robot program: the same files with only the target values changed.

For a parsed program (:mod:`calib_oed.program.parse`) every target becomes nominal
joints :math:`q^0` (URDF, rad): joint targets through the language's unit and the scene's
controller convention (:math:`q = Ac + b`, :mod:`calib_oed.model.controller`), Cartesian
targets :math:`P` (in the base frame) by the nominal inverse kinematics seeded at the
previous target's :math:`q^0` (the first at ``home``; a target whose inverse kinematics
failed is skipped as a seed), so the branch is the one the program moves along. Then :func:`calib_oed.calibration.compensation.compensate_joints`
gives :math:`\hat q` and, for Cartesian targets, the pose :math:`P'` the nominal
controller must be given. Joint targets are rewritten with :math:`\hat q` (back in the
controller's convention and unit), Cartesian targets with :math:`P'` in the language's
convention (angles the representation nearest the original, status/turn/confdata as
written). A target whose inverse kinematics did not converge is left as written and
named; one near a singularity or outside the calibrated joint range is compensated and
named. Each target gets a comment with its predicted residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.calibration.compensation import (
    SINGULAR_THRESHOLD,
    CalibrationUncertainty,
    Compensation,
    compensate_joints,
)
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.inverse_kinematics import IkSettings, TcpKinematics
from calib_oed.model.robot import Robot
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
            puts the TCP from the target without compensation (n,).
        sources: Where the tool and base came from (``file``, ``given``, ``none``).
    """

    parsed: ParsedProgram
    texts: dict[str, str]
    compensation: Compensation
    changed: np.ndarray
    shift_mm: np.ndarray
    sources: dict[str, str]

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.parsed.targets]

    def issues(self) -> list[str]:
        flagged = np.flatnonzero(self.compensation.flagged)
        lines = self.compensation.issues(self.names)
        return [line + ("" if self.changed[i] else "; NOT compensated (left as written)")
                for i, line in zip(flagged, lines, strict=True)]

    def to_dict(self) -> dict:
        c = self.compensation
        return {
            "language": self.parsed.language.name, "files": sorted(self.texts), "tool": self.sources["tool"],
            "base": self.sources["base"], "notes": list(self.parsed.notes), "issues": self.issues(),
            "targets": [{"name": t.name, "kind": t.kind, "changed": bool(self.changed[i]),
                         "shift_mm": float(self.shift_mm[i]),
                         "predicted_residual_mm": None if c.predicted_mm is None else float(c.predicted_mm[i]),
                         "joint_correction_deg": float(np.degrees(np.abs(c.correction[i]).max())),
                         "sigma_min": float(c.sigma_min[i]), "in_range": bool(c.in_range[i])}
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
                       singular_threshold: float = SINGULAR_THRESHOLD) -> CompensatedProgram:
    """Compensate every target of ``parsed`` (module docstring).

    Args:
        tool, base: :math:`T_{F,E}`, :math:`T_{W,B}` unless the program declares them.
        home: Seed of the first Cartesian target (nq,) [rad]; None: the joint-range middle.
    """
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
    for i, target in enumerate(parsed.targets):
        if target.kind == "joint":
            q0[i] = _joints_from(target, parsed, controller, nq)
        else:
            q0[i], err, _, _ = nom.solve(base * lang.pose_from(target.values), seed, settings)
            ok[i] = err <= settings.tolerance
        if ok[i]:       # a failed solve's end point is no branch to follow
            seed = q0[i]
    comp = compensate_joints(nominal, calibrated, q0, tool=tool, base=base, uncertainty=uncertainty,
                             settings=settings, singular_threshold=singular_threshold)
    comp = Compensation(**{**comp.__dict__, "converged": comp.converged & ok})
    cal = TcpKinematics(calibrated, tool, length=nom.length)
    shift = np.array([1e3 * np.linalg.norm(cal.compute_pose(q).translation - nom.compute_pose(q).translation)
                      for q in q0])
    values, comments = {}, {}
    short = lang.name == "tp"
    for i, target in enumerate(parsed.targets):
        flags = [] if comp.converged[i] else ["NOT compensated: inverse kinematics failed"]
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
    return CompensatedProgram(parsed, texts, comp, comp.converged.copy(), shift, sources)


__all__ = ["CompensatedProgram", "compensate_program"]
