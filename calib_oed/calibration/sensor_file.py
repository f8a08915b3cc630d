r"""The identified sensor set-up as a YAML file: write it, read it back.

A URDF describes the robot only; the identified tracker pose
:math:`T_{W,T}` and reflector offsets :math:`c_j` (and, when modelled, the
joint compliances and the joint gains) go to a small YAML file (:func:`sensor_yaml_text`, written by
:func:`calib_oed.calibration.export.export_calibration`, read back by :func:`read_sensor_yaml`, :func:`read_sensor_compliance` and
:func:`read_sensor_gains`), next to
the calibrated URDF (:mod:`calib_oed.calibration.export`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

from calib_oed._version import __version__
from calib_oed.exceptions import CalibOedError, ExportError, InputFileError
from calib_oed.model.compliance import Compliance
from calib_oed.model.joint_map import JointGains
from calib_oed.model.parameters import ParameterSpace
from calib_oed.scene.yaml_file import load_yaml_file

#: Version tag of the sensor YAML layout.
SENSOR_FORMAT = "calib_oed.sensor/1"

# Redundant copies in the sensor file (mm, degrees, quaternion) must agree with
# the SI values read back to this tolerance [m, rad].
_CONSISTENCY_TOL = 1e-9


# ---------------------------------------------------------------- sensor
def sensor_yaml_text(space: ParameterSpace, p: np.ndarray | None) -> str:
    r"""The identified tracker pose :math:`T_{W,T}` and reflector offsets :math:`c_j` as YAML.

    Lengths in mm and m, angles in degrees (roll, pitch, yaw with
    :math:`R = R_z(y)R_y(p)R_x(r)`), the rotation also as a matrix and a
    quaternion (x, y, z, w). The SI values are written with full precision
    and are the ones :func:`read_sensor_yaml` returns.
    """
    p = space.check(p)
    robot = space.robot
    tracker = space.tracker_placement(p)
    offsets = space.reflector_offsets(p)
    quat = pin.Quaternion(tracker.rotation).coeffs()  # x, y, z, w
    data = {
        "format": SENSOR_FORMAT,
        "robot": robot.name,
        "tool_frame": robot.tool_frame,
        "parameters": space.size,
        "tracker": {
            "position_mm": _floatlist(1e3 * tracker.translation),
            "rpy_deg": _floatlist(np.degrees(pin.rpy.matrixToRpy(tracker.rotation))),
            "position_m": _floatlist(tracker.translation),
            "rotation_matrix": [_floatlist(row) for row in tracker.rotation],
            "quaternion_xyzw": _floatlist(quat),
        },
        "reflectors": [
            {"index": j, "offset_mm": _floatlist(1e3 * c), "offset_m": _floatlist(c)}
            for j, c in enumerate(offsets)
        ],
    }
    if space.compliance is not None:  # a URDF has no place for joint stiffness either
        comp = space.compliance
        data["compliance"] = {
            "payload_kg": comp.payload_mass,
            "payload_com_m": _floatlist(comp.payload_com),
            "joints": [
                {"joint": name, "compliance_si": float(c) + 0.0,
                 "unit": space.parameters[space.compliance_slice.start + i].unit,
                 "stiffness_si": (1.0 / float(c)) if c > 0 else None}
                for i, (name, c) in enumerate(zip(robot.joint_names, p[space.compliance_slice],
                                                  strict=True))
            ],
        }
        if comp.link_masses is not None:  # the arm's weight the compliances were identified under
            data["compliance"]["link_masses_kg"] = _floatlist(comp.link_masses)
            data["compliance"]["link_coms_m"] = [_floatlist(c) for c in comp.link_coms]
    if space.joint_gains is not None:  # nor for encoder scales and coupling ratios
        gains = space.joint_gains
        values = p[space.gain_slice]
        data["joint_gains"] = {
            "joints": [{"joint": robot.joint_names[i - 1], "number": i, "gain": float(v) + 0.0}
                       for i, v in zip(gains.joints, values, strict=False)],
            "couplings": [{"joint": j, "from": f, "ratio": float(v) + 0.0}
                          for (j, f), v in zip(gains.couplings, values[len(gains.joints):], strict=True)],
        }
    header = (
        f"# Sensor set-up identified by calib_oed {__version__} for robot "
        f"{robot.name!r} ({space.size} parameters).\n"
        "# A URDF describes the robot only: it has no place for the laser tracker's pose or for\n"
        "# the reflector (SMR) centres, so they are kept here, next to the calibrated URDF.\n"
        "# tracker: pose T_W,T of the tracker's measurement frame in the world (robot base)\n"
        "#   frame, x_W = R x_T + t; rpy_deg is roll, pitch, yaw with R = Rz(yaw) Ry(pitch) Rx(roll).\n"
        f"# reflectors: centre of each reflector in the tool frame {robot.tool_frame!r}.\n"
        "# The SI values (position_m, rotation_matrix, offset_m) are exact and authoritative;\n"
        "# mm, degrees and the quaternion are copies for people and must agree with them.\n"
        + ("# compliance: the identified joint compliances c = 1/k (rad/(N*m)) and stiffnesses\n"
           "#   (N*m/rad; null where c <= 0), with the payload they were identified under.\n"
           if space.compliance is not None else "")
        + ("# joint_gains: the identified gains g (the joint moves (1 + g) q for a command q) and\n"
           "#   coupling ratios k (joint 'joint' moves k q_from more), on the URDF's joint values.\n"
           if space.joint_gains is not None else "")
    )
    body = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=1000)
    return header + body


def _floatlist(values) -> list[float]:
    return [float(v) + 0.0 for v in np.asarray(values, dtype=float).ravel()]


def _load(path: Path) -> dict:
    """The sensor file's YAML mapping ({} if it is not a mapping); ExportError if unreadable."""
    try:
        data = load_yaml_file(path, "sensor file")
    except (OSError, UnicodeDecodeError, yaml.YAMLError, InputFileError) as exc:
        raise ExportError(f"cannot read sensor file {path}: {exc}") from exc
    return data if isinstance(data, dict) else {}


def sensor_robot(path: str | os.PathLike) -> str | None:
    """The name of the robot a sensor file was identified for (its ``robot`` key), or None."""
    name = _load(Path(path)).get("robot")
    return None if name is None else str(name)


def read_sensor_yaml(path: str | os.PathLike) -> tuple[pin.SE3, np.ndarray]:
    r"""Read a sensor file (:func:`sensor_yaml_text`).

    Returns:
        The tracker pose :math:`T_{W,T}` and the reflector offsets, shape (k, 3)
        [m] in the tool frame, from the SI values.

    Raises:
        ExportError: missing or malformed file, a rotation that is not a
            rotation, or mm / degree / quaternion copies that disagree with
            the SI values (a hand edit of one copy only).
    """
    path = Path(path)
    data = _load(path)
    if data.get("format") != SENSOR_FORMAT:
        raise ExportError(f"{path}: not a calib_oed sensor file (expected format: {SENSOR_FORMAT})")
    tracker = data.get("tracker")
    reflectors = data.get("reflectors")
    if not isinstance(tracker, dict) or not isinstance(reflectors, list) or not reflectors:
        raise ExportError(f"{path}: needs a 'tracker' mapping and a non-empty 'reflectors' list")
    t = _array(path, tracker, "position_m", (3,), "tracker.")
    rot = _array(path, tracker, "rotation_matrix", (3, 3), "tracker.")
    if not (np.allclose(rot.T @ rot, np.eye(3), atol=_CONSISTENCY_TOL, rtol=0.0)
            and np.linalg.det(rot) > 0):
        raise ExportError(f"{path}: tracker.rotation_matrix is not a rotation matrix")
    _agree(path, "tracker.position_mm", 1e-3 * _array(path, tracker, "position_mm", (3,),
                                                      "tracker."), t)
    rpy = np.radians(_array(path, tracker, "rpy_deg", (3,), "tracker."))
    _agree(path, "tracker.rpy_deg", pin.log3(rot.T @ pin.rpy.rpyToMatrix(rpy)), np.zeros(3))
    q = _array(path, tracker, "quaternion_xyzw", (4,), "tracker.")
    if not np.isclose(np.linalg.norm(q), 1.0, atol=_CONSISTENCY_TOL, rtol=0.0):
        raise ExportError(f"{path}: tracker.quaternion_xyzw is not a unit quaternion")
    rq = pin.Quaternion(q[3], q[0], q[1], q[2]).toRotationMatrix()
    _agree(path, "tracker.quaternion_xyzw", pin.log3(rot.T @ rq), np.zeros(3))
    offsets = []
    for j, entry in enumerate(reflectors):
        if not isinstance(entry, dict) or entry.get("index") != j:
            raise ExportError(f"{path}: reflectors[{j}] must be a mapping with index: {j}")
        c = _array(path, entry, "offset_m", (3,), f"reflectors[{j}].")
        _agree(path, f"reflectors[{j}].offset_mm",
               1e-3 * _array(path, entry, "offset_mm", (3,), f"reflectors[{j}]."), c)
        offsets.append(c)
    return pin.SE3(rot, t), np.array(offsets)


def read_sensor_compliance(path: str | os.PathLike, joint_names) -> tuple[Compliance, np.ndarray] | None:
    """The joint compliances of a sensor file written with compliance modelled, or None.

    Args:
        path: The sensor file.
        joint_names: The robot's joints; the file's must be these, in this order.

    Returns:
        The payload they were identified under and the compliances (n_joints,)
        [rad/(N m); m/N for a prismatic joint], or None if the file has no
        ``compliance`` section.

    Raises:
        ExportError: a malformed section or joints that are not the robot's.
    """
    path = Path(path)
    found = _section_lists(path, "compliance", ("joints",))
    if found is None:
        return None
    section, (joints,) = found
    names = [j.get("joint") for j in joints]
    if names != list(joint_names):
        raise ExportError(f"{path}: compliance.joints are {names}, the robot's joints are {list(joint_names)}")
    try:
        mass = float(section["payload_kg"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ExportError(f"{path}: compliance.payload_kg is missing or not numeric") from exc
    com = _array(path, section, "payload_com_m", (3,), "compliance.")
    c = np.array([_array(path, j, "compliance_si", (), f"compliance.joints[{i}].")
                  for i, j in enumerate(joints)], dtype=float)
    masses = coms = None
    if "link_masses_kg" in section:
        masses = _array(path, section, "link_masses_kg", (len(joints),), "compliance.")
        coms = _array(path, section, "link_coms_m", (len(joints), 3), "compliance.")
    try:
        return Compliance(mass, com, link_masses=masses, link_coms=coms), c
    except CalibOedError as exc:
        raise ExportError(f"{path}: compliance: {exc}") from exc


def read_sensor_gains(path: str | os.PathLike, joint_names) -> tuple[JointGains, np.ndarray] | None:
    """The joint gains and coupling ratios of a sensor file, or None if it has none.

    Returns the :class:`~calib_oed.model.joint_map.JointGains` layout and its
    values (gains, then couplings) [1], in the order of ``ParameterSpace.gain_slice``.

    Raises:
        ExportError: a malformed section or joints that are not the robot's.
    """
    path = Path(path)
    found = _section_lists(path, "joint_gains", ("joints", "couplings"))
    if found is None:
        return None
    rows = found[1]
    names = list(joint_names)
    for i, e in enumerate(rows[0]):
        if e.get("number") not in range(1, len(names) + 1) or e.get("joint") != names[e["number"] - 1]:
            raise ExportError(f"{path}: joint_gains.joints[{i}] is {e.get('joint')!r} (number "
                              f"{e.get('number')!r}); the robot's joints are {names}")
    values = [_array(path, e, "gain", (), f"joint_gains.joints[{i}].") for i, e in enumerate(rows[0])]
    values += [_array(path, e, "ratio", (), f"joint_gains.couplings[{i}].") for i, e in enumerate(rows[1])]
    try:
        layout = JointGains(tuple(e["number"] for e in rows[0]),
                            tuple((e.get("joint"), e.get("from")) for e in rows[1]))
        layout.check(len(names))
    except (CalibOedError, TypeError, ValueError) as exc:
        raise ExportError(f"{path}: joint_gains: {exc}") from exc
    return layout, np.array(values, dtype=float)


def _section_lists(path: Path, name: str, keys: tuple[str, ...]) -> tuple[dict, list[list[dict]]] | None:
    """A sensor file's section ``name`` and its lists of mappings ``name.<key>``, or None if the
    file has no such section; ExportError if they are not lists of mappings."""
    section = _load(path).get(name)
    if section is None:
        return None
    rows = [section.get(k) if isinstance(section, dict) else None for k in keys]
    if not all(isinstance(r, list) and all(isinstance(e, dict) for e in r) for r in rows):
        lists = " and ".join(f"{name}.{k}" for k in keys)
        raise ExportError(f"{path}: {lists} must be {'a list' if len(keys) == 1 else 'lists'} of mappings")
    return section, rows


def _array(path: Path, data: dict, key: str, shape: tuple[int, ...], prefix: str) -> np.ndarray:
    try:
        arr = np.asarray(data[key], dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise ExportError(f"{path}: {prefix}{key} is missing or not numeric") from exc
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ExportError(f"{path}: {prefix}{key} must be finite numbers of shape {shape}, "
                          f"got shape {arr.shape}")
    return arr


def _agree(path: Path, key: str, copy: np.ndarray, value: np.ndarray) -> None:
    if np.max(np.abs(copy - value)) > _CONSISTENCY_TOL:
        raise ExportError(f"{path}: {key} disagrees with the SI values (edited by hand?); "
                          "edit the SI values, they are the ones read")


__all__ = [
    "SENSOR_FORMAT",
    "read_sensor_compliance",
    "read_sensor_yaml",
    "sensor_yaml_text",
]
