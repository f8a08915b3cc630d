r"""A realistic robot to test against: what real arms have and the kinematic model does not.

The truth of :func:`sample_truth` (a :class:`RealisticTruth`) maps a commanded
configuration :math:`q` (n, nq) [rad] to the true reflector and TCP positions,
and those to tracker readings. Per row, in this order:

1. **geometry** (modelled): the perturbed joint placements, tracker pose and
   reflector offsets of :func:`calib_oed.calibration.simulation.draw_true_parameters`
   (0.5 mm / 0.5 mrad on the free parameters; joint gains if the scene has them);
2. **transmission errors** (unmodelled): per joint :math:`i` with gear ratio :math:`N_i`,

   .. math::
       e_i(q_i) = \sum_{h=1,2} a_{ih}\sin(h q_i + \alpha_{ih})
                + \sum_{h=1,2} b_{ih}\sin(h N_i q_i + \beta_{ih}) \quad [\mathrm{rad}],

   once and twice per revolution of the joint (:math:`a`) and of its motor (:math:`b`);
3. **gravity compliance** (unmodelled unless the model has compliance):
   :math:`c_i\,(\tau_{g,i}(q) + \tau_{b,i}(q))`, :math:`c_i = 1/k_i` [rad/(N·m)],
   :math:`\tau_g = -g(q)` from ``pin.computeGeneralizedGravity`` on the URDF's
   inertials with the payload and the reflector nest on the tool
   (:class:`calib_oed.model.compliance.GravityLoad`, the model's own convention);
4. **J2 balancer** (unmodelled): a spring torque on the second joint,
   :math:`\tau_{b,2}(q_2)` (:class:`Balancer`), part of the torque the J2 gear carries;
5. **joint gain errors** (unmodelled unless the scene identifies joint gains):
   :math:`\nu\circ q`, a small scale error of every joint's angle (gear ratio, encoder);
6. **thermal drift** (unmodelled, off by default): the arm expands uniformly,
   every world point scaled about the base by :math:`1 + \alpha\,\Delta T\,t`,
   :math:`t \in [0, 1]` the time of the measurement in the session (row order);
7. **tracker systematics** (unmodelled), in the tracker frame, range
   :math:`r`, azimuth :math:`\theta` = atan2(y, x), elevation :math:`\varphi`:
   :math:`r' = (1 + s)\,r`, :math:`\theta' = \theta + e_\theta\sin(\theta + \gamma_\theta)`,
   :math:`\varphi' = \varphi + e_\varphi\sin(\varphi + \gamma_\varphi)`: scale
   error :math:`s` and the eccentricity of the two angle encoders (once per revolution);
8. the scene's measurement noise (``tracker.noise`` / ``sigma``, robot
   repeatability) and optionally a few gross errors (:mod:`calib_oed.calibration.realistic_measure`).

The joint errors of 2-5 add: the kinematics run at
:math:`q_{eff} = q + g\circ q + \nu\circ q + e(q) + c\circ(\tau_g + \tau_b)` (:math:`g` the
modelled gains, only if the scene identifies them). ``level`` scales every unmodelled part (2-7)
together. The defaults and their sources: ``docs/identification.md`` (the
realistic simulator) and :mod:`calib_oed.calibration.realistic_defaults`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from calib_oed.calibration.realistic_defaults import (
    RealisticSettings,
    realistic_settings_from_scene,
)
from calib_oed.calibration.simulation import draw_true_parameters
from calib_oed.exceptions import ParameterError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.model.compliance import Compliance, GravityLoad
from calib_oed.model.joint_map import effective_configurations
from calib_oed.model.kinematics import compute_tool_kinematics
from calib_oed.model.parameters import ParameterSpace
from calib_oed.model.size_class import arm_mass


@dataclass(frozen=True, eq=False)
class Transmission:
    """Periodic transmission errors of every joint (level already applied).

    Attributes:
        gear_ratios: :math:`N_i`, motor turns per joint turn, (nv,).
        joint_amplitude: :math:`a_{ih}` [rad], (nv, 2): once, twice per joint revolution.
        joint_phase: :math:`\\alpha_{ih}` [rad], (nv, 2).
        motor_amplitude: :math:`b_{ih}` [rad], (nv, 2): once, twice per motor revolution.
        motor_phase: :math:`\\beta_{ih}` [rad], (nv, 2).
    """

    gear_ratios: np.ndarray
    joint_amplitude: np.ndarray
    joint_phase: np.ndarray
    motor_amplitude: np.ndarray
    motor_phase: np.ndarray

    def compute_errors(self, q: np.ndarray) -> np.ndarray:
        """:math:`e(q)`, (n, nv) [rad]."""
        e = np.zeros_like(q)
        for h in (1, 2):
            e += self.joint_amplitude[:, h - 1] * np.sin(h * q + self.joint_phase[:, h - 1])
            e += self.motor_amplitude[:, h - 1] * np.sin(h * self.gear_ratios * q + self.motor_phase[:, h - 1])
        return e


@dataclass(frozen=True)
class Balancer:
    r"""A spring balancer on one joint (J2): a torque that depends on that joint's angle only.

    A spring from a point on the base at distance 1 from the joint axis to a
    point on the link at distance :math:`\rho` (both in units of the first), the
    angle between them :math:`\phi = q_j - \theta_0`: spring length
    :math:`L = \sqrt{1 + \rho^2 - 2\rho\cos\phi}` (law of cosines), force
    :math:`F \propto 1 + \kappa\,(L - L_0)/L_0` (a progressive gas spring,
    :math:`L_0 = 1 - \rho`), lever :math:`\rho\sin\phi / L`:

    .. math::
        \tau_b(q_j) = -T\, \frac{F(L)\,\sin\phi / L}{\max_\phi F(L)\,\sin\phi / L} \quad [\mathrm{N\,m}]

    :math:`\theta_0` is where the arm's gravity torque on the joint vanishes
    (arm upright), so the balancer opposes gravity; :math:`T` is ``fraction``
    times the amplitude of that gravity torque (level applied).

    Attributes:
        joint: Index of the joint (0-based; 1 = J2).
        torque: :math:`T` [N·m].
        theta0: :math:`\theta_0` [rad].
        rho: :math:`\rho` [1].
        kappa: :math:`\kappa` [1].
    """

    joint: int
    torque: float
    theta0: float
    rho: float
    kappa: float

    def _shape(self, phi: np.ndarray) -> np.ndarray:
        length = np.sqrt(1.0 + self.rho**2 - 2.0 * self.rho * np.cos(phi))
        rest = 1.0 - self.rho
        return (1.0 + self.kappa * (length - rest) / rest) * np.sin(phi) / length

    def compute_torques(self, q: np.ndarray) -> np.ndarray:
        r""":math:`\tau_b` on every joint, (n, nv) [N·m] (zero but on ``joint``)."""
        peak = float(np.max(np.abs(self._shape(np.linspace(-np.pi, np.pi, 3601)))))
        tau = np.zeros_like(q)
        tau[:, self.joint] = -self.torque * self._shape(q[:, self.joint] - self.theta0) / peak
        return tau


@dataclass(frozen=True)
class TrackerSystematics:
    """Tracker errors beyond its noise (level applied).

    Attributes:
        scale: :math:`s`, range scale error [1] (ppm = 1e-6).
        azimuth_eccentricity: :math:`e_\\theta` [rad]; ``azimuth_phase`` :math:`\\gamma_\\theta` [rad].
        elevation_eccentricity: :math:`e_\\varphi` [rad]; ``elevation_phase`` :math:`\\gamma_\\varphi` [rad].
    """

    scale: float = 0.0
    azimuth_eccentricity: float = 0.0
    azimuth_phase: float = 0.0
    elevation_eccentricity: float = 0.0
    elevation_phase: float = 0.0

    def compute_readings(self, y: np.ndarray) -> np.ndarray:
        """What the tracker reports for true tracker-frame points ``y`` (..., 3) [m]."""
        r = np.linalg.norm(y, axis=-1)
        az = np.arctan2(y[..., 1], y[..., 0])
        el = np.arctan2(y[..., 2], np.hypot(y[..., 0], y[..., 1]))
        r = r * (1.0 + self.scale)
        az = az + self.azimuth_eccentricity * np.sin(az + self.azimuth_phase)
        el = el + self.elevation_eccentricity * np.sin(el + self.elevation_phase)
        return np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=-1)


@dataclass(frozen=True, eq=False)
class RealisticTruth:
    r"""One realistic true robot and tracker (:func:`sample_truth`).

    Attributes:
        space: The scene's parameter layout (robot, nominal tracker and reflectors).
        settings: The magnitudes it was drawn with.
        p: True parameters in ``space``'s layout (n_p,) [SI]: geometry and joint
            gains; its compliance entries are 0 (compliance is ``compliance`` below).
        stiffness: Drawn joint stiffness :math:`k` (nv,) [N·m/rad] (before ``level``).
        compliance: :math:`c` (nv,) [rad/(N·m)] applied: ``level / k``, 0 when switched off.
        payload_mass: Payload plus reflector nest on the tool [kg].
        payload_com: Its centre of mass in the tool frame (3,) [m].
        transmission: Periodic transmission errors.
        balancer: The J2 balancer, or None.
        thermal_expansion: :math:`\\alpha\\,\\Delta T` over the session [1] (0: off).
        tracker: Tracker systematics.
        gravity: Gravity torques of the nominal arm with the payload (not serialized).
        gain_errors: Joint gain (scale) errors :math:`\nu` (nv,) [rad/rad], applied as
            :math:`\nu\circ q` (level applied; None: zeros).
    """

    space: ParameterSpace
    settings: RealisticSettings
    p: np.ndarray
    stiffness: np.ndarray
    compliance: np.ndarray
    payload_mass: float
    payload_com: np.ndarray
    transmission: Transmission
    balancer: Balancer | None
    thermal_expansion: float
    tracker: TrackerSystematics
    gravity: GravityLoad = field(repr=False)
    gain_errors: np.ndarray | None = None

    # ------------------------------------------------------------ joints
    def compute_gravity_torques(self, q: np.ndarray) -> np.ndarray:
        r""":math:`\tau_g(q) = -g(q)` with payload and nest, (n, nv) [N·m]."""
        return self.gravity.torques(q)

    def compute_joint_errors(self, q: np.ndarray) -> np.ndarray:
        r""":math:`q_{eff} - q`: gains, transmission, compliance (gravity + balancer), (n, nv) [rad]."""
        q = self.space.robot.check_configurations(q)
        dq = self.transmission.compute_errors(q)
        if self.gain_errors is not None:
            dq = dq + self.gain_errors * q
        if np.any(self.compliance != 0):
            tau = self.compute_gravity_torques(q)
            if self.balancer is not None:
                tau = tau + self.balancer.compute_torques(q)
            dq = dq + self.compliance * tau
        if self.space.gain_basis is not None:
            dq = dq + effective_configurations(q, self.space.gain_basis, self.p[self.space.gain_slice]) - q
        return dq

    # ------------------------------------------------------------ points
    def compute_tool_points(self, q: np.ndarray, offsets: np.ndarray, time: float | np.ndarray = 0.0
                            ) -> np.ndarray:
        """True world positions of tool points ``offsets`` (m, 3) [m, tool frame], (n, m, 3) [m].

        ``time``: the time of each row in the session, scalar or (n,), in [0, 1]
        (thermal drift only; 0 = the start, the cold robot).
        """
        q = self.space.robot.check_configurations(q)
        model = self.space.perturbed_model(self.p)
        kin = compute_tool_kinematics(model, self.space.robot.tool_frame_id, q + self.compute_joint_errors(q),
                                      regressor=False, jacobian=False)
        offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
        x = kin.translation[:, None, :] + np.einsum("nij,mj->nmi", kin.rotation, offsets)
        t = np.broadcast_to(np.asarray(time, dtype=float), (q.shape[0],))
        if np.any((t < 0) | (t > 1)):
            raise ParameterError(f"time must lie in [0, 1] (the session), got {np.min(t)}..{np.max(t)}")
        return x * (1.0 + self.thermal_expansion * t)[:, None, None]

    def compute_reflector_points(self, q: np.ndarray, time: float | np.ndarray = 0.0) -> np.ndarray:
        """True world positions of every reflector centre, (n, k, 3) [m]."""
        return self.compute_tool_points(q, self.space.reflector_offsets(self.p), time)

    def compute_tcp(self, q: np.ndarray, point: np.ndarray | None = None,
                    time: float | np.ndarray = 0.0) -> np.ndarray:
        """True world position of the tool point ``point`` (default the tool-frame origin), (n, 3) [m]."""
        b = np.zeros(3) if point is None else np.asarray(point, dtype=float)
        return self.compute_tool_points(q, b[None], time)[:, 0]

    def compute_kpi_values(self, kpi, time: float = 0.0) -> np.ndarray:
        """The true value of a :class:`~calib_oed.calibration.kpi.TcpKpi` (its point or reflector
        centre, world or true tracker frame, no tracker systematics), (t, 3) [m]: the counterpart of
        ``kpi.compute_values(space, p)``, so ``kpi.compute_values(space, p_hat) - this`` is the
        error of a calibrated model at the working configurations."""
        point = kpi.point if kpi.reflector is None else self.space.reflector_offsets(self.p)[kpi.reflector]
        x = self.compute_tcp(kpi.configurations, point, time)
        if kpi.frame == "tracker":
            tracker = self.space.tracker_placement(self.p)
            x = (x - tracker.translation) @ tracker.rotation
        return x

    def compute_model_errors(self, p_model: np.ndarray | None, q: np.ndarray, point: np.ndarray | None = None,
                             time: float | np.ndarray = 0.0) -> np.ndarray:
        """World position error of the model ``p_model`` (``space``'s layout, None: nominal) at ``q``
        (n, nq): predicted minus true, (n, k, 3) [m] for every reflector centre, or (n, 3) for
        the tool point ``point`` [m, tool frame]. The achieved error of a calibration at new poses."""
        state = evaluate_setup(self.space, p_model, q, regressor=False, jacobian=False)
        if point is not None:
            return state.kin.points(point) - self.compute_tcp(q, point, time)
        predicted = np.stack([state.kin.points(c) for c in state.reflectors], axis=1)
        return predicted - self.compute_reflector_points(q, time)

    def compute_tracker_readings(self, world: np.ndarray) -> np.ndarray:
        """Noise-free tracker readings (tracker frame, systematics applied) of world points (..., 3) [m]."""
        tracker = self.space.tracker_placement(self.p)
        return self.tracker.compute_readings((world - tracker.translation) @ tracker.rotation)


def gravity_load(scene, robot, mass: float, com: np.ndarray) -> GravityLoad:
    """The true arm's gravity load: the URDF's inertials (or the scene's ``robot.compliance.links``
    point masses) with ``mass`` [kg] at ``com`` (tool frame, [m]) on the tool."""
    spec = getattr(scene, "compliance", None)
    links = spec.payload if spec is not None else Compliance()
    return GravityLoad(robot.model, robot.tool_frame_id,
                       Compliance(mass, com, link_masses=links.link_masses, link_coms=links.link_coms))


def _arm_mass(model: pin.Model, scene) -> float:
    """The arm's mass [kg]: the scene's ``robot.compliance.links`` masses if given, else the URDF's."""
    spec = getattr(scene, "compliance", None)
    if spec is not None and spec.payload.link_masses is not None:
        return float(np.sum(spec.payload.link_masses))
    return arm_mass(model)


def _balancer_zero(gravity: GravityLoad, joint: int, nq: int) -> tuple[float, float]:
    r"""Amplitude [N·m] and zero angle :math:`\theta_0` of the arm's gravity torque on ``joint``,
    :math:`\tau \approx A\sin(q_j - \theta_0)`, fitted over a turn with the other joints at 0."""
    angles = np.linspace(-np.pi, np.pi, 73)
    q = np.zeros((angles.size, nq))
    q[:, joint] = angles
    tau = gravity.torques(q)[:, joint]
    (s, c), *_ = np.linalg.lstsq(np.column_stack([np.sin(angles), np.cos(angles)]), tau, rcond=None)
    # tau = s sin q + c cos q = A sin(q - theta0) with A cos theta0 = s, -A sin theta0 = c
    return float(np.hypot(s, c)), float(np.arctan2(-c, s))


def sample_truth(setup, rng: np.random.Generator | int,
                 settings: RealisticSettings | None = None) -> RealisticTruth:
    """Draw a realistic true robot and tracker for a :class:`~calib_oed.calibration.workflow.Setup`.

    ``settings``: None for the scene's ``realistic:`` block (the defaults where it says nothing).

    Every component is drawn whether switched on or not (in a fixed order), so
    switching one off leaves the others' values unchanged for the same ``rng``.
    """
    settings = realistic_settings_from_scene(setup.scene) if settings is None else settings
    rng = np.random.default_rng(rng)
    problem = setup.problem
    space = problem.space
    robot = space.robot
    nv = robot.model.nv
    if robot.model.nq != nv:
        raise ParameterError(f"the realistic simulator needs 1-DoF joints (nq = nv); {robot.name} has "
                             f"nq={robot.model.nq}, nv={nv}")
    p = draw_true_parameters(space, problem.identifiability.free_indices, rng,
                             settings.sigma_length, settings.sigma_angle)
    p[space.compliance_slice] = 0.0
    if not settings.geometric:
        p[: space.compliance_slice.start] = 0.0
    size = settings.size_class_of(_arm_mass(robot.model, setup.scene))
    defaults = settings.table(size, nv)
    level = settings.level
    # stiffness: log-normal about the size class's typical value
    stiffness = defaults.stiffness * np.exp(settings.stiffness_spread * rng.normal(size=nv))
    compliance = level / stiffness if settings.compliance else np.zeros(nv)
    # transmission: amplitudes uniform in [0.5, 1.5] x typical, phases uniform
    ja = settings.joint_cyclic * rng.uniform(0.5, 1.5, size=(nv, 2))
    jp = rng.uniform(0, 2 * np.pi, size=(nv, 2))
    ma = settings.motor_cyclic * rng.uniform(0.5, 1.5, size=(nv, 2))
    mp = rng.uniform(0, 2 * np.pi, size=(nv, 2))
    on = level if settings.transmission else 0.0
    transmission = Transmission(defaults.gear_ratios.copy(), on * ja, jp, on * ma, mp)
    # payload and reflector nest (not scaled by the level: a real mass)
    payload_mass, payload_com = settings.payload_of(setup.scene)
    offsets = space.reflector_offsets(space.zeros())
    total = payload_mass + settings.nest_mass
    com = (payload_mass * payload_com + settings.nest_mass * offsets.mean(axis=0)) / total if total > 0 \
        else np.zeros(3)
    gravity = gravity_load(setup.scene, robot, total, com)
    # balancer on J2
    fraction = defaults.balancer_fraction * rng.uniform(0.8, 1.2)
    balancer = None
    if settings.balancer and fraction > 0 and nv >= 2:
        amp, theta0 = _balancer_zero(gravity, 1, robot.model.nq)
        balancer = Balancer(1, level * fraction * amp, theta0, settings.balancer_rho, settings.balancer_kappa)
    thermal_draw = rng.uniform(0.5, 1.5)
    thermal = level * settings.thermal_alpha * settings.thermal_delta_t * thermal_draw if settings.thermal else 0.0
    # tracker: scale normal (sd in ppm), eccentricities uniform in [0.5, 1.5] x typical
    draws = rng.normal(), rng.uniform(0.5, 1.5, size=2), rng.uniform(0, 2 * np.pi, size=2)
    tk = level if settings.tracker else 0.0
    tracker = TrackerSystematics(tk * settings.tracker_scale_ppm * 1e-6 * draws[0],
                                 tk * settings.encoder_eccentricity * draws[1][0], float(draws[2][0]),
                                 tk * settings.encoder_eccentricity * draws[1][1], float(draws[2][1]))
    # joint gain errors: drawn last, so the draws above do not depend on them
    gains = (level if settings.gains else 0.0) * settings.sigma_gain * rng.normal(size=nv)
    for arr in (p, stiffness, compliance, com, gains):
        arr.setflags(write=False)
    return RealisticTruth(space, settings, p, stiffness, compliance, float(total), com, transmission,
                          balancer, float(thermal), tracker, gravity, gains)
