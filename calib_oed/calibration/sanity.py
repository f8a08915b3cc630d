r"""Sanity of measured data before fitting: is the registration residual plausible, and if not, why.

:func:`check_measurements` fits the tracker pose alone
(:func:`calib_oed.calibration.registration.register_tracker`) and compares the
RMS registration residual with a plausibility limit (default 10 mm: a real
arm's geometric errors are a few mm, a wrong file or scene gives metres).
Above it, :func:`diagnose` tries the usual mistakes, each by a registration of
the corrected data (the registration RMS with the correction is the evidence):

- **units**: positions scaled by 1e-3 or 1e3 (mm read as m, or m as mm), joint
  angles by :math:`\pi/180` or :math:`180/\pi`;
- **swapped or mirrored axes**: the position columns through each of the 24
  signed permutations with determinant -1 (a proper rotation of the columns is
  absorbed by the tracker pose itself, only a mirror is not);
- **a joint's sign, offset or coupling**: joint :math:`k` read as
  :math:`s\,q_k + o`, :math:`s = \pm 1`, :math:`o` on a 5 degree grid then refined,
  and :math:`q_{k+1} \pm q_k` (FANUC's J2/J3 coupling);
- **a constant tool offset**: the reflector offsets :math:`c_j` fitted with the
  tracker pose (alternating Kabsch and linear least squares).

A correction *explains* the data when its registration RMS is below the limit
and below a fifth of the uncorrected one. The result names the explanations,
best first, or the joint whose value the residual grows with most.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from calib_oed.calibration.registration import (
    MM_PER_M,
    Registration,
    pose_difference,
    predicted_points,
    register_tracker,
    rigid_registration,
)
from calib_oed.exceptions import DataSanityError, ParameterError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.parameters import ParameterSpace

#: Default plausibility limit of the registration RMS [m].
DEFAULT_MAX_RMS = 10e-3
_AXES = "xyz"
#: Fitted tracker orientation this far from the scene's [deg] gets a warning.
TURN_WARNING_DEG = 20.0


@dataclass(frozen=True)
class Cause:
    """One candidate explanation: what, the evidence, and the registration RMS with it corrected [mm]."""

    kind: str  # "units", "axes", "joint", "tool"
    description: str
    rms_mm: float

    def evidence(self, rms_mm: float) -> str:
        return f"corrected, the registration RMS drops from {rms_mm:.4g} mm to {self.rms_mm:.3g} mm"


@dataclass(frozen=True, eq=False)
class SanityReport:
    """The registration before fitting and, when implausible, its diagnosis.

    Attributes:
        registration: The tracker pose fitted alone and its residuals.
        limit_mm: The plausibility limit [mm].
        tracker_shift_mm, tracker_turn_deg: The fitted tracker pose against the scene's.
        causes: Explanations found, best first (empty when plausible).
        growing_joint: ``(joint name, |correlation|)`` of the joint the residual
            norm correlates with most.
    """

    registration: Registration
    limit_mm: float
    tracker_shift_mm: float
    tracker_turn_deg: float
    causes: tuple[Cause, ...] = ()
    growing_joint: tuple[str, float] | None = None

    @property
    def plausible(self) -> bool:
        return self.registration.rms_mm <= self.limit_mm

    def summary(self) -> str:
        r = self.registration
        text = (f"sanity: tracker pose fitted alone (rigid registration, nominal robot): residual "
                f"RMS {r.rms_mm:.4f} mm, max {r.max_mm:.4f} mm (limit {self.limit_mm:g} mm); fitted "
                f"tracker {self.tracker_shift_mm:.2f} mm and {self.tracker_turn_deg:.3f} deg from "
                "the scene's")
        if self.tracker_turn_deg > TURN_WARNING_DEG:
            text += (f"\n  warning: the fitted tracker orientation is {self.tracker_turn_deg:.1f} deg "
                     "from the scene's: a wrong tracker rpy in the scene, or position columns "
                     "permuted by a rotation (x, y, z read as y, -x, z and the like)")
        return text

    def to_dict(self) -> dict:
        return {"registration_rms_mm": self.registration.rms_mm,
                "registration_max_mm": self.registration.max_mm, "limit_mm": self.limit_mm,
                "tracker_shift_mm": self.tracker_shift_mm, "tracker_turn_deg": self.tracker_turn_deg,
                "causes": [{"kind": c.kind, "description": c.description, "rms_mm": c.rms_mm}
                           for c in self.causes]}


def _signed_permutations():
    """The 24 signed permutation matrices with determinant -1 (mirrors), and a name for each."""
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) < 0:
                held = ", ".join(f"{_AXES[a]} holds {'-' if s < 0 else ''}{_AXES[perm[a]]}"
                                 for a, s in zip(range(3), signs, strict=True)
                                 if perm[a] != a or s < 0)
                yield m, held


def _tool_offset_fit(kin_rot, kin_pos, measured, reflector, k, iters=100):
    """Tracker pose and reflector offsets fitted together (alternating); the last registration."""
    c = np.zeros((k, 3))
    reg = None
    for _ in range(iters):
        world = kin_pos + np.einsum("nij,nj->ni", kin_rot, c[reflector])
        reg = rigid_registration(world, measured)
        target = measured @ reg.rotation.T + reg.translation - kin_pos  # = R_WF c in world
        local = np.einsum("nji,nj->ni", kin_rot, target)
        new = np.array([local[reflector == j].mean(axis=0) if np.any(reflector == j) else c[j]
                        for j in range(k)])
        if np.max(np.abs(new - c)) < 1e-9:
            c = new
            break
        c = new
    world = kin_pos + np.einsum("nij,nj->ni", kin_rot, c[reflector])
    return rigid_registration(world, measured), c


def diagnose(space: ParameterSpace, mset: MeasurementSet, base_rms_mm: float, limit_mm: float,
             reflector_names=None) -> tuple[tuple[Cause, ...], tuple[str, float] | None]:
    """Candidate causes of an implausible registration, best first, and the joint the error grows with."""
    names = list(reflector_names or [f"reflector{j}" for j in range(len(space.reflector_offsets0))])
    q, refl, eta = mset.q, mset.reflector, mset.positions
    world = predicted_points(space, q, refl)
    causes: list[Cause] = []

    def rms(world_pts, measured):
        return rigid_registration(world_pts, measured).rms_mm

    for factor, text in ((1e-3, "units: the positions are 1000 times too large (the file holds mm "
                                "but is read as m: fix its '# units:' line, or give --length-unit mm "
                                "if it has none)"),
                         (1e3, "units: the positions are 1000 times too small (the file holds m "
                               "but is read as mm: fix its '# units:' line, or give --length-unit m "
                               "if it has none)")):
        causes.append(Cause("units", text, rms(world, eta * factor)))
    for factor, text in ((np.pi / 180, "units: the joint angles look like degrees read as radians "
                                       "(fix the '# units:' line, or give --angle-unit deg if it has none)"),
                         (180 / np.pi, "units: the joint angles look like radians read as degrees "
                                       "(fix the '# units:' line, or give --angle-unit rad if it has none)")):
        causes.append(Cause("units", text, rms(predicted_points(space, q * factor, refl), eta)))
    # every mirror fits equally well (two mirrors differ by a rotation, which the tracker
    # pose absorbs): the one whose fitted tracker pose is nearest the scene's is meant
    nominal = space.tracker_placement(None)
    mirrors = []
    for m, held in _signed_permutations():
        reg = rigid_registration(world, eta @ m.T)
        mirrors.append((pose_difference(nominal, reg.placement)[1], reg.rms_mm, held))
    turn, mirror_rms, held = min(mirrors)
    causes.append(Cause("axes", f"swapped or mirrored position columns: column {held} (the "
                                f"tracker pose then fits {turn:.1f} deg from the scene's)", mirror_rms))
    state = evaluate_setup(space, None, q, regressor=False, jacobian=False)
    reg, c = _tool_offset_fit(state.kin.rotation, state.kin.translation, eta, refl,
                              len(space.reflector_offsets0))
    delta = np.round((c - space.reflector_offsets0) * MM_PER_M, 1) + 0.0  # no -0.0
    shown = "; ".join(f"{names[j]} by ({delta[j, 0]:+.1f}, {delta[j, 1]:+.1f}, {delta[j, 2]:+.1f}) mm"
                      for j in mset.reflectors)
    causes.append(Cause("tool", f"constant tool offset: the reflector offsets (tool frame) are off: "
                                f"{shown}; check the scene's reflectors and tool_frame", reg.rms_mm))
    explains = [cz for cz in causes if _explains(cz, base_rms_mm, limit_mm)]
    if not explains:  # the costly search only when the cheap ones failed
        causes += _joint_causes(space, mset, world)
        explains = [cz for cz in causes if _explains(cz, base_rms_mm, limit_mm)]
    growing = _growing_joint(space, q, rigid_registration(world, eta).errors_mm)
    return tuple(sorted(explains, key=lambda cz: cz.rms_mm)), growing


def _explains(cause: Cause, base_rms_mm: float, limit_mm: float) -> bool:
    return cause.rms_mm <= limit_mm and cause.rms_mm <= 0.2 * base_rms_mm


def _joint_causes(space, mset, world) -> list[Cause]:
    """Joint k read as s q_k + o (grid, then refined), and q_{k+1} +- q_k."""
    robot = space.robot
    q, refl, eta = mset.q, mset.reflector, mset.positions
    out = []

    def rms_with(qm):
        return rigid_registration(predicted_points(space, qm, refl), eta).rms_mm

    grid = np.radians(np.arange(-180.0, 180.0, 5.0))
    for k, joint in enumerate(robot.joint_names):
        best = (np.inf, 1, 0.0)
        for sign in (1, -1):
            for o in grid:
                qm = q.copy()
                qm[:, k] = sign * q[:, k] + o
                best = min(best, (rms_with(qm), sign, o))
        _, sign, o0 = best

        def f(o, sign=sign, k=k):
            qm = q.copy()
            qm[:, k] = sign * q[:, k] + o
            return rms_with(qm)

        sol = scipy.optimize.minimize_scalar(f, bounds=(o0 - np.radians(5), o0 + np.radians(5)),
                                             method="bounded", options={"xatol": 1e-6})
        o = float((sol.x + np.pi) % (2 * np.pi) - np.pi)
        what = "its sign reversed" if sign < 0 else "an offset"
        if sign < 0 and abs(np.degrees(o)) > 0.5:
            what = "its sign reversed and an offset"
        out.append(Cause("joint", f"joint {joint}: {what} (the model angle is "
                                  f"{'-' if sign < 0 else ''}q {np.degrees(o):+.2f} deg); check the "
                                  "controller's sign and zero convention for this joint",
                         float(sol.fun)))
    for k in range(robot.nq - 1):
        for sign in (1, -1):
            qm = q.copy()
            qm[:, k + 1] = q[:, k + 1] + sign * q[:, k]
            a, b = robot.joint_names[k + 1], robot.joint_names[k]
            out.append(Cause("joint", f"joint coupling: the model's {a} is the file's {a} "
                                      f"{'+' if sign > 0 else '-'} {b} (a controller that reports "
                                      f"{a} relative to the horizontal)", rms_with(qm)))
    return out


def _growing_joint(space, q, errors_mm) -> tuple[str, float] | None:
    best = None
    for k, name in enumerate(space.robot.joint_names):
        if np.ptp(q[:, k]) == 0 or np.ptp(errors_mm) == 0:
            continue
        rho = abs(float(np.corrcoef(q[:, k], errors_mm)[0, 1]))
        if best is None or rho > best[1]:
            best = (name, rho)
    return best


def check_measurements(space: ParameterSpace, mset: MeasurementSet, max_rms: float = DEFAULT_MAX_RMS,
                       reflector_names=None, raise_error: bool = True) -> SanityReport:
    """Register the tracker alone; above ``max_rms`` [m] diagnose and raise.

    Raises:
        DataSanityError: the registration RMS exceeds ``max_rms`` (with
            ``raise_error``); its message names the likely causes and their evidence.
        ParameterError: ``max_rms`` not positive.
    """
    if not (np.isfinite(max_rms) and max_rms > 0):
        raise ParameterError(f"max_rms must be a positive length [m], got {max_rms}")
    reg = register_tracker(space, mset)
    shift, turn = pose_difference(space.tracker_placement(None), reg.placement)
    limit_mm = max_rms * MM_PER_M
    report = SanityReport(reg, limit_mm, shift, turn)
    if report.plausible:
        return report
    causes, growing = diagnose(space, mset, reg.rms_mm, limit_mm, reflector_names)
    report = SanityReport(reg, limit_mm, shift, turn, causes, growing)
    if raise_error:
        pairs = [(c.description, c.evidence(reg.rms_mm)) for c in causes]
        if not pairs and growing is not None and growing[1] > 0.7:
            pairs = [(f"joint {growing[0]}: its sign, offset or coupling", "the residual grows "
                      f"along its range, correlation {growing[1]:.2f}")]
        raise DataSanityError(mset.source, reg.rms_mm, limit_mm, pairs,
                              " (--max-registration-rms)")
    return report


#: The tracker pose and the reflector offsets fitted together to measured positions, the
#: robot nominal: ``fit_tracker_and_offsets(kin_rot, kin_pos, measured, reflector, k)``
#: returns the registration and the offsets (k, 3) [m, tool frame].
fit_tracker_and_offsets = _tool_offset_fit
