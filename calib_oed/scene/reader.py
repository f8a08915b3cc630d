"""Calibration scenes: robot, laser tracker, reflectors, noise and KPI, read from YAML.

A scene file states its units once (``units: {length: mm, angle: deg}``);
everything in a :class:`Scene` is SI [m, rad]. The world frame is the robot
base, z up. The schema is documented in ``docs/scenes.md``; the optional
``cell:`` and ``feasibility:`` blocks are read by :mod:`calib_oed.scene.cell`.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from calib_oed.exceptions import (
    CalibOedError,
    InputFileError,
    SceneError,
    UnknownSceneError,
)
from calib_oed.feasibility.shapes import AIMS, Cell, FeasibilitySettings
from calib_oed.measurement.noise import TrackerNoise, sigma_from_mpe, sigma_from_repeatability
from calib_oed.model.controller import controller_from_mapping
from calib_oed.model.joint_path import sample_joint_path
from calib_oed.model.robot import Robot, load_robot
from calib_oed.scene.cell import read_cell, read_feasibility, reflector_normal
from calib_oed.scene.checks import check_scene
from calib_oed.scene.fields import FieldReader
from calib_oed.scene.include import resolve_includes
from calib_oed.scene.joint_error import read_joint_error
from calib_oed.scene.joint_keys import read_compliance, read_joint_gains, read_model_error
from calib_oed.scene.records import (
    DEFAULT_SIGMA_ANGLE,
    KPI_AGGREGATES,
    KPI_FRAMES,
    MEASUREMENTS,
    SUPPORTED_VERSIONS,
    GenericDesignSpec,
    KpiSpec,
    ReflectorSpec,
    Scene,
    TrackerSpec,
    WorkingConfiguration,
)
from calib_oed.scene.yaml_file import load_yaml_file, shipped_file, shipped_names
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS

#: The package of the shipped scenes.
SHIPPED = "calib_oed.scene.shipped"


def scene_names() -> list[str]:
    """Names of the shipped scenes (``calib_oed/scene/shipped/<name>.yaml``)."""
    return shipped_names(SHIPPED)


def load_scene(name_or_path: str | os.PathLike, *, check: bool = True) -> Scene:
    """Load a shipped scene by name, or a scene file by path.

    With ``check`` (default), the scene checks itself (:func:`calib_oed.scene.checks.check_scene`):
    the robot at the working configurations and the tracker against the cell.

    Raises:
        UnknownSceneError: a bare name that is neither a shipped scene nor a file.
        SceneError: missing or unreadable file, YAML syntax error, invalid content,
            an impossible scene (the pair and its depth named).
    """
    text = os.fspath(name_or_path)
    path = shipped_file(SHIPPED, text)
    if path is None:
        path = Path(text)
        looks_like_path = os.sep in text or path.suffix in (".yaml", ".yml") or path.exists()
        if not looks_like_path:
            raise UnknownSceneError(text, scene_names())
        if not path.is_file():
            raise SceneError(f"scene file not found: {path}", source=str(path))
    try:
        data = load_yaml_file(path, "scene file")
    except InputFileError as exc:
        raise SceneError(exc.problem, source=str(path)) from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise SceneError(f"YAML syntax error{at}: {problem}", source=str(path)) from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"cannot read scene file ({exc})", source=str(path)) from exc
    return scene_from_dict(resolve_includes(data, path), source=str(path), check=check)


def scene_from_dict(data: Mapping[str, Any], source: str | None = None, *,
                    check: bool = True) -> Scene:
    """Build a :class:`Scene` from the parsed YAML (same validation as :func:`load_scene`).

    Args:
        data: The scene as a mapping (schema version 1, see ``docs/scenes.md``).
        source: File the data came from: named in errors, and the folder
            relative ``robot.urdf`` paths resolve against (default: the working directory).
        check: Run :func:`calib_oed.scene.checks.check_scene` on the result.
    """
    scene = SceneReader(source).scene(data)
    if check:
        check_scene(scene)
    return scene


class SceneReader(FieldReader):
    """Reads a whole scene: the top level, robot, compliance, tracker, reflectors, KPI."""

    def scene(self, data) -> Scene:
        top = self.mapping(data, None, ("version", "name", "units", "robot", "tracker",
                                        "reflectors", "kpi"),
                           ("description", "measurement", "generic_design", "cell",
                            "feasibility", "program", "controller", "realistic"))
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
        compliance = (read_compliance(self, top["robot"]["compliance"], robot.model.nq)
                      if "compliance" in top["robot"] else None)
        controller = (controller_from_mapping(top["controller"], robot.model.nq)
                      if "controller" in top else None)
        joint_gains = (read_joint_gains(self, top["robot"]["joint_gains"], robot.model.nq, controller)
                       if "joint_gains" in top["robot"] else None)
        gd = self.mapping(top.get("generic_design", {}), "generic_design", (), ("n", "seed"))
        error = top["robot"].get("model_error")
        joint_error = isinstance(error, dict) and "kind" in error  # the joint-space prior
        return Scene(
            name=self.string(top["name"], "name"),
            description=description,
            source=Path(self.source) if self.source else None,
            robot=robot,
            tracker=self.tracker(top["tracker"], top.get("measurement", "position")),
            reflectors=tuple(
                ReflectorSpec(r["name"], self.vector(r["offset"], f"reflectors[{i}].offset", 3,
                                                     self.length),
                              reflector_normal(self, r.get("normal", [0.0, 0.0, 1.0]), i),
                              self.string(r.get("aim", "fixed"), f"reflectors[{i}].aim", AIMS))
                for i, r in enumerate(self.named_list(top["reflectors"], "reflectors",
                                                      ("name", "offset"), "reflector", ("normal", "aim")))
            ),
            measurement=self.string(top.get("measurement", "position"), "measurement",
                                    MEASUREMENTS),
            kpi=self.kpi(top["kpi"], robot, [r["name"] for r in top["reflectors"]]),
            generic_design=GenericDesignSpec(
                n=self.integer(gd.get("n", 200), "generic_design.n", 1),
                seed=self.integer(gd.get("seed", 0), "generic_design.seed", 0),
            ),
            units=dict(self.units),
            cell=read_cell(self, top["cell"], robot) if "cell" in top else Cell(),
            feasibility=(read_feasibility(self, top["feasibility"], robot)
                         if "feasibility" in top else FeasibilitySettings()),
            compliance=compliance,
            program=self.free_mapping(top.get("program", {}), "program"),
            realistic=self.free_mapping(top.get("realistic", {}), "realistic"),
            controller=controller,
            joint_gains=joint_gains,
            repeatability=self.repeatability(top),
            model_error=(read_model_error(self, error, robot)
                         if error is not None and not joint_error else None),
            joint_error=read_joint_error(self, error, robot.nq) if joint_error else None,
        )

    def repeatability(self, top) -> float:
        """``robot.repeatability``: sigma at the reflector [length unit] -> [m], or ``robot.rp``:
        the data sheet's ISO 9283 pose repeatability RP, sigma = RP / 3.616; 0 if absent."""
        given = [k for k in ("repeatability", "rp") if k in top["robot"]]
        if not given:
            return 0.0
        if len(given) > 1:
            raise self.fail("robot.rp", "give robot.rp (the ISO 9283 RP of the data sheet) or "
                            "robot.repeatability (a sigma), not both")
        value = self.number(top["robot"][given[0]], f"robot.{given[0]}", self.length, nonnegative=True)
        if given[0] == "rp":
            value = sigma_from_repeatability(value)
        if value > 0 and top.get("measurement", "position") != "position":
            raise self.fail("robot.repeatability", "applies to measurement: position only "
                            f"(this scene measures {top.get('measurement')!r})")
        if value > 0 and not {"noise", "mpe"} & set(top["tracker"]) and len(set(
                np.atleast_1d(np.asarray(top["tracker"]["sigma"], dtype=float)).tolist())) > 1:
            raise self.fail("robot.repeatability", "needs a scalar tracker.sigma or a "
                            "tracker.noise block (a per-axis sigma has no range/direction model)")
        return value

    def tracker_noise(self, value, measurement, block: str = "noise") -> TrackerNoise:
        """``tracker.noise: {radial: [r0, r1], lateral: [t0, t1]}``, sigma(d) = c0 + c1 d, d in m;
        or ``tracker.mpe: {radial: [a, b], lateral: [a, b], k: 2}``, the data sheet's maximum
        permissible error +-(a + b d) as an expanded uncertainty of coverage factor k (default 2),
        sigma = (a + b d) / k (:func:`~calib_oed.measurement.noise.sigma_from_mpe`)."""
        key0 = f"tracker.{block}"
        spec = self.mapping(value, key0, ("radial", "lateral"), ("k",) if block == "mpe" else ())
        if measurement != "position":
            raise self.fail(key0, "applies to measurement: position only "
                            f"(this scene measures {measurement!r})")
        k = self.number(spec.get("k", 2.0), f"{key0}.k", positive=True)
        pairs = {}
        for key in ("radial", "lateral"):
            where = f"{key0}.{key}"
            pair = self.vector(spec[key], where, 2, self.length,
                               what="[sigma at zero range, sigma per metre of range]" if block == "noise"
                               else "[MPE a at zero range, MPE b per metre of range]")
            if block == "mpe" and np.all(pair >= 0):
                pair = np.array(sigma_from_mpe(*pair, k=k))
            if np.any(pair < 0):
                raise self.fail(where, f"both coefficients must be >= 0, got {spec[key]!r}")
            if pair[0] == 0:
                raise self.fail(where, f"the first coefficient (sigma at zero range) must be "
                                f"> 0, got {spec[key]!r}")
            pairs[key] = pair
        return TrackerNoise(pairs["radial"], pairs["lateral"])

    def robot(self, value) -> Robot:
        spec = self.mapping(value, "robot", (), ("name", "urdf", "xacro", "args", "tool_frame",
                                                 "joint_limits", "lock_joints", "package_dirs",
                                                 "compliance", "repeatability", "rp", "joint_gains",
                                                 "model_error"))
        given = [k for k in ("name", "urdf", "xacro") if k in spec]
        if len(given) != 1:
            raise self.fail("robot", "expected exactly one of 'name' (a robot name), 'urdf' "
                            "(a URDF file path) or 'xacro' (a xacro file path, with 'args'), "
                            f"got {given or 'neither'}")
        if "args" in spec and "xacro" not in spec:
            raise self.fail("robot.args", "arguments are for a xacro file (robot.xacro); "
                            f"this robot is given by {given[0]!r}")
        xacro_args = self.xacro_args(spec.get("args", {}))
        if "name" in spec:
            source = self.string(spec["name"], "robot.name")
        else:
            key = given[0]
            path = Path(self.string(spec[key], f"robot.{key}")).expanduser()
            if not path.is_absolute():
                path = (Path(self.source).parent if self.source else Path.cwd()) / path
            if not path.is_file():
                raise self.fail(f"robot.{key}", f"{key.upper() if key == 'urdf' else key} file "
                                f"not found: {path}")
            if (key == "xacro") != path.name.endswith(".xacro"):
                raise self.fail(f"robot.{key}", f"{path.name}: a xacro file (*.xacro) goes under "
                                "robot.xacro, a URDF under robot.urdf")
            source = str(path.resolve())
        tool = self.string(spec["tool_frame"], "robot.tool_frame") if "tool_frame" in spec else None
        packages = self.package_dirs(spec.get("package_dirs", []))
        limits = self.free_mapping(spec.get("joint_limits", {}), "robot.joint_limits")
        locks = self.free_mapping(spec.get("lock_joints", {}), "robot.lock_joints")
        try:
            robot = load_robot(source, tool_frame=tool, lock_joints={j: 0.0 for j in locks},
                               package_dirs=packages, xacro_args=xacro_args)
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
                package_dirs=packages, xacro_args=xacro_args,
            )
        except SceneError:
            raise
        except CalibOedError as exc:
            raise self.fail("robot", str(exc)) from exc

    def xacro_args(self, value) -> dict[str, str]:
        """``robot.args``: ``{name: value}`` for the xacro file, as ``name:=value`` on the command line."""
        if not isinstance(value, Mapping):
            raise self.fail("robot.args", f"expected a mapping {{argument: value}}, got {value!r}")
        args = dict(value)
        for name, v in args.items():
            if not isinstance(v, (str, int, float, bool)):
                raise self.fail(f"robot.args.{name}", f"expected a string, number or true/false, "
                                f"got {v!r}")
        return {str(k): ("true" if v is True else "false" if v is False else str(v))
                for k, v in args.items()}

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

    def tracker(self, value, measurement: str = "position") -> TrackerSpec:
        spec = self.mapping(value, "tracker", ("position", "rpy", "sigma"), ("sigma_angle", "noise", "mpe"))
        if "noise" in spec and "mpe" in spec:
            raise self.fail("tracker.mpe", "give tracker.mpe (the data sheet's MPE) or tracker.noise "
                            "(sigmas), not both")
        sigma_angle = (self.vector3_or_scalar(spec["sigma_angle"], "tracker.sigma_angle",
                                              self.angle)
                       if "sigma_angle" in spec else np.full(3, DEFAULT_SIGMA_ANGLE))
        return TrackerSpec(
            position=self.vector(spec["position"], "tracker.position", 3, self.length),
            rpy=self.vector(spec["rpy"], "tracker.rpy", 3, self.angle),
            sigma=self.vector3_or_scalar(spec["sigma"], "tracker.sigma", self.length),
            sigma_angle=sigma_angle,
            noise=next((self.tracker_noise(spec[b], measurement, b) for b in ("noise", "mpe") if b in spec),
                       None),
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
        prismatic = robot.prismatic
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


