r"""Model error of a measured point as a Gaussian process over the joint configuration.

After the parametric fit a real arm keeps an error that is a smooth function of
the configuration (gravity, gear and transmission errors, thermal drift, tracker
scale): not independent noise. Each Cartesian component of a measured point's
model error is an independent zero-mean Gaussian process over the JOINT
CONFIGURATION :math:`q` (the design variable, so a design can differentiate it):

.. math::
    \mathrm{Cov}(e_i, e_j) = k(q_i, q_j)\,I_3 + \delta_{ij}\,\Sigma_{\mathrm{noise},i}
    \quad [\mathrm{m}^2],

:math:`\Sigma_{\mathrm{noise},i}` the tracker noise and repeatability of
:mod:`calib_oed.measurement.noise`. Isotropic in the three components, so the
frame (tracker or world) does not matter. Several reflectors measured at the
same :math:`q` share their model error (correlation 1): the error is the arm's.

**Kernel** (automatic relevance determination over the joints), with
:math:`\Delta = q_1 - q_2` and per joint the chordal distance
:math:`\delta_k = 2\sin(\Delta_k/2)` (a revolute joint: the arm at :math:`q_k` and
:math:`q_k + 2\pi` is the same; :math:`\delta_k = \Delta_k` for a joint listed in
``linear_joints``, e.g. prismatic), :math:`r^2 = \sum_k \delta_k^2/\ell_k^2` (a joint
with :math:`\ell_k = \infty` is ignored), :math:`u_k = \sin\Delta_k/\ell_k^2`,
:math:`c_k = \cos\Delta_k/\ell_k^2` (linear: :math:`\Delta_k/\ell_k^2`, :math:`1/\ell_k^2`):

- ``"matern52"`` (the default, Rasmussen & Williams 2006, eq. 4.17), :math:`a = \sqrt5`:
  :math:`k = \sigma^2(1 + ar + a^2r^2/3)\,e^{-ar}`;
- ``"squared_exponential"``: :math:`k = \sigma^2 e^{-r^2/2}`;
- ``"matern52_harmonic"``: the Matérn 5/2 plus an **additive harmonic part per joint**,
  each revolute joint's own error as a function of its own angle, once and twice per
  revolution, whatever the other joints do:

  .. math::
      k_H(q_1, q_2) = \sum_k \sum_{h=1,2} s_{kh}^2 \cos(h\Delta_k) \quad [\mathrm{m}^2],

  the covariance of :math:`\sum_h a_{kh}\cos(hq_k) + b_{kh}\sin(hq_k)` with independent
  :math:`a, b \sim N(0, s_{kh}^2)`: a joint-side transmission error
  (:math:`e_k = \sum_h A\sin(hq_k + \alpha)`) of a reducer, carried to the point by
  the arm. The ARD part couples configurations close in all joints, the harmonic part
  those with one joint at the same angle. No harmonic part for a joint in
  ``linear_joints`` or with :math:`\ell_k = \infty`. Amplitudes ``harmonic``
  :math:`(s_{k1}, s_{k2})` per joint; when not given, :data:`HARMONIC_SHARE` of
  :math:`\sigma^2` spread evenly over the harmonics of the revolute joints considered.

**White part** (``sigma_white``, default 0): an error independent between distinct
configurations but shared by every reflector measured at one (the motor-side
transmission errors of a joint repeat every few degrees, far below any length scale),
:math:`k_w(q_1, q_2) = \sigma_w^2\,[q_1 = q_2]`. It is not differentiable in
:math:`q` and not part of :meth:`DiscrepancyPrior.kernel` (the smooth part a design
differentiates). The design criteria of :mod:`calib_oed.oed.model_error` use the
smooth part only: the white part would add extra noise to each distinct arm position
and a constant to the predicted TCP variance, which they do not count yet.
:meth:`DiscrepancyPrior.covariance_kernel` is the sum, which the statistics use.

Both are radial; with :math:`g(r) = k'(r)/r` and :math:`h(r) = g'(r)/r`
(smooth at :math:`r = 0`: Matérn 5/2
:math:`g = -\sigma^2\tfrac{a^2}{3}(1 + ar)e^{-ar}`, :math:`h = \sigma^2\tfrac{a^4}{3}e^{-ar}`;
squared exponential :math:`g = -k`, :math:`h = k`), the derivatives in :math:`q_1` are

.. math::
    \frac{\partial k}{\partial q_{1,k}} = g\,u_k, \qquad
    \frac{\partial^2 k}{\partial q_{1,k}\partial q_{1,l}} = g\,c_k\,[k = l] + h\,u_k u_l,
    \qquad \frac{\partial^2 k}{\partial q_{1,k}\partial q_{2,l}} = -\frac{\partial^2 k}{\partial q_{1,k}\partial q_{1,l}}

(a function of :math:`\Delta` only). The harmonic part adds
:math:`\partial k_H/\partial q_{1,k} = -\sum_h h\,s_{kh}^2\sin(h\Delta_k)` and, on the
diagonal only, :math:`\partial^2 k_H/\partial q_{1,k}^2 = -\sum_h h^2 s_{kh}^2\cos(h\Delta_k)`. Checked by central finite differences in
``tests/measurement/test_discrepancy.py``.

**Pose scale** (``scale``, :class:`~calib_oed.measurement.pose_scale.PoseScale`): the smooth
part times :math:`m(q_1)\,m(q_2)`, the joint-space prior's standard deviation at the pose over
its training-pose mean, blended with 1 by a fitted weight; :math:`\sigma` stays the RMS over the
training poses, :meth:`DiscrepancyPrior.pose_variance` is the variance at a pose; the white part
is not scaled. A scaled prior has no derivatives in :math:`q` (designs take a scene's stationary
prior); :meth:`DiscrepancyPrior.from_dict` reads its stationary part
(``calibration/joint_prior_choice.fitted_model_error`` restores the scale, which needs the robot).

**Defaults for design time** (:meth:`DiscrepancyPrior.default_for`), when no data
exist: :math:`\sigma` = :data:`SIGMA_PER_REACH` x reach (0.1 mm per metre, at least
:data:`MIN_SIGMA`), length scales :data:`ARM_LENGTH_SCALE` for the first three
joints and :data:`WRIST_LENGTH_SCALE` for the others. From an earlier
identification: :meth:`DiscrepancyPrior.from_dict` of its JSON's ``model_error``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import ParameterError, ShapeError
from calib_oed.measurement.pose_scale import PoseScale

__all__ = ["ARM_LENGTH_SCALE", "HARMONIC_KERNELS", "HARMONIC_SHARE", "KERNELS", "MIN_SIGMA", "SIGMA_PER_REACH", "WRIST_LENGTH_SCALE",
           "DiscrepancyPrior", "robot_reach"]

#: Kernel families of :class:`DiscrepancyPrior`.
KERNELS = ("matern52", "squared_exponential", "matern52_harmonic")
#: Kernels with the additive harmonic part per joint (module docstring).
HARMONIC_KERNELS = ("matern52_harmonic",)
#: Default share of sigma^2 given to the harmonic part when its amplitudes are not given.
HARMONIC_SHARE = 0.5
#: Harmonics per revolution of the harmonic part (once, twice).
HARMONICS = (1, 2)
#: Default model-error amplitude per Cartesian axis per metre of reach [m/m] (0.1 mm per m).
SIGMA_PER_REACH = 1e-4
#: Smallest default amplitude [m] (0.02 mm).
MIN_SIGMA = 2e-5
#: Default length scale of the first three joints (the arm) [rad] (45 deg).
ARM_LENGTH_SCALE = float(np.radians(45.0))
#: Default length scale of the wrist joints [rad] (90 deg).
WRIST_LENGTH_SCALE = float(np.radians(90.0))

_A = np.sqrt(5.0)


def robot_reach(robot) -> float:
    """Reach [m]: the sum of the joint-to-joint distances from joint 2 to the tool frame.

    An upper bound of the distance from the shoulder to the tool at any configuration
    (the lengths of the links in a straight line).
    """
    model = robot.model
    frame = model.frames[robot.tool_frame_id]
    chain, j = [], frame.parentJoint
    while j > 0:
        chain.append(j)
        j = model.parents[j]
    total = sum(float(np.linalg.norm(model.jointPlacements[j].translation)) for j in chain[:-1])
    return total + float(np.linalg.norm(frame.placement.translation))


def _length_scales(value, nq: int | None = None) -> tuple[float, ...]:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.ndim != 1 or arr.size == 0 or (nq is not None and arr.size not in (1, nq)):
        raise ShapeError("model_error.length_scales", f"({nq},) or a scalar" if nq else "(nq,)",
                         arr.shape)
    if nq is not None and arr.size == 1:
        arr = np.full(nq, arr[0])
    if np.any(np.isnan(arr)) or np.any(arr <= 0):
        raise ParameterError("model_error.length_scales: every length scale must be > 0 "
                             f"(inf ignores a joint), got {arr.tolist()}")
    if np.all(np.isinf(arr)):
        raise ParameterError("model_error.length_scales: at least one joint needs a finite "
                             "length scale (all inf is a constant offset, which the fit absorbs)")
    return tuple(float(x) for x in arr)


@dataclass(frozen=True)
class DiscrepancyPrior:
    r"""The model-error Gaussian process of a measured point (module docstring).

    Attributes:
        sigma: Amplitude per Cartesian axis [m]: :math:`k(q, q) = \sigma^2`.
        length_scales: Per joint [rad, or m for prismatic joints]; ``np.inf`` ignores a joint.
        kernel_name: One of :data:`KERNELS`.
        source: Where the numbers come from (``"default"``, ``"scene"``, a file, ``"fit"``).
        sigma_white: Amplitude of the white part per Cartesian axis [m] (module docstring).
        linear_joints: Indices of joints measured by plain differences (prismatic); the
            others by the chordal distance of their angles.
        harmonic: Amplitudes :math:`s_{kh}` of the harmonic part [m], joint by joint, once
            then twice per revolution (2 nq,); only for :data:`HARMONIC_KERNELS` (empty:
            the default share, module docstring); 0 for a linear or ignored joint.
        scale: The pose scale :math:`m(q)` of the smooth part (module docstring), or None
            (stationary).
    """

    sigma: float
    length_scales: tuple[float, ...]
    kernel_name: str = "matern52"
    source: str = "given"
    sigma_white: float = 0.0
    linear_joints: tuple[int, ...] = ()
    harmonic: tuple[float, ...] = ()
    scale: PoseScale | None = None

    def __post_init__(self):
        for name in ("sigma", "sigma_white"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value >= 0):
                raise ParameterError(f"model_error.{name} must be finite and >= 0 [m], got {value}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "length_scales", _length_scales(self.length_scales))
        linear = tuple(int(j) for j in self.linear_joints)
        if any(not 0 <= j < len(self.length_scales) for j in linear):
            raise ParameterError(f"model_error.linear_joints: joint indices 0..{len(self.length_scales) - 1}, "
                                 f"got {list(linear)}")
        object.__setattr__(self, "linear_joints", linear)
        if self.kernel_name not in KERNELS:
            raise ParameterError(f"unknown model_error.kernel {self.kernel_name!r}; valid kernels "
                                 f"are: {', '.join(KERNELS)}")
        object.__setattr__(self, "harmonic", self._harmonic_amplitudes(self.harmonic))

    def _harmonic_amplitudes(self, given) -> tuple[float, ...]:
        """The checked amplitudes (2 nq,), zero where there is no harmonic part."""
        if self.kernel_name not in HARMONIC_KERNELS:
            if any(float(x) != 0.0 for x in given):
                raise ParameterError(f"model_error.harmonic: the kernel {self.kernel_name!r} has no "
                                     f"harmonic part (use one of {', '.join(HARMONIC_KERNELS)})")
            return ()
        mask = np.repeat(self.harmonic_joints, len(HARMONICS))
        if len(given) == 0:
            share = HARMONIC_SHARE * self.sigma**2 / max(int(mask.sum()), 1)
            arr = np.where(mask, np.sqrt(share), 0.0)
        else:
            arr = np.asarray(given, dtype=float).ravel()
            if arr.size != mask.size:
                raise ShapeError("model_error.harmonic", f"({mask.size},)", arr.shape)
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ParameterError("model_error.harmonic: amplitudes must be finite and >= 0 [m], "
                                     f"got {arr.tolist()}")
        return tuple(float(x) for x in np.where(mask, arr, 0.0))

    @property
    def harmonic_joints(self) -> np.ndarray:
        """Joints with a harmonic part (nq,) bool: revolute, finite length scale, harmonic kernel."""
        ok = np.isfinite(self.length_scales)
        ok[list(self.linear_joints)] = False
        return ok & (self.kernel_name in HARMONIC_KERNELS)

    # ------------------------------------------------------------ builders
    @classmethod
    def default_for(cls, robot, kernel_name: str = "matern52") -> DiscrepancyPrior:
        """The documented design-time default for ``robot`` (module docstring)."""
        sigma = max(SIGMA_PER_REACH * robot_reach(robot), MIN_SIGMA)
        ell = [ARM_LENGTH_SCALE if i < 3 else WRIST_LENGTH_SCALE for i in range(robot.nq)]
        return cls(sigma, tuple(ell), kernel_name, "default", 0.0, linear_joints_of(robot))

    @classmethod
    def from_dict(cls, data: Mapping, nq: int | None = None, source: str = "identification"
                  ) -> DiscrepancyPrior:
        """From :meth:`to_dict`'s form (``sigma_mm``, ``length_scales_deg``, ``kernel``),
        as ``calib-oed identify --json`` writes it under ``model_error``.

        Raises:
            ParameterError: keys missing or values out of range.
        """
        if not isinstance(data, Mapping) or "sigma_mm" not in data or "length_scales_deg" not in data:
            raise ParameterError("model_error: expected a mapping with sigma_mm and "
                                 f"length_scales_deg (and optionally kernel), got {data!r}")
        ell = [np.inf if v is None else float(v) for v in np.atleast_1d(data["length_scales_deg"])]
        return cls(float(data["sigma_mm"]) * 1e-3, _length_scales(np.radians(ell), nq),
                   str(data.get("kernel", "matern52")), source,
                   float(data.get("sigma_white_mm", 0.0)) * 1e-3,
                   tuple(int(j) for j in data.get("linear_joints", ())),
                   tuple(1e-3 * np.ravel(np.asarray(data.get("harmonic_mm", ()), dtype=float))))

    def to_dict(self) -> dict:
        """JSON form in report units: ``sigma_mm``, ``length_scales_deg`` (None = ignored joint)."""
        out = {"sigma_mm": self.sigma * 1e3, "sigma_white_mm": self.sigma_white * 1e3,
                "kernel": self.kernel_name, "linear_joints": list(self.linear_joints),
                "length_scales_deg": [None if np.isinf(x) else float(np.degrees(x))
                                      for x in self.length_scales],
                "source": self.source}
        if self.harmonic:
            out["harmonic_mm"] = (1e3 * np.reshape(self.harmonic, (-1, len(HARMONICS)))).tolist()
        if self.scale is not None:
            out["pose_scale"] = self.scale.to_dict()
        return out

    def with_values(self, sigma: float, length_scales, source: str,
                    sigma_white: float | None = None, harmonic=None, weight: float | None = None
                    ) -> DiscrepancyPrior:
        """The same kernel with new hyperparameters (``sigma_white``, ``harmonic``, the pose scale's
        ``weight`` None: unchanged; the harmonic part of a joint whose length scale became infinite
        is dropped)."""
        white = self.sigma_white if sigma_white is None else sigma_white
        harm = self.harmonic if harmonic is None else tuple(np.ravel(harmonic))
        scale = self.scale if weight is None or self.scale is None else self.scale.with_weight(weight)
        return DiscrepancyPrior(sigma, tuple(length_scales), self.kernel_name, source, white,
                                self.linear_joints, harm, scale)

    def with_scale(self, scale: PoseScale | None) -> DiscrepancyPrior:
        """The same prior with the pose scale ``scale`` (None: stationary)."""
        return DiscrepancyPrior(self.sigma, self.length_scales, self.kernel_name, self.source,
                                self.sigma_white, self.linear_joints, self.harmonic, scale)

    @property
    def n_kernel_hyperparameters(self) -> int:
        """Length of :meth:`kernel_log_gradient`'s last axis: sigma, nq length scales, for a
        harmonic kernel the 2 nq amplitudes and, with a pose scale, its weight."""
        return 1 + self.nq + len(self.harmonic) + (self.scale is not None)

    @property
    def nq(self) -> int:
        return len(self.length_scales)

    def describe(self) -> str:
        """One line in report units."""
        ell = ", ".join("-" if np.isinf(x) else f"{np.degrees(x):.0f}" for x in self.length_scales)
        harm = ""
        if self.harmonic:
            per = np.reshape(self.harmonic, (-1, len(HARMONICS))) * 1e3
            harm = ", harmonic [" + ", ".join("-" if not ok else "/".join(f"{x:.4f}" for x in row)
                                               for ok, row in zip(self.harmonic_joints, per, strict=True)) \
                + "] mm (once/twice per revolution)"
        scaled = "" if self.scale is None else f", {self.scale.describe()}"
        return (f"model error {self.kernel_name}: sigma {self.sigma * 1e3:.4f} mm per axis, "
                f"length scales [{ell}] deg{harm}, white part {self.sigma_white * 1e3:.4f} mm{scaled} "
                f"({self.source})")

    # ------------------------------------------------------------- kernel
    def _pieces(self, q1, q2):
        """u (n1, n2, nq), c (n1, n2, nq), k, g, h (n1, n2) and the distances delta (module docstring)."""
        q1 = self._check(q1, "Q1")
        q2 = self._check(q2, "Q2")
        inv = 1.0 / np.asarray(self.length_scales) ** 2  # 0 for an ignored joint
        diff = q1[:, None, :] - q2[None, :, :]
        delta, u, c = 2.0 * np.sin(0.5 * diff), np.sin(diff) * inv, np.cos(diff) * inv
        if self.linear_joints:
            j = list(self.linear_joints)
            delta[..., j], u[..., j], c[..., j] = diff[..., j], diff[..., j] * inv[j], inv[j]
        r = np.sqrt(np.maximum(np.einsum("abk,k->ab", delta * delta, inv), 0.0))
        s2 = self.sigma**2
        if self.kernel_name.startswith("matern52"):
            e = np.exp(-_A * r)
            k = s2 * (1 + _A * r + 5.0 * r**2 / 3) * e
            g = -s2 * (5.0 / 3) * (1 + _A * r) * e
            h = s2 * (25.0 / 3) * e
        else:
            k = s2 * np.exp(-0.5 * r**2)
            g, h = -k, k
        return u, c, k, g, h, delta * delta * inv

    def _check(self, q, what) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != self.nq:
            raise ShapeError(what, f"(n, {self.nq})", q.shape)
        return q

    def _harmonic_terms(self, q1, q2, order: int) -> np.ndarray:
        r"""Per joint and harmonic, :math:`s_{kh}^2 h^o f(h\Delta_k)` (n1, n2, nq, 2), f = cos for
        ``order`` 0 and 2 (with the sign of the derivative), -sin for 1 (module docstring)."""
        diff = self._check(q1, "Q1")[:, None, :] - self._check(q2, "Q2")[None, :, :]
        s2 = np.reshape(self.harmonic, (self.nq, len(HARMONICS))) ** 2
        h = np.asarray(HARMONICS, dtype=float)
        arg = diff[..., None] * h
        f = {0: np.cos(arg), 1: -np.sin(arg), 2: -np.cos(arg)}[order]
        return s2 * h**order * f

    def _stationary(self, q1, q2) -> np.ndarray:
        k = self._pieces(q1, q2)[2]
        if self.harmonic:
            k = k + self._harmonic_terms(q1, q2, 0).sum(axis=(2, 3))
        return k

    def _scale_factor(self, q1, q2) -> np.ndarray | float:
        r""":math:`m(q_{1,a})\,m(q_{2,b})` (n1, n2), or 1 without a pose scale."""
        if self.scale is None:
            return 1.0
        return np.outer(self.scale.compute(self._check(q1, "Q1")), self.scale.compute(self._check(q2, "Q2")))

    def kernel(self, q1, q2) -> np.ndarray:
        r""":math:`k(q_{1,a}, q_{2,b})` (n1, n2) [m²] for configurations ``q1`` (n1, nq), ``q2`` (n2, nq)
        (times the pose scale's :math:`m(q_1)m(q_2)` when there is one)."""
        return self._stationary(q1, q2) * self._scale_factor(q1, q2)

    def _no_scale(self, what: str) -> None:
        if self.scale is not None:
            raise ParameterError(f"{what}: a model error scaled by the joint prior pose by pose has no "
                                 "configuration derivatives here; designs use the stationary prior "
                                 "(with_scale(None))")

    def kernel_gradient(self, q1, q2) -> np.ndarray:
        r""":math:`\partial k/\partial q_1` (n1, n2, nq) [m²/rad] (stationary priors only)."""
        self._no_scale("kernel_gradient")
        u, _, _, g, _, _ = self._pieces(q1, q2)
        grad = g[:, :, None] * u
        if self.harmonic:
            grad = grad + self._harmonic_terms(q1, q2, 1).sum(axis=3)
        return grad

    def kernel_log_gradient(self, q1, q2) -> np.ndarray:
        r"""Derivatives of :math:`k` in the log-hyperparameters, (n1, n2,
        :attr:`n_kernel_hyperparameters`) [m²]: :math:`\partial k/\partial\log\sigma = 2k_{ARD}`,
        :math:`\partial k/\partial\log\ell_j = -g\,\delta_j^2/\ell_j^2` (0 for an ignored joint)
        and, harmonic kernels, :math:`\partial k/\partial\log s_{kh} = 2 s_{kh}^2\cos(h\Delta_k)`
        (joint by joint), each times :math:`m(q_1)m(q_2)`, and with a pose scale
        :math:`\partial k/\partial\log\beta = \beta\,k_0\,\partial(m_1m_2)/\partial\beta`
        (:math:`k_0` the stationary kernel), for the marginal likelihood's gradient."""
        _, _, k, g, _, scaled = self._pieces(q1, q2)
        parts = [2.0 * k[..., None], -g[..., None] * scaled]
        if self.harmonic:
            terms = self._harmonic_terms(q1, q2, 0)
            parts.append(2.0 * terms.reshape(*terms.shape[:2], -1))
        out = np.concatenate(parts, axis=-1)
        if self.scale is None:
            return out
        m1, d1 = self.scale.compute_weight_derivative(self._check(q1, "Q1"))
        m2, d2 = self.scale.compute_weight_derivative(self._check(q2, "Q2"))
        dw = self.scale.weight * self._stationary(q1, q2) * (np.outer(d1, m2) + np.outer(m1, d2))
        return np.concatenate([out * np.outer(m1, m2)[..., None], dw[..., None]], axis=-1)

    def white_kernel(self, q1, q2) -> np.ndarray:
        r""":math:`\sigma_w^2\,[q_{1,a} = q_{2,b}]` (n1, n2) [m²] (module docstring)."""
        q1, q2 = self._check(q1, "Q1"), self._check(q2, "Q2")
        same = np.all(q1[:, None, :] == q2[None, :, :], axis=-1)  # the same commanded configuration
        return self.sigma_white**2 * same

    def covariance_kernel(self, q1, q2) -> np.ndarray:
        """The smooth and the white part, (n1, n2) [m²]: what the statistics use."""
        return self.kernel(q1, q2) + self.white_kernel(q1, q2)

    @property
    def smooth_variance(self) -> float:
        """:math:`k(q, q)` of one component, the smooth part (ARD and harmonic) [m²]."""
        return self.sigma**2 + float(np.sum(np.square(self.harmonic)))

    @property
    def variance(self) -> float:
        """:math:`k(q, q)` of one component, the smooth and the white part [m²] (with a pose scale:
        the mean over the training poses, :meth:`pose_variance` at a pose)."""
        return self.smooth_variance + self.sigma_white**2

    def pose_variance(self, q) -> np.ndarray:
        """:math:`k(q, q)` of one component at each configuration ``q`` (n, nq), the smooth and
        the white part, (n,) [m²]."""
        q = self._check(q, "Q")
        m2 = 1.0 if self.scale is None else self.scale.compute(q) ** 2
        return np.broadcast_to(m2 * self.smooth_variance + self.sigma_white**2, (q.shape[0],)).copy()

    def point_covariance(self, q) -> np.ndarray:
        r""":math:`K = k(Q, Q) + k_w(Q, Q)` (n, n) [m²]: the covariance of one Cartesian component
        of the model error over the configurations ``q`` (n, nq)."""
        return self.covariance_kernel(q, q)

    def sample(self, q, rng: np.random.Generator | int, jitter: float = 1e-12) -> np.ndarray:
        """One draw of the model error at configurations ``q`` (n, nq): (n, 3) [m]."""
        rng = np.random.default_rng(rng)
        k = self.point_covariance(q)
        w, v = np.linalg.eigh(k + jitter * max(self.variance, 1e-30) * np.eye(k.shape[0]))
        root = v * np.sqrt(np.maximum(w, 0.0))
        return root @ rng.normal(size=(k.shape[0], 3))


def linear_joints_of(robot) -> tuple[int, ...]:
    """Indices of the robot's prismatic joints (measured by plain differences)."""
    return tuple(int(i) for i in np.flatnonzero(robot.prismatic))
