r"""Export a calibration: the calibrated URDF and the identified sensor set-up.

**URDF.** A parameter vector :math:`p` perturbs every joint placement on the
right, :math:`M_i \leftarrow M_i \exp_6(\delta_i)` (``docs/conventions.md``).
Pinocchio builds :math:`M_i` of a URDF joint as (the origins of the fixed or
locked joints merged since the previous movable joint) times (this joint's own
``<origin>``), so the perturbation folds into this joint's origin alone:

.. math::

    O_i' = O_i \exp_6(\delta_i), \qquad O_i \in SE(3)
    \text{ the joint's URDF } \texttt{<origin xyz rpy>}.

The joint axis is expressed in the joint frame and stays as written. Joints
with :math:`\delta_i = 0`, locked joints (gripper fingers), fixed joints and
everything else in the file are left exactly as they were.

How the file is edited: the URDF is read with yourdfpy (joint map and origin
matrices), and only the ``<origin>`` attributes of the perturbed joints are
rewritten in the original XML document (lxml, which yourdfpy is built on).
yourdfpy's own writer (``URDF.write_xml_string``, 0.0.60) is not used for the
output: it drops ``<mimic>`` (panda's second finger), ``<safety_controller>``,
``<transmission>`` and ``<gazebo>`` elements and all comments, and rewrites
every origin of the file. It does not round (``str`` of a float is the
shortest text that round-trips), but it converts rotations back to rpy with
``trimesh.transformations.euler_from_matrix``, which near pitch
:math:`\pm\pi/2` amplifies absolute rounding noise in the matrix by
:math:`1/\cos(\text{pitch})` (2e-6 rad for a noisy matrix 1e-9 rad from the
singularity). Here the new origin is written with ``pinocchio.rpy.matrixToRpy``
(about 1e-15 rad everywhere, the singularity included) and ``repr`` of each
float, so the exported model reproduces :meth:`ParameterSpace.perturbed_model`
to rounding error.

**Sensor.** A URDF describes the robot only; the identified tracker pose
:math:`T_{W,T}` and reflector offsets :math:`c_j` go to a small YAML file
(:func:`write_sensor_yaml`, read back by :func:`read_sensor_yaml`).

Files are written atomically (:func:`calib_oed.io.atomic.atomic_write_text`):
a failed export leaves no file behind.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml
import yourdfpy
from lxml import etree

import calib_oed
from calib_oed.exceptions import CalibOedError, ExportError
from calib_oed.io import atomic as io_utils
from calib_oed.model.compliance import Compliance
from calib_oed.model.parameters import ParameterSpace

#: Version tag of the sensor YAML layout.
SENSOR_FORMAT = "calib_oed.sensor/1"

_MOVABLE_TYPES = ("revolute", "prismatic", "continuous")

# Redundant copies in the sensor file (mm, degrees, quaternion) must agree with
# the SI values read back to this tolerance [m, rad].
_CONSISTENCY_TOL = 1e-9


# ---------------------------------------------------------------- URDF
def calibrated_urdf_text(space: ParameterSpace, p: np.ndarray | None, *,
                         robot_name: str | None = None) -> str:
    r"""The robot's URDF with every joint origin :math:`O_i` replaced by :math:`O_i\exp_6(\delta_i)`.

    Args:
        space: The parameter space; its robot's ``urdf_text`` is edited.
        p: Parameter vector, shape ``(space.size,)`` (SI); ``None`` means nominal.
        robot_name: New ``<robot name>``; ``None`` keeps the URDF's.

    Returns:
        The URDF text, starting with an XML declaration and a provenance comment.

    Raises:
        ShapeError, NonFiniteError: ``p`` is not a finite vector of the right length.
        ExportError: the URDF cannot be read or does not hold a model joint.
    """
    p = space.check(p)
    robot = space.robot
    where = robot.urdf_path.name if robot.urdf_path is not None else f"{robot.name} (generated)"
    data = robot.urdf_text.encode("utf-8")
    try:
        urdf = yourdfpy.URDF.load(
            io.BytesIO(data), build_scene_graph=False, build_collision_scene_graph=False,
            load_meshes=False, load_collision_meshes=False,
            filename_handler=yourdfpy.filename_handler_null,
        )
        parser = etree.XMLParser(remove_comments=False, remove_blank_text=False,
                                 resolve_entities=False, no_network=True)
        root = etree.fromstring(data, parser)
    except Exception as exc:  # yourdfpy and lxml raise many types on bad input
        raise ExportError(f"{where}: cannot read the URDF for export ({exc})") from exc
    elements = {j.get("name"): j for j in root.findall("joint")}

    changed = []
    for i, name in enumerate(robot.joint_names, start=1):
        delta = p[space.joint_slice(i)]
        if not np.any(delta):
            continue  # leave the original text untouched
        joint = urdf.joint_map.get(name)
        element = elements.get(name)
        if joint is None or element is None:
            raise ExportError(
                f"{where}: model joint {name!r} is not a <joint> of the URDF; "
                f"its joints are: {sorted(elements)}"
            )
        if joint.type not in _MOVABLE_TYPES:
            raise ExportError(
                f"{where}: joint {name!r} is {joint.type!r} in the URDF but movable in the model"
            )
        origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
        new = pin.SE3(origin[:3, :3], origin[:3, 3]) * pin.exp6(delta)
        _set_origin(element, new)
        changed.append((i, name, delta))

    if robot_name is not None:
        if not str(robot_name).strip():
            raise ExportError("robot_name must not be empty")
        root.set("name", str(robot_name))
    header = _provenance(space, p, where, changed, root.get("name"))
    return f'<?xml version="1.0" encoding="utf-8"?>\n<!--\n{header}\n-->\n{_document(root)}\n'


def _document(root: etree._Element) -> str:
    """The document without its XML declaration, one top-level node per line."""
    before, node = [], root.getprevious()
    while node is not None:
        before.insert(0, node)
        node = node.getprevious()
    after = list(root.itersiblings())
    doctype = root.getroottree().docinfo.doctype
    parts = [doctype] if doctype else []
    parts += [etree.tostring(n, encoding="unicode", with_tail=False)
              for n in (*before, root, *after)]
    return "\n".join(parts)


def _set_origin(joint: etree._Element, placement: pin.SE3) -> None:
    """Write ``placement`` into the joint's ``<origin>`` (created after ``<child>`` if missing)."""
    origin = joint.find("origin")
    if origin is None:
        origin = etree.Element("origin")
        child = joint.find("child")
        if child is not None:
            child.addnext(origin)
            origin.tail = child.tail
        else:
            joint.append(origin)
    origin.set("xyz", _floats(placement.translation))
    origin.set("rpy", _floats(pin.rpy.matrixToRpy(placement.rotation)))


def _floats(values) -> str:
    """Shortest round-trip text of each float (``repr``), ``-0.0`` written as ``0.0``."""
    return " ".join(repr(float(v) + 0.0) for v in values)


def _provenance(space: ParameterSpace, p: np.ndarray, where: str, changed, name: str) -> str:
    """The XML comment at the top of the calibrated URDF (date-free, so exports are reproducible)."""
    n_joint = 6 * space.n_joints
    nonzero = int(np.count_nonzero(p[space.joints_slice]))
    lines = [
        f"  Calibrated by calib_oed {calib_oed.__version__}: robot {name!r}, "
        f"calib_oed robot {space.robot.name!r}, from {where}.",
        f"  Parameter vector: {space.size} parameters (tracker pose 6, reflector offsets "
        f"{3 * space.n_reflectors}, joints {n_joint}"
        + (f", joint compliances {space.n_joints} (in the sensor YAML)" if space.compliance is not None else "")
        + f"); applied here: the {n_joint} joint "
        f"parameters ({nonzero} non-zero), changing the <origin> of {len(changed)} of "
        f"{space.n_joints} joints.",
        "  Each changed origin is O * exp6(delta), delta = (tx, ty, tz, rx, ry, rz) in the "
        "joint's frame; joint axes and all other elements are as in the source.",
        "  The tracker pose and the reflector offsets have no place in a URDF: see the "
        "sensor YAML written with this file.",
    ]
    for i, jname, delta in changed:
        mm = ", ".join(f"{1e3 * v:+.6f}" for v in delta[:3])
        mrad = ", ".join(f"{1e3 * v:+.6f}" for v in delta[3:])
        lines.append(f"    joint{i} ({jname}): t = ({mm}) mm, r = ({mrad}) mrad")
    text = "\n".join(lines)
    while "--" in text:  # not allowed inside an XML comment
        text = text.replace("--", "- -")
    return text


def export_calibrated_urdf(space: ParameterSpace, p: np.ndarray | None, path: str | os.PathLike,
                           *, robot_name: str | None = None) -> Path:
    r"""Write the calibrated URDF (:func:`calibrated_urdf_text`) to ``path``, atomically.

    Loading the file with :func:`calib_oed.load_robot` (same tool frame, locked
    joints and ``package_dirs``) gives the model ``space.perturbed_model(p)``.

    Raises:
        ShapeError, NonFiniteError: bad ``p``.
        ExportError: the folder does not exist, ``path`` is a folder, the write
            failed, or the URDF cannot be edited. No file is left behind.
    """
    text = calibrated_urdf_text(space, p, robot_name=robot_name)
    return _write(path, text)


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
    header = (
        f"# Sensor set-up identified by calib_oed {calib_oed.__version__} for robot "
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
    )
    body = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=1000)
    return header + body


def _floatlist(values) -> list[float]:
    return [float(v) + 0.0 for v in np.asarray(values, dtype=float).ravel()]


def write_sensor_yaml(space: ParameterSpace, p: np.ndarray | None,
                      path: str | os.PathLike) -> Path:
    """Write :func:`sensor_yaml_text` to ``path``, atomically.

    Raises:
        ShapeError, NonFiniteError: bad ``p``.
        ExportError: the folder does not exist, ``path`` is a folder or the write failed.
    """
    return _write(path, sensor_yaml_text(space, p))


def read_sensor_yaml(path: str | os.PathLike) -> tuple[pin.SE3, np.ndarray]:
    r"""Read a sensor file written by :func:`write_sensor_yaml`.

    Returns:
        The tracker pose :math:`T_{W,T}` and the reflector offsets, shape (k, 3)
        [m] in the tool frame, from the SI values.

    Raises:
        ExportError: missing or malformed file, a rotation that is not a
            rotation, or mm / degree / quaternion copies that disagree with
            the SI values (a hand edit of one copy only).
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ExportError(f"cannot read sensor file {path}: {exc}") from exc
    if not isinstance(data, dict) or data.get("format") != SENSOR_FORMAT:
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
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ExportError(f"cannot read sensor file {path}: {exc}") from exc
    section = data.get("compliance") if isinstance(data, dict) else None
    if section is None:
        return None
    joints = section.get("joints") if isinstance(section, dict) else None
    if not isinstance(joints, list) or not all(isinstance(j, dict) for j in joints):
        raise ExportError(f"{path}: compliance.joints must be a list of mappings")
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
    try:
        return Compliance(mass, com), c
    except CalibOedError as exc:
        raise ExportError(f"{path}: compliance: {exc}") from exc


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


# ---------------------------------------------------------------- both
def export_calibration(space: ParameterSpace, p: np.ndarray | None,
                       folder: str | os.PathLike, *, stem: str | None = None,
                       robot_name: str | None = None) -> dict[str, Path]:
    """Write ``<stem>_calibrated.urdf`` and ``<stem>_sensor.yaml`` into ``folder``.

    Args:
        space, p: As for :func:`export_calibrated_urdf`.
        folder: An existing folder.
        stem: File name stem; defaults to the robot's name.
        robot_name: New ``<robot name>`` in the URDF; ``None`` keeps the URDF's.

    Returns:
        ``{"urdf": path, "sensor": path}``.

    Raises:
        ExportError: ``folder`` does not exist, a bad stem, or a write failed.
            Both files are prepared before either is written, and the URDF is
            removed again if the sensor file cannot be written.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ExportError(f"cannot export the calibration: folder {folder} does not exist")
    stem = space.robot.name if stem is None else str(stem)
    if not stem or Path(stem).name != stem or stem in (".", ".."):
        raise ExportError(f"stem {stem!r} must be a plain file name (no folder part)")
    urdf_text = calibrated_urdf_text(space, p, robot_name=robot_name)
    sensor_text = sensor_yaml_text(space, p)
    urdf_path = folder / f"{stem}_calibrated.urdf"
    sensor_path = folder / f"{stem}_sensor.yaml"
    for target in (urdf_path, sensor_path):
        _check_target(target)
    _write(urdf_path, urdf_text)
    try:
        _write(sensor_path, sensor_text)
    except BaseException:
        urdf_path.unlink(missing_ok=True)
        raise
    return {"urdf": urdf_path, "sensor": sensor_path}


def _check_target(path: Path) -> None:
    if path.is_dir():
        raise ExportError(f"cannot write {path}: it is a folder")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ExportError(f"cannot write {path}: folder {folder} does not exist")


def _write(path: str | os.PathLike, text: str) -> Path:
    path = Path(path)
    _check_target(path)
    try:
        return io_utils.atomic_write_text(path, text)
    except OSError as exc:
        raise ExportError(f"cannot write {path}: {exc}") from exc


__all__ = [
    "SENSOR_FORMAT",
    "calibrated_urdf_text",
    "export_calibrated_urdf",
    "export_calibration",
    "read_sensor_compliance",
    "read_sensor_yaml",
    "sensor_yaml_text",
    "write_sensor_yaml",
]
