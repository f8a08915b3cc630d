"""Scene records: robot, tracker, reflectors, KPI and compliance specs, SI throughout.

What a scene file describes once read (:mod:`calib_oed.scene.reader`): every
length in [m], every angle in [rad], arrays read-only. The world frame is the
robot base, z up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import SceneError
from calib_oed.feasibility.shapes import Cell, FeasibilitySettings
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.error_model import ErrorModel
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.model.compliance import Compliance
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.joint_map import JointGains
from calib_oed.model.robot import Robot
from calib_oed.values import finite_vector

MEASUREMENTS = ("position", "pose")
KPI_FRAMES = ("world", "tracker")
KPI_AGGREGATES = ("mean", "max")
SUPPORTED_VERSIONS = (1,)
DEFAULT_SIGMA_ANGLE = 1e-5  # [rad] = 0.01 mrad


# eq=False: records holding arrays compare by identity (the generated __eq__
# would compare arrays element-wise and fail on truth value).
@dataclass(frozen=True, eq=False)
class TrackerSpec:
    """Laser tracker pose and noise.

    Attributes:
        position: Origin of the tracker frame in the world, :math:`t_{wt}`, shape (3,) [m].
        rpy: Roll, pitch, yaw of the tracker frame in the world, shape (3,) [rad];
            :math:`R_{wt} = R_z(y) R_y(p) R_x(r)` = ``pin.rpy.rpyToMatrix(r, p, y)``.
        sigma: Standard deviation of the position noise along the tracker axes, shape (3,) [m].
        sigma_angle: Standard deviation of the rotation noise about the tracker axes,
            shape (3,) [rad]; used only by the 6-D pose measurement model.
        noise: ``tracker.noise``: range-dependent radial/lateral error model
            (:class:`~calib_oed.measurement.noise.TrackerNoise`, repeatability 0 here;
            the robot's is :attr:`Scene.repeatability`), or None: isotropic ``sigma``.
    """

    position: np.ndarray
    rpy: np.ndarray
    sigma: np.ndarray
    sigma_angle: np.ndarray
    noise: TrackerNoise | None = None

    def __post_init__(self):
        for name in ("position", "rpy", "sigma", "sigma_angle"):
            object.__setattr__(self, name, finite_vector(getattr(self, name), f"tracker.{name}", 3))
        for name in ("sigma", "sigma_angle"):
            if np.any(getattr(self, name) <= 0):
                raise SceneError(f"must be > 0, got {getattr(self, name)}", key=f"tracker.{name}")

    def placement(self) -> pin.SE3:
        """Pose of the tracker in the world, :math:`T_{wt}` (maps tracker to world coordinates)."""
        return pin.SE3(pin.rpy.rpyToMatrix(*self.rpy), np.array(self.position))


@dataclass(frozen=True, eq=False)
class ReflectorSpec:
    """A reflector (SMR) on the tool.

    Attributes:
        name: Reflector name, unique in the scene.
        offset: Reflector centre in the tool frame, shape (3,) [m].
        normal: Reflector axis in the tool frame, unit, shape (3,) (default tool z);
            the incidence constraint measures the beam's angle to it.
        aim: ``"fixed"`` (default: the SMR's axis turns with the tool, the incidence
            constraint holds) or ``"manual"`` (the operator turns the SMR in its nest
            towards the tracker at each pose: no incidence constraint; line of sight,
            the beam rows, still holds).
    """

    name: str
    offset: np.ndarray
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    aim: str = "fixed"

    def __post_init__(self):
        object.__setattr__(self, "offset", finite_vector(self.offset, f"reflector {self.name}", 3))
        normal = np.array(self.normal, dtype=float)
        norm = float(np.linalg.norm(normal)) if normal.shape == (3,) else 0.0
        if not (np.isfinite(norm) and norm > 1e-12):
            raise SceneError(f"expected a non-zero vector nx, ny, nz, got {self.normal!r}",
                             key=f"reflector {self.name}.normal")
        object.__setattr__(self, "normal", finite_vector(normal / norm, f"reflector {self.name}.normal", 3))


@dataclass(frozen=True, eq=False)
class WorkingConfiguration:
    """A configuration at which the KPI is evaluated.

    Attributes:
        name: Configuration name, unique in the scene.
        q: Joint configuration, shape (nq,) [rad] (prismatic joints [m]).
        weight: Its weight >= 0 in the mean KPI variance (default 1; a path's
            samples share the path's weight, ``weight/samples`` each).
        path: Name of the path it samples (``<path>@k``), or None.
    """

    name: str
    q: np.ndarray
    weight: float = 1.0
    path: str | None = None

    def __post_init__(self):
        object.__setattr__(self, "q", finite_vector(self.q, f"working configuration {self.name}"))
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise SceneError(f"expected a number >= 0, got {self.weight!r}",
                             key=f"kpi working configuration {self.name}.weight")


@dataclass(frozen=True, eq=False)
class KpiSpec:
    """The key performance indicator: the position of a tool point at working configurations.

    Attributes:
        point: The point in the tool frame, shape (3,) [m] (zero: the tool frame origin).
        frame: Frame the position is expressed in, ``"world"`` or ``"tracker"``.
        configurations: The working configurations (at least one).
        reflector: Index of the reflector whose (estimated) centre is the KPI
            point instead of ``point``, or None.
        aggregate: How the design criterion combines the KPI points:
            ``"mean"`` (weighted mean variance, the A-criterion) or ``"max"``
            (worst-case variance, docs/oed.md).
    """

    point: np.ndarray
    frame: Literal["world", "tracker"]
    configurations: tuple[WorkingConfiguration, ...]
    reflector: int | None = None
    aggregate: Literal["mean", "max"] = "mean"

    def __post_init__(self):
        object.__setattr__(self, "point", finite_vector(self.point, "kpi.point", 3))
        object.__setattr__(self, "configurations", tuple(self.configurations))
        if self.frame not in KPI_FRAMES:
            raise SceneError(f"expected one of {KPI_FRAMES}, got {self.frame!r}", key="kpi.frame")
        if self.aggregate not in KPI_AGGREGATES:
            raise SceneError(f"expected one of {', '.join(KPI_AGGREGATES)}, got {self.aggregate!r}",
                             key="kpi.aggregate")
        if not self.configurations:
            raise SceneError("expected at least one", key="kpi.working_configurations")
        if not any(c.weight > 0 for c in self.configurations):
            raise SceneError("expected at least one working configuration with weight > 0",
                             key="kpi.working_configurations")

    @property
    def q(self) -> np.ndarray:
        """The working configurations stacked, shape (k, nq) [rad]."""
        out = np.array([c.q for c in self.configurations])
        out.setflags(write=False)
        return out


@dataclass(frozen=True)
class GenericDesignSpec:
    """The fixed-seed random design used by the gauge rule.

    Attributes:
        n: Number of configurations, uniform in the joint limits.
        seed: Seed of :func:`numpy.random.default_rng`.
    """

    n: int = 200
    seed: int = 0


@dataclass(frozen=True, eq=False)
class Scene:
    """A calibration set-up. All quantities SI [m, rad]; world frame = robot base, z up.

    Attributes:
        name: Scene name.
        description: Free text.
        source: The YAML file it came from, or ``None``.
        robot: The loaded robot (tool frame, joint limits applied).
        tracker: Laser tracker pose and noise.
        reflectors: Reflectors on the tool (at least one).
        measurement: ``"position"`` (3-D per reflector) or ``"pose"`` (6-D).
        kpi: The key performance indicator.
        generic_design: The gauge rule's random design.
        units: The file's units as written (``{"length": "mm", "angle": "deg"}``), for reports.
        cell: World-fixed obstacles (capsules, half-spaces) [m]; empty if the file has none.
        feasibility: What makes a measurement configuration executable [m, rad];
            the defaults of :class:`FeasibilitySettings` if the file has no ``feasibility:``.
        compliance: ``robot.compliance``: whether joint compliance is modelled and
            the payload; None if the file has no such block (rigid joints).
    """

    name: str
    description: str
    source: Path | None
    robot: Robot
    tracker: TrackerSpec
    reflectors: tuple[ReflectorSpec, ...]
    measurement: Literal["position", "pose"]
    kpi: KpiSpec
    generic_design: GenericDesignSpec
    units: dict[str, str]
    cell: Cell = field(default_factory=Cell)
    feasibility: FeasibilitySettings = field(default_factory=FeasibilitySettings)
    compliance: ComplianceSpec | None = None
    #: The optional ``program:`` block as written (file units), read by
    #: :mod:`calib_oed.program.settings`; empty if the file has none.
    program: dict = field(default_factory=dict)
    #: ``robot.repeatability``: isotropic standard deviation at the reflector [m]; 0 if absent.
    repeatability: float = 0.0

    def position_noise(self) -> TrackerNoise | None:
        """The full error model of each position measurement, or None (today's isotropic ``sigma``).

        ``tracker.noise`` with the robot's repeatability; the isotropic ``sigma`` plus
        the repeatability when only ``robot.repeatability`` is given.
        """
        if self.tracker.noise is not None:
            return TrackerNoise(self.tracker.noise.radial, self.tracker.noise.lateral,
                                self.repeatability)
        if self.repeatability > 0:
            return TrackerNoise.isotropic(float(self.tracker.sigma[0]), self.repeatability)
        return None
    #: The optional ``controller:`` block: controller joint conventions
    #: (:mod:`calib_oed.model.controller`); None if the file has none.
    controller: ControllerConvention | None = None
    #: The optional ``realistic:`` block as written (file units): the magnitudes of the
    #: realistic simulator, read by :mod:`calib_oed.calibration.realistic_defaults`; empty if absent.
    realistic: dict = field(default_factory=dict)
    #: ``robot.joint_gains``: joint gains and coupling ratios to identify
    #: (:mod:`calib_oed.model.joint_map`); None if the file has none or disables them.
    joint_gains: JointGains | None = None
    #: ``robot.model_error``: the model-error prior as the scene gives it
    #: (:mod:`calib_oed.measurement.discrepancy`); None: the documented default (:meth:`discrepancy`).
    model_error: DiscrepancyPrior | None = None
    #: ``robot.model_error`` with ``kind: joint`` (or ``calib-oed design --prior-from``): the
    #: joint-space prior of ``kpi_model`` as given (:class:`JointErrorSpec`); None: its defaults.
    joint_error: JointErrorSpec | None = None

    def error_model(self) -> ErrorModel:
        """The covariance contract of this scene's measurements (noise, repeatability, model error)."""
        return ErrorModel(self.measurement, self.tracker.sigma, self.tracker.sigma_angle,
                          self.position_noise() if self.measurement == "position" else None,
                          self.discrepancy())

    def discrepancy(self) -> DiscrepancyPrior:
        """The model-error prior: ``robot.model_error``, else the default for the robot's reach."""
        return self.model_error if self.model_error is not None else \
            DiscrepancyPrior.default_for(self.robot)


@dataclass(frozen=True, eq=False)
class ComplianceSpec:
    """``robot.compliance``: joint compliance under gravity (:mod:`calib_oed.model.compliance`).

    Attributes:
        enabled: Model it (one compliance parameter per joint); ``calib-oed
            --compliance`` turns it on for a scene that says ``enabled: false``.
        payload: The payload on the tool (mass [kg], centre of mass in the tool frame [m]).
    """

    enabled: bool
    payload: Compliance

    def model(self) -> Compliance | None:
        """The :class:`~calib_oed.model.compliance.Compliance` of the parameter space, or None if disabled."""
        return self.payload if self.enabled else None




@dataclass(frozen=True, eq=False)
class JointErrorSpec:
    r"""``robot.model_error: {kind: joint, ...}``: what a scene (or an earlier identification)
    sets of the joint-space model-error prior (:class:`~calib_oed.measurement.joint_prior.JointErrorPrior`);
    every other part keeps its default for the robot's size class.

    Attributes:
        values: Part name (``once``, ``twice``, ``smooth``, ``length``, ``gain``, ``compliance``,
            ``motor``, ``motor_length``) -> one value per joint, SI (rad, rad, rad, rad, rad/rad,
            rad/(N·m), rad, rad); NaN keeps
            that joint's default.
        at_point: ``once``, ``twice``, ``smooth`` given as an RMS per Cartesian axis at the
            measured points [m] (an identification's fitted kernel), turned into joint angles by
            each joint's lever arm when the criterion is made (:mod:`calib_oed.calibration.joint_prior_choice`).
        scale: Every amplitude times this (> 0).
        source: Where the numbers come from (the scene, or the identification file).
    """

    values: dict = field(default_factory=dict)
    at_point: dict = field(default_factory=dict)
    scale: float = 1.0
    source: str = "scene"
