r"""How the size of a real arm's model error changes with the pose: the joint-space prior's shape.

A stationary model error (:class:`~calib_oed.measurement.discrepancy.DiscrepancyPrior` without a
scale) has the same variance at every configuration: the average over the training poses. A real
arm's unmodelled errors are mostly joint-angle errors, moved to a point by lever arms and (for
compliance) scaled by gravity torques that change with the pose, so the error is larger where the
arm is stretched and loaded. The joint-space prior (:mod:`calib_oed.measurement.joint_prior`)
says how much: the variance of a tool point's error at :math:`q`,

.. math::
    v(q) = \sum_k k_k(q, q)\,\lVert J_k(q; c)\rVert^2 \quad [\mathrm{m}^2],

:math:`J_k` the point's Jacobian column of joint k (nominal arm), :math:`k_k(q, q)` joint k's
angle-error variance (transmission, smooth, gain and gravity-compliance parts) [rad²]. The
**pose scale** multiplies the model error's covariance by
:math:`m(q)\,m(q')` with

.. math::
    m(q)^2 = 1 - \beta + \beta\,v(q)/\bar v, \qquad \beta \in [0, 1],

:math:`\bar v` the mean of :math:`v` over the training configurations (so :math:`\sigma` keeps its
meaning: the RMS over those poses), :math:`\beta` the weight of the prior's shape, fitted with the
other hyperparameters by the restricted likelihood (:math:`\beta \to 0`: the stationary model
error). :math:`m(q)m(q')k(q, q')` is a covariance for any :math:`m` (a product with a rank-one
positive kernel).

The point :math:`c` is the centre of the scene's reflectors (the model error is one field
shared by every reflector at a pose); the frame does not matter (:math:`v` is a trace). The
derivative :math:`\partial m/\partial\beta = (v/\bar v - 1)/(2m)` enters the likelihood's
gradient (checked by central differences in ``tests/measurement/test_pose_scale.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calib_oed.exceptions import ParameterError
from calib_oed.measurement.joint_prior import JointErrorPrior, PointJacobians
from calib_oed.model.compliance import Compliance, GravityLoad

MM2_PER_M2 = 1e6
#: Configuration sets whose v(q) a scale and its copies keep (the fit evaluates the same ones).
CACHED = 8


@dataclass(frozen=True, eq=False)
class PoseScale:
    r"""The pose scale :math:`m(q)` of a model error (module docstring).

    Attributes:
        prior: The joint-space prior whose shape is used.
        points: The nominal arm's Jacobian of the point :math:`c` (one offset).
        mean_variance: :math:`\bar v` [m²] (> 0).
        weight: :math:`\beta` in [0, 1].
    """

    prior: JointErrorPrior = field(repr=False)
    points: PointJacobians = field(repr=False)
    mean_variance: float = 1.0
    weight: float = 1.0
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        w, v = float(self.weight), float(self.mean_variance)
        if not (np.isfinite(w) and 0.0 <= w <= 1.0):
            raise ParameterError(f"model error pose scale: weight must be in [0, 1], got {w}")
        if not (np.isfinite(v) and v > 0.0):
            raise ParameterError(f"model error pose scale: mean variance must be > 0 [m²], got {v}")
        object.__setattr__(self, "weight", w)
        object.__setattr__(self, "mean_variance", v)

    def compute_variance(self, q: np.ndarray) -> np.ndarray:
        r""":math:`v(q)` (n,) [m²] at the configurations ``q`` (n, nq), with
        :math:`k_k(q, q) = a_1^2 + a_2^2 + s^2 + \nu^2 q_k^2 + \gamma^2\tau_k(q)^2`
        (:mod:`calib_oed.measurement.joint_prior`); kept for the last few ``q``."""
        q = np.asarray(q, dtype=float)
        key = (q.shape, q.tobytes())
        if key not in self._cache:
            jac = self.points.compute(q)[0][:, 0, :, :self.prior.nq]  # (n, 3, nq)
            own = self.prior.compute_own_variance(q)
            if len(self._cache) >= CACHED:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = np.einsum("nk,nk->n", own, np.sum(jac**2, axis=1))
        return self._cache[key]

    def compute(self, q: np.ndarray) -> np.ndarray:
        """:math:`m(q)` (n,) [1]."""
        return np.sqrt(1.0 - self.weight + self.weight * self.compute_variance(q) / self.mean_variance)

    def compute_weight_derivative(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r""":math:`m(q)` and :math:`\partial m/\partial\beta` (each (n,)) (module docstring)."""
        ratio = self.compute_variance(q) / self.mean_variance
        m = np.sqrt(1.0 - self.weight + self.weight * ratio)
        return m, (ratio - 1.0) / (2.0 * m)

    def normalised(self, q: np.ndarray) -> PoseScale:
        r"""The same scale with :math:`\bar v` the mean of :math:`v` over ``q`` (n, nq)."""
        return replace(self, mean_variance=float(np.mean(self.compute_variance(q))), _cache=self._cache)

    def with_weight(self, weight: float) -> PoseScale:
        r"""The same scale with :math:`\beta` = ``weight``."""
        return replace(self, weight=weight, _cache=self._cache)

    def describe(self) -> str:
        return (f"scaled pose by pose by the joint-space prior's variance (weight {self.weight:.2f}, "
                f"mean {self.mean_variance * MM2_PER_M2:.4g} mm² over the training poses)")

    def to_dict(self) -> dict:
        """JSON form: the weight, the mean variance [mm²], the point [mm], the joint prior and the
        load on the tool its compliance part was computed with (``load``: kg, mm)."""
        out = {"kind": "joint_prior", "weight": self.weight,
               "mean_variance_mm2": self.mean_variance * MM2_PER_M2,
               "point_mm": (self.points.offsets[0] * 1e3).tolist(), "joint_prior": self.prior.to_dict()}
        if self.prior.gravity is not None:
            out["load"] = self.prior.gravity.load.to_dict()
        return out

    @classmethod
    def from_dict(cls, data, space) -> PoseScale:
        """From :meth:`to_dict`'s form for the nominal robot of ``space`` (a
        :class:`~calib_oed.model.parameters.ParameterSpace`), the arm loaded as recorded (``load``;
        a record without it, written before the load was, by ``space``'s compliance payload alone,
        as it was then made).

        Raises:
            ParameterError: keys missing or values out of range.
        """
        try:
            robot = space.robot
            if "load" in data:
                gravity = GravityLoad(robot.model, robot.tool_frame_id, Compliance.from_dict(data["load"]))
            else:
                gravity = JointErrorPrior.default_for(robot, getattr(space, "compliance", None)).gravity
            prior = JointErrorPrior.from_dict(data["joint_prior"], gravity)
            point = 1e-3 * np.asarray(data["point_mm"], dtype=float).reshape(1, 3)
            return cls(prior, PointJacobians(robot.model, robot.tool_frame_id, point, np.eye(3)),
                       float(data["mean_variance_mm2"]) / MM2_PER_M2, float(data["weight"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"model_error.fitted.pose_scale: expected weight, mean_variance_mm2, "
                                 f"point_mm (3 values) and joint_prior, got {data!r} ({exc})") from exc
