r"""Export a calibration: the calibrated URDF, and it together with the sensor file.

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

The identified tracker pose and reflector offsets have no place in a URDF:
they go to the sensor file (:mod:`calib_oed.calibration.sensor_file`);
:func:`export_calibration` writes both. Files are written atomically
(:mod:`calib_oed.calibration.export_files`): a failed export leaves no file
behind.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pinocchio as pin
import yourdfpy
from lxml import etree

from calib_oed._version import __version__
from calib_oed.calibration.export_files import _check_target, _write
from calib_oed.calibration.sensor_file import sensor_yaml_text
from calib_oed.exceptions import ExportError
from calib_oed.model.parameters import ParameterSpace

_MOVABLE_TYPES = ("revolute", "prismatic", "continuous")


# ---------------------------------------------------------------- URDF
def calibrated_urdf_text(space: ParameterSpace, p: np.ndarray | None) -> str:
    r"""The robot's URDF with every joint origin :math:`O_i` replaced by :math:`O_i\exp_6(\delta_i)`.

    Args:
        space: The parameter space; its robot's ``urdf_text`` is edited.
        p: Parameter vector, shape ``(space.size,)`` (SI); ``None`` means nominal.

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

    header = _provenance(space, p, where, changed, root.get("name"))
    return f'<?xml version="1.0" encoding="utf-8"?>\n<!--\n{header}\n-->\n{_document(root)}\n'


def _document(root: etree._Element) -> str:
    """The document without its XML declaration, one top-level node per line; a URDF
    written as one long line (no line breaks between its elements) is indented."""
    if len(root) and not any("\n" in (n.tail or "") for n in root.iter()):
        etree.indent(root, space="  ")
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
        f"  Calibrated by calib_oed {__version__}: robot {name!r}, "
        f"calib_oed robot {space.robot.name!r}, from {where}.",
        f"  Parameter vector: {space.size} parameters (tracker pose 6, reflector offsets "
        f"{3 * space.n_reflectors}, joints {n_joint}"
        + (f", joint compliances {space.n_joints} (in the sensor YAML)" if space.compliance is not None else "")
        + (f", joint gains and couplings {space.gain_slice.stop - space.gain_slice.start} (in the sensor YAML)"
           if space.joint_gains is not None else "")
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


# ---------------------------------------------------------------- both
def export_calibration(space: ParameterSpace, p: np.ndarray | None,
                       folder: str | os.PathLike, *, stem: str | None = None) -> dict[str, Path]:
    """Write ``<stem>_calibrated.urdf`` and ``<stem>_sensor.yaml`` into ``folder``.

    Args:
        space, p: As for :func:`calibrated_urdf_text`.
        folder: An existing folder.
        stem: File name stem; defaults to the robot's name.

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
    urdf_text = calibrated_urdf_text(space, p)
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


__all__ = [
    "calibrated_urdf_text",
    "export_calibration",
]
