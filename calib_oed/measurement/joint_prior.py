r"""A joint-space model-error prior for the design criterion: each joint's angle error a Gaussian
process, mapped to the measured points and the TCP by that joint's column of the Jacobian.

**Model** (``docs/oed.md``, "The joint-space prior"). What a calibrated arm keeps after the
geometric fit is mostly *joint-angle* error (reducer transmission errors, gravity compliance,
the J2 balancer, joint gain errors): an error :math:`\varepsilon_k(q)` of joint k's angle moves a
point :math:`c` fixed on the tool by :math:`J_k(q; c)\,\varepsilon_k(q)`, :math:`J_k` the point's
Jacobian column of joint k (tracker frame, [m/rad]). With the joints' errors independent zero-mean
Gaussian processes,

.. math::
    e(q; c) = \sum_k J_k(q; c)\,\varepsilon_k(q), \qquad
    \mathrm{Cov}\big(e(q; c), e(q'; c')\big) = \sum_k k_k(q, q')\,J_k(q; c)\,J_k(q'; c')^\top
    \quad [\mathrm{m}^2],

and per joint, with :math:`\Delta = q_k - q'_k` [rad] and :math:`\tau_k` the gravity torque on
joint k of the nominal arm with the scene's payload (modelled or not) and the reflector nest of
the measurements (:class:`~calib_oed.model.compliance.GravityLoad`) [N·m],

.. math::
    k_k(q, q') = a_{1k}^2\cos\Delta + a_{2k}^2\cos 2\Delta
      + s_k^2\,m_{5/2}\!\big(|2\sin(\Delta/2)|/\ell_k\big)
      + \nu_k^2\,q_k q'_k + \gamma_k^2\,\tau_k(q)\,\tau_k(q') \quad [\mathrm{rad}^2]:

once and twice per revolution of the joint (a sinusoid of RMS :math:`a` with a uniformly random
phase has the covariance :math:`a^2\cos\Delta`), a smooth error of the joint's own angle
(Matérn 5/2 of the chordal distance, Rasmussen & Williams 2006, eq. 4.17), a gain (scale) error
of standard deviation :math:`\nu_k` [rad/rad], and a compliance :math:`c_k` of standard deviation
:math:`\gamma_k` [rad/(N·m)] under the arm's own gravity load. Several reflectors at one pose share
the joints' errors (their columns differ); a joint whose axis passes through a point moves it by
zero, so turning A6 with the shipped one-SMR scenes measures the same error again. The parts of
:math:`\varepsilon` a scene identifies (joint offsets, gains, compliance) are absorbed by the
fit the criterion models; the rest is what the design must average at the working configurations.

**Derivatives** in :math:`q` (first argument), for the criterion's exact gradient:
:math:`\partial_{q_k}` of the own-angle parts is :math:`-a_1^2\sin\Delta - 2a_2^2\sin 2\Delta
+ s^2 g(r)\sin\Delta/\ell^2 + \nu^2 q'_k` (:math:`g = k'(r)/r` of the Matérn kernel,
:mod:`calib_oed.measurement.discrepancy`), the compliance part
:math:`\gamma^2\,\partial\tau_k/\partial q\;\tau_k(q')` over every joint
(``pin.computeGeneralizedGravityDerivatives``), and the point's Jacobian columns
:math:`\partial_l J_k = \omega_{\min(k,l)}\times J_{\max(k,l)}` (serial chain, revolute joints,
:math:`\omega` the joint axes in the tracker frame). Checked against central differences in
``tests/oed/test_joint_prior.py``.

**Motor-side harmonics**: a second Matérn 5/2 part
:math:`m_k^2\,m_{5/2}(|2\sin(\Delta/2)|/\ell_{m,k})` of short length :math:`\ell_m`
(:data:`MOTOR_LENGTH`), for the transmission errors once and twice per *motor* revolution (at
gear ratios :math:`N` of 50-200 their period :math:`2\pi/N` is 0.03-0.13 rad of joint angle; with
:math:`N` unknown their covariance decays within about :math:`1/N`). Poses more than a few
:math:`\ell_m` apart see independent values, a repeated pose the same one: a repeat does not
average it, and a pose that shares one joint's angle with a working configuration measures that
joint's part of the working configuration's error.

**Defaults per robot size** (:meth:`JointErrorPrior.default_for`, ``docs/scenes.md``): the size
class of the arm's URDF mass and the published magnitudes of
:mod:`calib_oed.model.size_class` (the same sources as the realistic simulator,
:mod:`calib_oed.calibration.realistic_defaults`): transmission error RMS 21 and 11 arcsec (30 and
15 arcsec amplitude), the motor-side part :data:`MOTOR_RMS` (the motor's own harmonics and
those of the input stage at the joint, 5 and 3 arcsec amplitude, as one RMS), no smooth part
(:data:`SMOOTH_SIGMA`), gain errors 5e-5, compliance :math:`\gamma_k = 1/k_k` (the class's
typical stiffness) with the scene's payload (modelled or not) and the reflector nest
(:data:`~calib_oed.model.compliance.NEST_MASS` at the reflectors' centroid, as the realistic
simulator loads the arm: without it a design cancels the deflection of a load the arm does not
carry, ``docs/oed.md``, "The reflector nest in the prior"); J2's times :math:`1 - b`, :math:`b` the class's
``balancer_fraction`` (medium and large arms carry a J2 spring balancer that takes that share of
the joint's gravity torque, as in the realistic simulator; small arms have none, :math:`b = 0`).
Measured on the realistic simulator in ``docs/oed.md`` ("The default prior and iteration budget").
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calib_oed.exceptions import ParameterError
from calib_oed.model.compliance import NEST_MASS, Compliance, GravityLoad
from calib_oed.model.kinematics import compute_tool_kinematics
from calib_oed.model.size_class import TYPICAL, arm_mass, per_joint, size_class_of

ARCSEC = np.pi / (180.0 * 3600.0)
#: Default RMS of the once- and twice-per-revolution transmission errors [rad] (amplitude / sqrt 2).
PERIODIC_RMS = (30.0 * ARCSEC / np.sqrt(2.0), 15.0 * ARCSEC / np.sqrt(2.0))
#: Default amplitude of the smooth part of a joint's own-angle error [rad]: none. The realistic
#: simulator has no smooth own-angle error; a smooth part of 10 arcsec (length 60 deg) stood in for
#: the motor-side part and, beside it, counted that error twice (``docs/benchmarks.md``, "The
#: motor part instead of the smooth part"). A scene or an identification can set one.
SMOOTH_SIGMA = 0.0
#: Default length scale of the smooth part [rad] (60 deg), for a scene or identification that sets one.
SMOOTH_LENGTH = float(np.radians(60.0))
#: Default standard deviation of the joint gain errors [rad/rad].
GAIN_SIGMA = 5e-5
#: Default RMS of the motor-side part [rad]: amplitudes 5 and 3 arcsec once and twice per motor
#: revolution at the joint (:mod:`calib_oed.calibration.realistic_defaults`), sqrt((5² + 3²)/2) = 4.12 arcsec.
MOTOR_RMS = float(np.sqrt((5.0**2 + 3.0**2) / 2.0)) * ARCSEC
#: Default length scale of the motor-side part [rad] (:class:`JointErrorPrior` ``motor``), about
#: 1/N for the gear ratios N of 50-200.
MOTOR_LENGTH = 0.015
_A = np.sqrt(5.0)
#: The per-joint parts of :class:`JointErrorPrior`, and those of them that are amplitudes (scaled together).
PARTS = ("once", "twice", "smooth", "length", "gain", "compliance", "motor", "motor_length")
AMPLITUDES = ("once", "twice", "smooth", "gain", "compliance", "motor")


@dataclass(frozen=True, eq=False)
class JointErrorPrior:
    r"""Per-joint angle-error processes (module docstring); arrays (nq,).

    Attributes:
        once, twice: RMS :math:`a_1, a_2` of the once/twice-per-revolution errors [rad].
        smooth: Amplitude :math:`s` of the smooth own-angle part [rad]; ``length`` :math:`\ell` [rad].
        gain: :math:`\nu` [rad/rad].
        compliance: :math:`\gamma` [rad/(N·m)]; needs ``gravity`` when any is > 0.
        gravity: The nominal arm's gravity load (None: no compliance part).
        source: Where the numbers come from.
        motor: RMS :math:`m` of the motor-side part [rad] (0: none); ``motor_length`` :math:`\ell_m` [rad].
    """

    once: np.ndarray
    twice: np.ndarray
    smooth: np.ndarray
    length: np.ndarray
    gain: np.ndarray
    compliance: np.ndarray
    gravity: GravityLoad | None = field(default=None, repr=False)
    source: str = "given"
    motor: np.ndarray | float = 0.0
    motor_length: np.ndarray | float = MOTOR_LENGTH

    def __post_init__(self):
        nq = np.atleast_1d(np.asarray(self.once)).size
        for name in PARTS:
            arr = np.broadcast_to(np.asarray(getattr(self, name), dtype=float), (nq,)).copy()
            if not np.all(np.isfinite(arr)) or np.any(arr < 0) or (name.endswith("length") and np.any(arr <= 0)):
                raise ParameterError(f"joint model error {name}: one finite value >= 0 per joint "
                                     f"({'> 0 ' if name.endswith('length') else ''}{nq} joints), got {arr.tolist()}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if np.any(self.compliance > 0) and self.gravity is None:
            raise ParameterError("joint model error compliance > 0 needs the arm's gravity load")

    @property
    def nq(self) -> int:
        return self.once.size

    @classmethod
    def default_for(cls, robot, payload: Compliance | None = None, reflectors=None) -> JointErrorPrior:
        """The documented default for ``robot`` (module docstring), the payload on its tool;
        ``reflectors`` (k, 3) [m, tool frame]: the nominal reflector centres, the reflector nest
        (:data:`~calib_oed.model.compliance.NEST_MASS`) joins the load at their centroid, as in
        the measurements (None: no nest)."""
        model = robot.model
        mass = arm_mass(model)
        size = size_class_of(mass)
        compliance = 1.0 / per_joint(TYPICAL[size].stiffness, model.nv)
        if model.nv >= 2:  # the J2 balancer carries its share of J2's gravity torque
            compliance[1] *= 1.0 - TYPICAL[size].balancer_fraction
        load = payload if payload is not None else Compliance()
        carried = ([] if load.arm_weight == "none" else ["arm"]) + (
            [f"payload {load.payload_mass:g} kg"] if load.payload_mass > 0 else [])
        if reflectors is not None:
            load = load.with_nest(NEST_MASS, np.mean(np.reshape(reflectors, (-1, 3)), axis=0))
            carried.append(f"reflector nest {NEST_MASS:g} kg")
        gravity = GravityLoad(model, robot.tool_frame_id, load)
        nq = model.nq
        source = f"default ({size} arm, {mass:.0f} kg; gravity load: {' + '.join(carried)})"
        return cls(np.full(nq, PERIODIC_RMS[0]), np.full(nq, PERIODIC_RMS[1]), np.full(nq, SMOOTH_SIGMA),
                   np.full(nq, SMOOTH_LENGTH), np.full(nq, GAIN_SIGMA), compliance, gravity,
                   source, np.full(nq, MOTOR_RMS), np.full(nq, MOTOR_LENGTH))

    def scaled(self, factor: float) -> JointErrorPrior:
        """Every amplitude times ``factor`` (the length scales kept): a prior that misjudges the
        size of the arm's errors."""
        f = float(factor)
        return replace(self, **{name: getattr(self, name) * f for name in AMPLITUDES},
                       source=f"{self.source}, x{f:g}")

    def with_motor(self, rms: float, length: float = MOTOR_LENGTH) -> JointErrorPrior:
        """This prior with the motor-side part of RMS ``rms`` [rad] and length ``length`` [rad] on every joint."""
        return replace(self, motor=rms, motor_length=length,
                       source=f"{self.source}, motor {rms / ARCSEC:.3g} arcsec / {length:g} rad")

    @property
    def has_motor(self) -> bool:
        """Whether the motor-side part is there (``motor`` > 0 on some joint)."""
        return bool(np.any(self.motor > 0))

    def to_dict(self) -> dict:
        """Report units: arcsec, deg, µrad/rad, µrad/(N·m)."""
        return {"kind": "joint", "once_arcsec": (self.once / ARCSEC).tolist(),
                "twice_arcsec": (self.twice / ARCSEC).tolist(), "smooth_arcsec": (self.smooth / ARCSEC).tolist(),
                "length_deg": np.degrees(self.length).tolist(), "gain_urad_per_rad": (self.gain * 1e6).tolist(),
                "compliance_urad_per_nm": (self.compliance * 1e6).tolist(), "source": self.source,
                **({"motor_arcsec": (self.motor / ARCSEC).tolist(), "motor_length_mrad": (self.motor_length * 1e3).tolist()}
                   if self.has_motor else {})}

    @classmethod
    def from_dict(cls, data: dict, gravity: GravityLoad | None) -> JointErrorPrior:
        """From :meth:`to_dict`'s form, ``gravity`` the nominal arm's load (KeyError, TypeError,
        ValueError on a malformed mapping; :class:`ParameterError` on values out of range)."""
        return cls(ARCSEC * np.asarray(data["once_arcsec"], float), ARCSEC * np.asarray(data["twice_arcsec"], float),
                   ARCSEC * np.asarray(data["smooth_arcsec"], float), np.radians(np.asarray(data["length_deg"], float)),
                   1e-6 * np.asarray(data["gain_urad_per_rad"], float),
                   1e-6 * np.asarray(data["compliance_urad_per_nm"], float), gravity, str(data.get("source", "")),
                   ARCSEC * np.asarray(data.get("motor_arcsec", 0.0), float),
                   1e-3 * np.asarray(data.get("motor_length_mrad", MOTOR_LENGTH * 1e3), float))

    def compute_deflections(self, q: np.ndarray) -> np.ndarray:
        r"""The compliance part's joint deflections at its RMS compliance, :math:`\gamma\circ\tau(q)`
        (n, nq) [rad] at the configurations ``q`` (n, nq); zeros without a compliance part."""
        if self.gravity is None or not np.any(self.compliance > 0):
            return np.zeros((len(q), self.nq))
        return self.compliance * self.gravity.torques(q)[:, :self.nq]

    def compute_own_variance(self, q: np.ndarray) -> np.ndarray:
        r"""Each joint's angle-error variance :math:`k_k(q, q) = a_1^2 + a_2^2 + s^2 + m^2 + \nu^2 q_k^2
        + \gamma^2\tau_k(q)^2` (n, nq) [rad²] at the configurations ``q`` (n, nq)."""
        own = self.once**2 + self.twice**2 + self.smooth**2 + self.motor**2 + self.gain**2 * q[:, :self.nq] ** 2
        if self.gravity is not None and np.any(self.compliance > 0):
            own = own + self.compliance**2 * self.gravity.torques(q)[:, :self.nq] ** 2
        return own

    def describe(self) -> str:
        """One line in report units."""
        def fmt(a, s):
            return "/".join(f"{x:.3g}" for x in a * s)
        return (f"joint model error: RMS once {fmt(self.once, 1 / ARCSEC)} arcsec, twice "
                f"{fmt(self.twice, 1 / ARCSEC)} arcsec, smooth {fmt(self.smooth, 1 / ARCSEC)} arcsec, "
                f"gain {fmt(self.gain, 1e6)} urad/rad, compliance {fmt(self.compliance, 1e6)} urad/(N m)"
                + (f", motor-side {fmt(self.motor, 1 / ARCSEC)} arcsec" if self.has_motor else "")
                + f" ({self.source})")

    # ------------------------------------------------------------ kernels
    def _own(self, q1, q2, gradient: bool):
        d = q1[:, None, :] - q2[None, :, :]  # (n1, n2, nq)
        a1, a2 = self.once**2, self.twice**2
        if not gradient:
            k = a1 * np.cos(d) + a2 * np.cos(2 * d) + self.gain**2 * q1[:, None, :] * q2[None, :, :]
        else:
            k = -a1 * np.sin(d) - 2 * a2 * np.sin(2 * d) + self.gain**2 * q2[None, :, :]
        return self._matern_parts(d, k, int(gradient))

    def _matern_parts(self, d, k, order: int):
        """``k`` plus the Matérn parts' (smooth, motor-side) ``order``-th derivative at ``d``."""
        for s, length in ((self.smooth, self.length), (self.motor, self.motor_length)):
            if np.any(s > 0):
                k = k + _matern(d, s**2, 1.0 / length**2, order)
        return k

    def compute_own_second(self, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
        r""":math:`k''_\kappa(\Delta)` of the own-angle parts, without the gain and compliance
        parts, (n1, n2, nq) [rad²/rad²] (for the criterion's exact Hessian,
        :mod:`calib_oed.oed.model_error_hessian`)."""
        d = q1[:, None, :] - q2[None, :, :]
        return self._matern_parts(d, -self.once**2 * np.cos(d) - 4.0 * self.twice**2 * np.cos(2 * d), 2)

    def compute_kernels(self, q1: np.ndarray, q2: np.ndarray, tau=None) -> np.ndarray:
        r""":math:`k_k(q_{1,a}, q_{2,b})` (nq, n1, n2) [rad²]; ``tau`` the torques at (q1, q2) if known."""
        k = np.moveaxis(self._own(q1, q2, False), 2, 0)
        if self.gravity is not None and np.any(self.compliance > 0):
            t1, t2 = tau if tau is not None else (self.gravity.torques(q1), self.gravity.torques(q2))
            k = k + (self.compliance**2)[:, None, None] * t1.T[:, :, None] * t2.T[:, None, :]
        return k

    def compute_kernel_gradients(self, q1: np.ndarray, q2: np.ndarray, tau=None) -> np.ndarray:
        r""":math:`\partial k_k(q_{1,a}, q_{2,b})/\partial q_{1,a}` (nq, n1, n2, nv) [rad]; ``tau``:
        (torques at q1, at q2, torque derivatives at q1) if known."""
        n1, n2, nq = q1.shape[0], q2.shape[0], self.nq
        out = np.zeros((nq, n1, n2, nq))
        own = self._own(q1, q2, True)  # (n1, n2, nq)
        idx = np.arange(nq)
        out[idx, :, :, idx] = np.moveaxis(own, 2, 0)
        if self.gravity is not None and np.any(self.compliance > 0):
            if tau is None:
                tau = (None, self.gravity.torques(q2), self.gravity.torque_derivatives(q1))
            _, t2, dt1 = tau  # dt1 (n1, nv, nv): [a, k, m] = d tau_k / d q_m
            out += (self.compliance**2)[:, None, None, None] * np.einsum("akm,bk->kabm", dt1, t2)
        return out


def _matern(d, s2, inv, order: int):
    r""":math:`s^2 m_{5/2}(r)`, :math:`r = |2\sin(\Delta/2)|/\ell` (``inv`` :math:`1/\ell^2`), or its
    first (``order`` 1) or second (2) derivative in the first argument; ``d`` :math:`\Delta` (n1, n2, nq)."""
    r = np.abs(2.0 * np.sin(0.5 * d)) * np.sqrt(inv)
    e = np.exp(-_A * r)
    if order == 0:
        return s2 * (1 + _A * r + 5.0 * r**2 / 3) * e
    g = -(5.0 / 3.0) * (1 + _A * r) * e
    if order == 1:
        return s2 * g * np.sin(d) * inv
    return s2 * ((25.0 / 3.0) * e * np.sin(d) ** 2 * inv**2 + g * np.cos(d) * inv)


@dataclass(frozen=True, eq=False)
class PointJacobians:
    """The nominal arm's point Jacobians in the tracker frame, for the joint-space prior.

    Attributes:
        model, frame_id: Pinocchio model and tool frame.
        offsets: Points on the tool (r, 3) [m, tool frame].
        rotation: :math:`R_{W,T}` of the nominal tracker (3, 3).
    """

    model: object
    frame_id: int
    offsets: np.ndarray
    rotation: np.ndarray

    def compute(self, q: np.ndarray, derivative: bool = False):
        r""":math:`\partial y_r/\partial q` (n, r, 3, nv) [m/rad], tracker frame, and with
        ``derivative`` :math:`\partial^2 y_r/\partial q_k\partial q_l` (n, r, 3, nv, nv) (module docstring)."""
        kin = compute_tool_kinematics(self.model, self.frame_id, q, regressor=False, jacobian=True)
        rt = self.rotation.T
        jac = np.stack([rt @ kin.point_sensitivity(c, "jacobian") for c in self.offsets], axis=1)
        if not derivative:
            return jac, None
        axes = rt @ kin.rotation @ kin.jacobian[:, 3:, :]  # (n, 3, nv)
        cross = np.cross(axes[:, None, :, :, None], jac[:, :, :, None, :], axis=2)  # [j, r, :, k, l]
        return jac, np.triu(cross) + np.swapaxes(np.triu(cross, 1), 3, 4)


def point_jacobians(problem, offsets: np.ndarray) -> PointJacobians:
    """:class:`PointJacobians` of ``problem``'s nominal robot and tracker at ``offsets`` (r, 3) [m]."""
    robot = problem.space.robot
    return PointJacobians(robot.model, robot.tool_frame_id, np.atleast_2d(np.asarray(offsets, dtype=float)),
                          np.asarray(problem.space.tracker_placement(None).rotation))
