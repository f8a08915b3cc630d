"""Calibration scenes: robot, laser tracker, reflectors, noise and KPI, read from YAML.

A scene file states its units once (``units: {length: mm, angle: deg}``);
everything in a :class:`Scene` is SI [m, rad]. The world frame is the robot
base, z up. The schema is documented in ``docs/scenes.md``; the optional
``cell:`` and ``feasibility:`` blocks are read by :mod:`calib_oed.scene_cell`.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pinocchio as pin
import yaml

from calib_oed.compliance import Compliance
from calib_oed.exceptions import (
    CalibOedError,
    NonFiniteError,
    SceneError,
    ShapeError,
    UnknownSceneError,
)
from calib_oed.feasibility.shapes import Cell, FeasibilitySettings
from calib_oed.kpi import sample_joint_path
from calib_oed.robot import Robot, load_robot
from calib_oed.scene_cell import read_cell, read_feasibility

#: Supported units and their value in SI [m] or [rad].
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3}
ANGLE_UNITS: dict[str, float] = {"rad": 1.0, "deg": math.pi / 180.0}
MEASUREMENTS = ("position", "pose")
KPI_FRAMES = ("world", "tracker")
KPI_AGGREGATES = ("mean", "max")
SUPPORTED_VERSIONS = (1,)
DEFAULT_SIGMA_ANGLE = 1e-5  # [rad] = 0.01 mrad


def _readonly(value: Any, what: str, size: int | None = None) -> np.ndarray:
    """A finite, read-only float copy of a vector (of length ``size`` if given)."""
    arr = np.array(value, dtype=float)
    if arr.ndim != 1 or (size is not None and arr.shape[0] != size):
        raise ShapeError(what, f"({size if size is not None else 'n'},)", arr.shape)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(arr)).tolist())
    arr.setflags(write=False)
    return arr


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
    """

    position: np.ndarray
    rpy: np.ndarray
    sigma: np.ndarray
    sigma_angle: np.ndarray

    def __post_init__(self):
        for name in ("position", "rpy", "sigma", "sigma_angle"):
            object.__setattr__(self, name, _readonly(getattr(self, name), f"tracker.{name}", 3))
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
    """

    name: str
    offset: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "offset", _readonly(self.offset, f"reflector {self.name}", 3))


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
        object.__setattr__(self, "q", _readonly(self.q, f"working configuration {self.name}"))
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
        object.__setattr__(self, "point", _readonly(self.point, "kpi.point", 3))
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


@dataclass(frozen=True, eq=False)
class ComplianceSpec:
    """``robot.compliance``: joint compliance under gravity (:mod:`calib_oed.compliance`).

    Attributes:
        enabled: Model it (one compliance parameter per joint); ``calib-oed
            --compliance`` turns it on for a scene that says ``enabled: false``.
        payload: The payload on the tool (mass [kg], centre of mass in the tool frame [m]).
    """

    enabled: bool
    payload: Compliance

    def model(self) -> Compliance | None:
        """The :class:`~calib_oed.compliance.Compliance` of the parameter space, or None if disabled."""
        return self.payload if self.enabled else None


def scene_names() -> list[str]:
    """Names of the shipped scenes (``calib_oed/scenes/<name>.yaml``)."""
    folder = resources.files("calib_oed.scenes")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_scene(name_or_path: str | os.PathLike) -> Scene:
    """Load a shipped scene by name, or a scene file by path.

    Raises:
        UnknownSceneError: a bare name that is neither a shipped scene nor a file.
        SceneError: missing or unreadable file, YAML syntax error, invalid content.
    """
    text = os.fspath(name_or_path)
    if text in scene_names():
        path = Path(str(resources.files("calib_oed.scenes").joinpath(f"{text}.yaml")))
    else:
        path = Path(text)
        looks_like_path = os.sep in text or path.suffix in (".yaml", ".yml") or path.exists()
        if not looks_like_path:
            raise UnknownSceneError(text, scene_names())
        if not path.is_file():
            raise SceneError(f"scene file not found: {path}", source=str(path))
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise SceneError(f"YAML syntax error{at}: {problem}", source=str(path)) from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"cannot read scene file ({exc})", source=str(path)) from exc
    return scene_from_dict(data, source=str(path))


def scene_from_dict(data: Mapping[str, Any], source: str | None = None) -> Scene:
    """Build a :class:`Scene` from the parsed YAML (same validation as :func:`load_scene`).

    Args:
        data: The scene as a mapping (schema version 1, see ``docs/scenes.md``).
        source: File the data came from: named in errors, and the folder
            relative ``robot.urdf`` paths resolve against (default: the working directory).
    """
    return _Reader(source).scene(data)


class _Reader:
    """Validates the parsed YAML key by key; errors name the dotted key."""

    def __init__(self, source: str | None):
        self.source = source
        self.length = self.angle = 1.0  # [m] and [rad] per file unit
        self.units = {"length": "m", "angle": "rad"}

    def fail(self, key: str | None, message: str) -> SceneError:
        return SceneError(message, key=key, source=self.source)

    def mapping(self, value, key, required, optional=()) -> dict:
        where = f"{key}." if key else ""
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a mapping with keys {_keys(required, optional)}, "
                            f"got {value!r}")
        valid = (*required, *optional)
        for k in value:
            if k not in valid:
                raise self.fail(f"{where}{k}", f"unknown key; valid keys of {_at(key)} are: "
                                f"{', '.join(valid)}")
        for k in required:
            if k not in value:
                raise self.fail(f"{where}{k}", f"missing required key; {_at(key)} requires: "
                                f"{', '.join(required)}")
        return dict(value)

    def free_mapping(self, value, key) -> dict:
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a mapping {{joint name: value}}, got {value!r}")
        return dict(value)

    def number(self, value, key, scale=1.0, positive=False, nonnegative=False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            hint = ""
            if isinstance(value, str) and _parses_as_float(value):
                hint = " (YAML reads a number like 1e-5 as text: write 1.0e-5)"
            raise self.fail(key, f"expected a number, got {value!r}{hint}")
        if not math.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(key, f"expected a number > 0, got {value!r}")
        if nonnegative and value < 0:
            raise self.fail(key, f"expected a number >= 0, got {value!r}")
        return float(value) * scale

    def vector(self, value, key, n, scale=1.0, what=None) -> np.ndarray:
        """A list of ``n`` finite numbers times ``scale``; ``what`` explains the entries."""
        why = f" ({what})" if what else ""
        if not isinstance(value, list):
            raise self.fail(key, f"expected a list of {n} numbers{why}, got {value!r}")
        if len(value) != n:
            raise self.fail(key, f"expected {n} values{why}, got {len(value)}: {value!r}")
        return np.array([self.number(v, f"{key}[{i}]", scale) for i, v in enumerate(value)])

    def vector3_or_scalar(self, value, key, scale) -> np.ndarray:
        """A number > 0 for all three axes, or a list of three."""
        if not isinstance(value, list):
            return np.full(3, self.number(value, key, scale, positive=True))
        if len(value) != 3:
            raise self.fail(key, f"expected a number or 3 values, got {len(value)}: {value!r}")
        return np.array([self.number(v, f"{key}[{i}]", scale, positive=True)
                         for i, v in enumerate(value)])

    def string(self, value, key, choices=None) -> str:
        if choices is not None and (not isinstance(value, str) or value not in choices):
            raise self.fail(key, f"expected one of {', '.join(choices)}, got {value!r}")
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"expected a non-empty string, got {value!r}")
        return value

    def integer(self, value, key, minimum) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(key, f"expected an integer >= {minimum}, got {value!r}")
        return value

    def named_list(self, value, key, fields, what, optional=()) -> list[dict]:
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"expected a non-empty list of {what}s, got {value!r}")
        items, seen = [], set()
        for i, item in enumerate(value):
            item = self.mapping(item, f"{key}[{i}]", fields, optional)
            name = self.string(item["name"], f"{key}[{i}].name")
            if name in seen:
                raise self.fail(f"{key}[{i}].name", f"duplicate {what} name {name!r}")
            seen.add(name)
            items.append(item)
        return items

    def scene(self, data) -> Scene:
        top = self.mapping(data, None, ("version", "name", "units", "robot", "tracker",
                                        "reflectors", "kpi"),
                           ("description", "measurement", "generic_design", "cell",
                            "feasibility"))
        if top["version"] not in SUPPORTED_VERSIONS or isinstance(top["version"], bool):
            raise self.fail("version", f"unsupported scene file version {top['version']!r}; "
                            f"supported versions: {', '.join(map(str, SUPPORTED_VERSIONS))}")
        units = self.mapping(top["units"], "units", ("length", "angle"))
        self.units = {k: self.string(units[k], f"units.{k}", table)
                      for k, table in (("length", LENGTH_UNITS), ("angle", ANGLE_UNITS))}
        self.length = LENGTH_UNITS[self.units["length"]]
        self.angle = ANGLE_UNITS[self.units["angle"]]
        description = top.get("description", "")
        if not isinstance(description, str):
            raise self.fail("description", f"expected a string, got {description!r}")
        robot = self.robot(top["robot"])
        compliance = (self.compliance(top["robot"]["compliance"])
                      if "compliance" in top["robot"] else None)
        gd = self.mapping(top.get("generic_design", {}), "generic_design", (), ("n", "seed"))
        return Scene(
            name=self.string(top["name"], "name"),
            description=description,
            source=Path(self.source) if self.source else None,
            robot=robot,
            tracker=self.tracker(top["tracker"]),
            reflectors=tuple(
                ReflectorSpec(r["name"], self.vector(r["offset"], f"reflectors[{i}].offset", 3,
                                                     self.length))
                for i, r in enumerate(self.named_list(top["reflectors"], "reflectors",
                                                      ("name", "offset"), "reflector"))
            ),
            measurement=self.string(top.get("measurement", "position"), "measurement",
                                    MEASUREMENTS),
            kpi=self.kpi(top["kpi"], robot, [r["name"] for r in top["reflectors"]]),
            generic_design=GenericDesignSpec(
                n=self.integer(gd.get("n", 200), "generic_design.n", 1),
                seed=self.integer(gd.get("seed", 0), "generic_design.seed", 0),
            ),
            units=dict(self.units),
            cell=read_cell(self, top["cell"]) if "cell" in top else Cell(),
            feasibility=(read_feasibility(self, top["feasibility"], robot)
                         if "feasibility" in top else FeasibilitySettings()),
            compliance=compliance,
        )

    def robot(self, value) -> Robot:
        spec = self.mapping(value, "robot", (), ("name", "urdf", "tool_frame", "joint_limits",
                                                 "lock_joints", "package_dirs", "compliance"))
        if ("name" in spec) == ("urdf" in spec):
            given = [k for k in ("name", "urdf") if k in spec]
            raise self.fail("robot", "expected exactly one of 'name' (a robot name) or 'urdf' "
                            f"(a URDF file path), got {given or 'neither'}")
        if "name" in spec:
            source = self.string(spec["name"], "robot.name")
        else:
            path = Path(self.string(spec["urdf"], "robot.urdf")).expanduser()
            if not path.is_absolute():
                path = (Path(self.source).parent if self.source else Path.cwd()) / path
            if not path.is_file():
                raise self.fail("robot.urdf", f"URDF file not found: {path}")
            source = str(path.resolve())
        tool = self.string(spec["tool_frame"], "robot.tool_frame") if "tool_frame" in spec else None
        packages = self.package_dirs(spec.get("package_dirs", []))
        limits = self.free_mapping(spec.get("joint_limits", {}), "robot.joint_limits")
        locks = self.free_mapping(spec.get("lock_joints", {}), "robot.lock_joints")
        try:
            robot = load_robot(source, tool_frame=tool, lock_joints={j: 0.0 for j in locks},
                               package_dirs=packages)
            if not (limits or locks):
                return robot
            # Joint types are known only once the URDF is read: prismatic joints take lengths.
            types = {j.get("name"): j.get("type") for j in ET.fromstring(robot.urdf_text)
                     .iter("joint")}
            for j in limits:
                if j not in robot.joint_names:
                    raise self.fail(f"robot.joint_limits.{j}", "unknown joint; the robot's "
                                    f"joints are: {', '.join(robot.joint_names)}")
            scale = {j: self.length if t == "prismatic" else self.angle for j, t in types.items()}
            bounds = {j: self.vector(v, f"robot.joint_limits.{j}", 2, what="lower, upper")
                      for j, v in limits.items()}
            for j, (lo, hi) in bounds.items():
                if not lo < hi:
                    raise self.fail(f"robot.joint_limits.{j}", f"lower limit {lo:.6g} is not "
                                    f"below upper limit {hi:.6g}")
            return load_robot(
                source, tool_frame=tool,
                joint_limits={j: b * scale[j] for j, b in bounds.items()},
                lock_joints={j: self.number(v, f"robot.lock_joints.{j}", scale[j])
                             for j, v in locks.items()},
                package_dirs=packages,
            )
        except SceneError:
            raise
        except CalibOedError as exc:
            raise self.fail("robot", str(exc)) from exc

    def compliance(self, value) -> ComplianceSpec:
        """``robot.compliance: {enabled: true, payload: {mass: kg, com: [x, y, z]}}`` (com in length units)."""
        spec = self.mapping(value, "robot.compliance", (), ("enabled", "payload"))
        enabled = spec.get("enabled", True)
        if not isinstance(enabled, bool):
            raise self.fail("robot.compliance.enabled", f"expected true or false, got {enabled!r}")
        load = self.mapping(spec.get("payload", {}), "robot.compliance.payload", (), ("mass", "com"))
        mass = self.number(load.get("mass", 0.0), "robot.compliance.payload.mass", nonnegative=True)
        com = self.vector(load.get("com", [0, 0, 0]), "robot.compliance.payload.com", 3, self.length)
        return ComplianceSpec(enabled, Compliance(mass, com))

    def package_dirs(self, value) -> list[str] | None:
        """``robot.package_dirs``: folders searched for ``package://`` meshes, relative to the file."""
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list):
            raise self.fail("robot.package_dirs", f"expected a list of folders, got {value!r}")
        out = []
        for k, entry in enumerate(value):
            path = Path(self.string(entry, f"robot.package_dirs[{k}]")).expanduser()
            if not path.is_absolute():
                path = (Path(self.source).parent if self.source else Path.cwd()) / path
            if not path.is_dir():
                raise self.fail(f"robot.package_dirs[{k}]", f"folder not found: {path}")
            out.append(str(path.resolve()))
        return out or None

    def tracker(self, value) -> TrackerSpec:
        spec = self.mapping(value, "tracker", ("position", "rpy", "sigma"), ("sigma_angle",))
        sigma_angle = (self.vector3_or_scalar(spec["sigma_angle"], "tracker.sigma_angle",
                                              self.angle)
                       if "sigma_angle" in spec else np.full(3, DEFAULT_SIGMA_ANGLE))
        return TrackerSpec(
            position=self.vector(spec["position"], "tracker.position", 3, self.length),
            rpy=self.vector(spec["rpy"], "tracker.rpy", 3, self.angle),
            sigma=self.vector3_or_scalar(spec["sigma"], "tracker.sigma", self.length),
            sigma_angle=sigma_angle,
        )

    def kpi(self, value, robot: Robot, reflector_names: list[str]) -> KpiSpec:
        spec = self.mapping(value, "kpi", (),
                            ("working_configurations", "paths", "aggregate", "point", "frame",
                             "reflector"))
        if "working_configurations" not in spec and "paths" not in spec:
            raise self.fail("kpi.working_configurations", "missing required key; kpi requires "
                            "working_configurations, paths or both")
        reflector = None
        if "reflector" in spec:
            if "point" in spec:
                raise self.fail("kpi.reflector", "give either kpi.point or kpi.reflector, not both")
            if spec["reflector"] not in reflector_names:
                raise self.fail("kpi.reflector", f"expected one of the reflectors "
                                f"{reflector_names}, got {spec['reflector']!r}")
            reflector = reflector_names.index(spec["reflector"])
        key = "kpi.working_configurations"
        joints = robot.joint_names
        per_joint = f"one per joint: {', '.join(joints)}"
        prismatic = [j.shortname().startswith("JointModelP") for j in robot.model.joints[1:]]
        scale = np.where(prismatic, self.length, self.angle)
        units = [self.units["length" if p else "angle"] for p in prismatic]
        configurations = []

        def joint_vector(value, where):
            q = self.vector(value, where, len(joints), what=per_joint) * scale
            for j, name in enumerate(joints):
                lo, hi, s, unit = robot.lower[j], robot.upper[j], scale[j], units[j]
                if not lo - 1e-9 <= q[j] <= hi + 1e-9:  # 1e-9: rounding of unit conversion
                    raise self.fail(where, f"{name} = {q[j] / s:.6g} {unit} is "
                                    f"outside its limits [{lo / s:.6g}, {hi / s:.6g}] {unit}")
            return q

        for i, wc in enumerate(self.named_list(spec["working_configurations"], key,
                                               ("name", "q"), "working configuration", ("weight",))
                               if "working_configurations" in spec else []):
            weight = self.number(wc.get("weight", 1.0), f"{key}[{i}].weight", nonnegative=True)
            configurations.append(WorkingConfiguration(wc["name"], joint_vector(wc["q"], f"{key}[{i}].q"),
                                                       weight))
        names = {c.name for c in configurations}
        for i, path in enumerate(self.named_list(spec["paths"], "kpi.paths",
                                                 ("name", "waypoints", "samples"), "path",
                                                 ("weight",)) if "paths" in spec else []):
            pkey = f"kpi.paths[{i}]"
            if path["name"] in names or "@" in path["name"]:
                raise self.fail(f"{pkey}.name", f"path name {path['name']!r} must differ from the "
                                "working configurations' names and contain no '@'")
            points = path["waypoints"]
            if not isinstance(points, list) or len(points) < 2:
                raise self.fail(f"{pkey}.waypoints", "expected a list of at least 2 joint "
                                f"configurations ({per_joint}), got {points!r}")
            way = np.array([joint_vector(v, f"{pkey}.waypoints[{k}]") for k, v in enumerate(points)])
            m = self.integer(path["samples"], f"{pkey}.samples", 2)
            if not np.any(np.abs(np.diff(way, axis=0)) > 0):
                raise self.fail(f"{pkey}.waypoints", "all waypoints are equal: the path has zero length")
            weight = self.number(path.get("weight", 1.0), f"{pkey}.weight", nonnegative=True)
            for k, q in enumerate(sample_joint_path(way, m)):
                configurations.append(WorkingConfiguration(f"{path['name']}@{k}", q, weight / m,
                                                           path["name"]))
        return KpiSpec(
            point=self.vector(spec.get("point", [0, 0, 0]), "kpi.point", 3, self.length),
            frame=self.string(spec.get("frame", "world"), "kpi.frame", KPI_FRAMES),
            configurations=tuple(configurations),
            reflector=reflector,
            aggregate=self.string(spec.get("aggregate", "mean"), "kpi.aggregate", KPI_AGGREGATES),
        )


def _keys(required, optional) -> str:
    return ", ".join([*required, *(f"{k} (optional)" for k in optional)]) or "(none fixed)"


def _at(key: str | None) -> str:
    return repr(key) if key else "the top level"


def _parses_as_float(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
