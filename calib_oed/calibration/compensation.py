r"""Compensation: the joint values at which the calibrated robot puts the TCP where the nominal model would.

A controller that keeps its nominal model :math:`T^0_{W,E}(q)` puts the real
TCP at :math:`T^\star_{W,E}(q)` (the true robot), not where the program meant.
With the calibrated model :math:`\hat T_{W,E}` standing in for the truth, a
target is compensated by

* **a joint target** :math:`q`: the intended pose is :math:`P = T^0_{W,E}(q)`;
  the compensated joints :math:`\hat q` solve :math:`\hat T_{W,E}(\hat q) = P`
  (:mod:`calib_oed.model.inverse_kinematics`, seeded at :math:`q`, so the
  branch is the programmed one);
* **a Cartesian target** :math:`P` (in the base frame :math:`B` of the program,
  :math:`T_{W,B}` given): the nominal solution :math:`q^0` of
  :math:`T^0_{W,E}(q^0) = T_{W,B}P` from a seed (the controller's branch, see
  ``docs/compensate.md``), then :math:`\hat q` as above seeded at :math:`q^0`, and
  the pose the nominal controller must be given to reach :math:`\hat q`:
  :math:`P' = T_{W,B}^{-1}\,T^0_{W,E}(\hat q)`.

**Joint compliance and gains.** A calibration that identifies them (``robot.compliance``,
``robot.joint_gains``) has links at :math:`q_{eff}(q) = q + c\circ\tau_g(q) + \sum_m\theta_m E_m q`
for the commanded :math:`q` (:mod:`calib_oed.model.deflected_kinematics`). Given that
``deflection``, the compensated joints are the commanded ones:
:math:`\hat T_{W,E}(q_{eff}(\hat q)) = P`, solved by the same Newton iteration with the
Jacobian :math:`{}^{E}J_E(q_{eff})\,D(\hat q)` of the deflected model. :math:`\tau_g` is the
gravity torque with the payload the deflection was built with (the scene's payload: the
program must run with the payload the scene declares).

**Predicted residual.** After compensation the true TCP misses :math:`P` by
:math:`\hat t(\hat q) - t^\star(\hat q) \approx G(\hat q)(\hat p - p^\star)`, the
calibrated model's error at :math:`\hat q`, with :math:`G = \partial t_{W,E}/\partial p`
on the free parameters (:class:`~calib_oed.calibration.kpi.TcpKpi`). Its
covariance is :math:`C_t = G C_p G^\top` [m²] plus a model-error term where one
is given (:attr:`CalibrationUncertainty.model_error`): from an identification with a
fitted model error, :func:`exact_model_error` makes :math:`C_t` the predicted accuracy
of :mod:`calib_oed.calibration.prediction` at :math:`\hat q`
(:meth:`CalibrationUncertainty.from_robust`); from ``identify``'s files,
:func:`marginal_model_error`, the fitted model error's variance. The report gives
:math:`\sqrt{\mathrm{tr}\,C_t}` [mm], the RMS position error expected at the target
(:math:`C_p` in the gauge of the calibration: the base and tool as in the
nominal model, ``docs/conventions.md``).

**Named targets.** A target is flagged when its compensated joints leave the
calibrated joint range (default: the robot's limits), when
:math:`\sigma_{min} <` ``singular_threshold`` at :math:`\hat q` (default
:data:`SINGULAR_THRESHOLD`; :mod:`calib_oed.model.inverse_kinematics`), or
when an inverse kinematics did not converge.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.calibration.kpi import TcpKpi
from calib_oed.exceptions import CompensationError, ShapeError
from calib_oed.model.deflected_kinematics import DeflectedTcpKinematics, JointDeflection
from calib_oed.model.inverse_kinematics import IkSettings, TcpKinematics, solve_ik
from calib_oed.model.parameters import ParameterSpace
from calib_oed.model.robot import Robot

#: Default :math:`\sigma_{min}` [1] below which a target is named near a singularity: a scaled
#: pose correction :math:`\varepsilon` then needs up to :math:`100\,\lVert\varepsilon\rVert` rad of joint
#: motion (kr16 and ur5 with 0.5 mm, 0.5 mrad errors: corrections of 1.6 and 3.7 deg median for
#: :math:`\sigma_{min}` in [0.005, 0.01), 0.2 and 0.4 deg above 0.05; docs/compensate.md).
SINGULAR_THRESHOLD = 0.01

#: A model-error hook: (configurations (n, nq), TCP point in the tool frame (3,)) -> (n, 3, 3) [m²].
ModelErrorTerm = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class CalibrationUncertainty:
    r"""The calibration's uncertainty, for the predicted residual of a compensated target.

    Attributes:
        space: The parameter space of the calibration (nominal robot).
        p: The identified parameters (n_p,) [SI].
        free_indices: Indices of the estimated parameters (n_f,).
        covariance: :math:`C_p` on the free parameters (n_f, n_f) [m², m·rad, rad²].
        model_error: Optional term added to :math:`C_t`: a callable
            ``(q (n, nq), point (3,)) -> (n, 3, 3)`` [m²] (the hook for a model-error
            covariance); None: the identification's covariance alone.
    """

    space: ParameterSpace
    p: np.ndarray
    free_indices: np.ndarray
    covariance: np.ndarray
    model_error: ModelErrorTerm | None = None

    def __post_init__(self):
        k = len(self.free_indices)
        if np.shape(self.covariance) != (k, k):
            raise ShapeError("covariance", f"({k}, {k})", np.shape(self.covariance))

    @classmethod
    def from_robust(cls, space: ParameterSpace, robust) -> CalibrationUncertainty:
        r"""From an identification with a fitted model error
        (:func:`~calib_oed.calibration.robust.identify_robust` with ``model_error=``): :math:`C_p`
        the a-priori covariance and the model-error term of :mod:`calib_oed.calibration.prediction`,
        :math:`V_\ast(K) - V_\ast(0)` at the target (:func:`exact_model_error`), so that
        :math:`C_t = V_\ast`, the predicted accuracy at a new pose without noise or repeatability."""
        res = robust.result
        free = np.asarray(res.free_indices, int)
        return cls(space, np.asarray(res.p, float), free, np.asarray(res.covariance, float),
                   exact_model_error(space, robust.linearisation, robust.model_error.prior, res.p, free))

    def compute_covariance(self, q: np.ndarray, point: np.ndarray) -> np.ndarray:
        r""":math:`C_t = G C_p G^\top` (+ model error) at every configuration, (n, 3, 3) [m²]."""
        q = self.space.robot.check_configurations(q)
        g = TcpKpi(q, np.asarray(point, float)).compute_param_jacobian(self.space, self.p)
        g = g[:, self.free_indices].reshape(len(q), 3, -1)
        c = np.einsum("nij,jk,nlk->nil", g, self.covariance, g)
        if self.model_error is not None:
            extra = np.asarray(self.model_error(q, np.asarray(point, float)), float)
            if extra.shape != c.shape:
                raise ShapeError("model_error(q, point)", str(c.shape), extra.shape)
            c = c + extra
        return c


@dataclass(frozen=True, eq=False)
class Compensation:
    r"""Compensated targets (n of them), SI.

    Attributes:
        q_nominal: The joints the nominal controller reaches the target with (n, nq): the
            programmed joints, or the nominal solution of a Cartesian target.
        q: Compensated joints :math:`\hat q` (n, nq).
        targets: Intended TCP poses :math:`P` in the base frame (n,) of ``pin.SE3``.
        commanded: Poses to give the nominal controller, :math:`T_{W,B}^{-1}T^0_{W,E}(\hat q)` (n,).
        base: :math:`T_{W,B}`; tool: :math:`T_{F,E}`.
        ik_error: Scaled error left by the calibrated inverse kinematics [1] (n,).
        converged: Both inverse kinematics converged (n,).
        sigma_min: :math:`\sigma_{min}` of the calibrated model at :math:`\hat q` [1] (n,).
        in_range: :math:`\hat q` within the calibrated joint range (n,).
        near_singular: ``sigma_min < singular_threshold`` (n,).
        predicted_mm: :math:`\sqrt{\mathrm{tr}\,C_t}` [mm] (n,), or None without an uncertainty.
        singular_threshold: The threshold used [1].
    """

    q_nominal: np.ndarray
    q: np.ndarray
    targets: tuple
    commanded: tuple
    base: pin.SE3
    tool: pin.SE3
    ik_error: np.ndarray
    converged: np.ndarray
    sigma_min: np.ndarray
    in_range: np.ndarray
    near_singular: np.ndarray
    predicted_mm: np.ndarray | None
    singular_threshold: float

    @property
    def n(self) -> int:
        return len(self.q)

    @property
    def correction(self) -> np.ndarray:
        """:math:`\\hat q - q^0` (n, nq) [rad or m]."""
        return self.q - self.q_nominal

    @property
    def flagged(self) -> np.ndarray:
        """Targets :meth:`issues` names (n,)."""
        return ~self.converged | ~self.in_range | self.near_singular

    def issues(self, names: Sequence[str] | None = None) -> list[str]:
        """One line per flagged target, naming it and why."""
        names = list(names) if names is not None else [f"target {i}" for i in range(self.n)]
        out = []
        for i in range(self.n):
            why = []
            if not self.converged[i]:
                why.append(f"inverse kinematics did not converge (scaled error {self.ik_error[i]:.2g})")
            if not self.in_range[i]:
                why.append("compensated joints outside the calibrated joint range")
            if self.near_singular[i]:
                why.append(f"near a singularity (sigma_min {self.sigma_min[i]:.3g} < "
                           f"{self.singular_threshold:g})")
            if why:
                out.append(f"{names[i]}: " + "; ".join(why))
        return out


def exact_model_error(space: ParameterSpace, lin, prior, p: np.ndarray, free: np.ndarray) -> ModelErrorTerm:
    r"""The model-error part of the predicted error at a new pose (:mod:`calib_oed.calibration.prediction`):
    :math:`V_\ast(K) - V_\ast(0) = kI_3 + BKB^\top - BC_\ast - C_\ast^\top B^\top` [m²], the
    Gaussian-process model error at the target plus how the fit's parameter error correlates with
    it (``lin`` the identification linearised, ``prior`` the fitted model error)."""
    from calib_oed.calibration.prediction import error_covariances

    def term(q: np.ndarray, point: np.ndarray) -> np.ndarray:
        g = TcpKpi(q, point).compute_param_jacobian(space, p)[:, free].reshape(len(q), 3, -1)
        return error_covariances(lin, prior, g, q) - error_covariances(lin, None, g, q)

    return term


def marginal_model_error(prior) -> ModelErrorTerm:
    r""":math:`k(q, q)\,I_3` [m²]: the fitted model error's variance at any pose (what ``identify``'s
    ``identification.json`` keeps, without the linearisation that :func:`exact_model_error` needs)."""
    return lambda q, point: prior.pose_variance(np.asarray(q, float))[:, None, None] * np.eye(3)


def calibrated_robot(space: ParameterSpace, p: np.ndarray) -> Robot:
    """The robot with the calibrated joint placements (the model of the URDF ``identify -o`` writes)."""
    from dataclasses import replace

    from calib_oed.calibration.export import calibrated_urdf_text

    return replace(space.robot, model=space.perturbed_model(p), urdf_text=calibrated_urdf_text(space, p))


def _as_poses(poses, what: str) -> list[pin.SE3]:
    if isinstance(poses, pin.SE3):
        return [pin.SE3(poses)]
    if isinstance(poses, (list, tuple)) and all(isinstance(t, pin.SE3) for t in poses):
        return [pin.SE3(t) for t in poses]
    arr = np.asarray(poses, float)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ShapeError(what, "(n, 4, 4) homogeneous matrices or pinocchio.SE3 poses", arr.shape)
    return [pin.SE3(a) for a in arr]


def _check_pair(nominal: Robot, calibrated: Robot) -> None:
    if nominal.joint_names != calibrated.joint_names:
        raise CompensationError(
            f"the calibrated robot's joints {list(calibrated.joint_names)} are not the nominal "
            f"robot's {list(nominal.joint_names)}: load both from the same robot description")
    if nominal.tool_frame != calibrated.tool_frame:
        raise CompensationError(
            f"the calibrated robot's tool frame {calibrated.tool_frame!r} is not the nominal "
            f"robot's {nominal.tool_frame!r}: load both with the same tool_frame")


def calibrated_kinematics(calibrated: Robot, deflection: JointDeflection | None,
                          tool: pin.SE3 | None = None, length: float | None = None) -> TcpKinematics:
    """The calibrated TCP kinematics of the commanded joints: rigid, or with the joint deflection."""
    if deflection is None:
        return TcpKinematics(calibrated, tool, length)
    return DeflectedTcpKinematics(calibrated, deflection, tool, length)


def _finish(nominal: Robot, calibrated: Robot, q_nominal, targets, nominal_ok, base, tool, uncertainty,
            joint_range, settings, singular_threshold, deflection) -> Compensation:
    cal = calibrated_kinematics(calibrated, deflection, tool)
    world = [base * t for t in targets]
    sol = solve_ik(cal, world, q_nominal, settings)
    nom = TcpKinematics(nominal, tool, length=cal.length)
    binv = base.inverse()
    commanded = tuple(binv * nom.compute_pose(row) for row in sol.q)
    lower, upper = (nominal.lower, nominal.upper) if joint_range is None else map(np.asarray, joint_range)
    in_range = np.all((sol.q >= lower) & (sol.q <= upper), axis=1)
    predicted = None
    if uncertainty is not None:
        c = uncertainty.compute_covariance(sol.q, tool.translation)
        predicted = 1e3 * np.sqrt(np.trace(c, axis1=1, axis2=2))
    return Compensation(np.array(q_nominal), sol.q, tuple(targets), commanded, base, tool, sol.error,
                        sol.converged & nominal_ok, sol.sigma_min, in_range,
                        sol.sigma_min < singular_threshold, predicted, float(singular_threshold))


def compensate_joints(nominal: Robot, calibrated: Robot, q: np.ndarray, *, tool: pin.SE3 | None = None,
                      base: pin.SE3 | None = None, uncertainty: CalibrationUncertainty | None = None,
                      joint_range: tuple[np.ndarray, np.ndarray] | None = None,
                      settings: IkSettings | None = None,
                      singular_threshold: float = SINGULAR_THRESHOLD,
                      deflection: JointDeflection | None = None) -> Compensation:
    r"""Compensate joint targets: :math:`\hat q` with :math:`\hat T_{W,E}(\hat q) = T^0_{W,E}(q)`.

    Args:
        nominal: The robot as the controller knows it (scene or URDF model).
        calibrated: The calibrated robot (the URDF ``identify -o`` wrote, same tool frame).
        q: Programmed joints (n, nq) or (nq,) [rad or m].
        tool: TCP :math:`T_{F,E}` in the tool frame; None: the tool frame.
        base: :math:`T_{W,B}` for the ``targets`` and ``commanded`` poses; None: the world.
        uncertainty: For the predicted residual; None: no prediction.
        joint_range: ``(lower, upper)`` of the calibrated range (nq,) each; None: the limits.
        settings: Inverse kinematics settings.
        singular_threshold: :math:`\sigma_{min}` below which a target is named [1].
        deflection: The calibration's joint compliance and gains
            (:meth:`~calib_oed.model.deflected_kinematics.JointDeflection.from_space`, with the
            payload the program runs with); :math:`\hat q` then solves
            :math:`\hat T_{W,E}(q_{eff}(\hat q)) = T^0_{W,E}(q)`, the commanded joints. None: rigid joints.

    Raises:
        CompensationError: the two robots differ in joints or tool frame.
        ShapeError, NonFiniteError: bad ``q``.
    """
    _check_pair(nominal, calibrated)
    q = nominal.check_configurations(q)
    tool = pin.SE3.Identity() if tool is None else pin.SE3(tool)
    base = pin.SE3.Identity() if base is None else pin.SE3(base)
    nom = TcpKinematics(nominal, tool)
    binv = base.inverse()
    targets = [binv * nom.compute_pose(row) for row in q]
    return _finish(nominal, calibrated, q, targets, np.ones(len(q), bool), base, tool, uncertainty,
                   joint_range, settings, singular_threshold, deflection)


def compensate_pose(nominal: Robot, calibrated: Robot, poses, seeds: np.ndarray, *,
                    tool: pin.SE3 | None = None, base: pin.SE3 | None = None,
                    uncertainty: CalibrationUncertainty | None = None,
                    joint_range: tuple[np.ndarray, np.ndarray] | None = None,
                    settings: IkSettings | None = None,
                    singular_threshold: float = SINGULAR_THRESHOLD,
                    deflection: JointDeflection | None = None) -> Compensation:
    r"""Compensate Cartesian targets: the pose :math:`P'` to give the nominal controller.

    Args:
        poses: Targets :math:`P` of the TCP in the base frame: ``pin.SE3``, a list of them, or
            (n, 4, 4) matrices [m].
        seeds: (n, nq) or (nq,) start of the nominal inverse kinematics, on the branch the
            controller uses (the previous joint target, or the configuration the program's
            status/turn bits describe).
        Others: as :func:`compensate_joints`.

    Returns:
        A :class:`Compensation`; ``commanded`` holds :math:`P'`, ``q_nominal`` the nominal solution.
    """
    _check_pair(nominal, calibrated)
    targets = _as_poses(poses, "poses")
    seeds = nominal.check_configurations(seeds, "seeds")
    if len(seeds) == 1 and len(targets) > 1:
        seeds = np.repeat(seeds, len(targets), axis=0)
    tool = pin.SE3.Identity() if tool is None else pin.SE3(tool)
    base = pin.SE3.Identity() if base is None else pin.SE3(base)
    nom = TcpKinematics(nominal, tool)
    sol = solve_ik(nom, [base * t for t in targets], seeds, settings)
    return _finish(nominal, calibrated, sol.q, targets, sol.converged, base, tool, uncertainty,
                   joint_range, settings, singular_threshold, deflection)


__all__ = ["SINGULAR_THRESHOLD", "CalibrationUncertainty", "Compensation", "calibrated_kinematics", "calibrated_robot",
           "compensate_joints",
           "compensate_pose", "exact_model_error", "marginal_model_error"]
