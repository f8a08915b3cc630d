"""Robot models: a serial arm loaded from URDF into Pinocchio, with a tool frame.

A :class:`Robot` holds the nominal :class:`pinocchio.Model` reduced to the
serial chain from the base (the world frame) to the tool frame, the joint
limits used for design, and where it came from. It is never mutated:
perturbed models are new objects (see :mod:`calib_oed.model.parameters`).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import (
    JointLimitError,
    NonFiniteError,
    RobotLoadError,
    ShapeError,
    UnknownFrameError,
    UnknownJointError,
    UnknownRobotError,
    UnsupportedModelError,
)
from calib_oed.model.description import (
    default_package_dirs,
    expand_xacro,
    is_xacro,
    resolve_package_paths,
)
from calib_oed.model.registry import (
    EXAMPLE_ROBOTS,
    NOTIONAL_PATTERN,
    OWN_ROBOTS,
    example_robot_data_share,
    own_urdf_path,
    robot_names,
)

# Joint types with one real coordinate per degree of freedom.
_SUPPORTED_JOINTS = {
    "JointModelRX",
    "JointModelRY",
    "JointModelRZ",
    "JointModelRevoluteUnaligned",
    "JointModelPX",
    "JointModelPY",
    "JointModelPZ",
    "JointModelPrismaticUnaligned",
}


def joint_kind(joint) -> str:
    """``"revolute"`` or ``"prismatic"`` for a one-coordinate Pinocchio joint model, else ``"other"``."""
    if joint.nq != 1 or joint.nv != 1:
        return "other"
    name = joint.shortname()
    if name.startswith("JointModelR"):
        return "revolute"
    return "prismatic" if name.startswith("JointModelP") else "other"


@dataclass(frozen=True, eq=False)
class Robot:
    """A serial arm ready for calibration.

    Attributes:
        name: Robot name (registry name or URDF file stem).
        model: Nominal Pinocchio model, joints ``1..n`` from base to tip,
            ``nq = nv = n``. The world frame is the robot base.
        tool_frame: Name of the tool frame.
        tool_frame_id: Its index in ``model.frames``.
        lower: Lower joint limits used for design [rad or m], read-only.
        upper: Upper joint limits [rad or m], read-only.
        urdf_path: The URDF (or xacro) file, or ``None`` for a generated model.
        urdf_text: The URDF the model was built from (for a xacro file, its expansion).
        package_dirs: Folders for resolving ``package://`` mesh paths: those
            given, then the parent folder of every package the URDF names that
            was found there or on ``ROS_PACKAGE_PATH``
            (:func:`calib_oed.model.description.resolve_package_paths`).
        locked_joints: Joints removed from the model and their fixed values.
        xacro_args: The arguments a xacro file was expanded with (empty for a URDF).
    """

    name: str
    model: pin.Model
    tool_frame: str
    tool_frame_id: int
    lower: np.ndarray
    upper: np.ndarray
    urdf_path: Path | None
    urdf_text: str
    package_dirs: tuple[str, ...] = ()
    locked_joints: dict[str, float] = field(default_factory=dict)
    xacro_args: dict[str, str] = field(default_factory=dict)

    @property
    def nq(self) -> int:
        """Number of joints (= configuration dimension)."""
        return self.model.nq

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Actuated joint names from base to tip (URDF names)."""
        return tuple(self.model.names[1:])

    @property
    def prismatic(self) -> np.ndarray:
        """Per joint (nq,), whether it is prismatic (its values in m, not rad)."""
        return np.array([joint_kind(j) == "prismatic" for j in self.model.joints[1:]], dtype=bool)

    @property
    def tool_joint(self) -> int:
        """Index of the joint carrying the tool frame."""
        return int(self.model.frames[self.tool_frame_id].parentJoint)

    def frame_id(self, name: str) -> int:
        """Index of frame ``name``; raises :class:`UnknownFrameError` listing the frames."""
        return frame_index(self.model, name)

    def check_configurations(self, q: np.ndarray, what: str = "q") -> np.ndarray:
        """Validate configurations and return them as a float array of shape (n, nq).

        A single configuration of shape (nq,) is accepted and returned as (1, nq).
        """
        arr = np.asarray(q, dtype=float)
        if arr.ndim == 1:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != self.nq:
            raise ShapeError(what, f"(n, {self.nq}) or ({self.nq},)", np.shape(q))
        if not np.all(np.isfinite(arr)):
            raise NonFiniteError(what, np.flatnonzero(~np.isfinite(arr)).tolist())
        return arr

    def random_configurations(self, n: int, rng: np.random.Generator | int) -> np.ndarray:
        """``n`` configurations uniform in the joint limits, shape (n, nq)."""
        rng = np.random.default_rng(rng)
        return rng.uniform(self.lower, self.upper, size=(int(n), self.nq))


def load_robot(
    source: str | os.PathLike,
    *,
    tool_frame: str | None = None,
    joint_limits: Mapping[str, Sequence[float]] | None = None,
    lock_joints: Mapping[str, float] | None = None,
    package_dirs: Sequence[str | os.PathLike] | None = None,
    xacro_args: Mapping[str, object] | None = None,
) -> Robot:
    """Load a serial arm.

    Args:
        source: A URDF file path, a xacro file path (``*.xacro``, expanded with
            ``xacro_args``), one of our robots (``"kr16"``, ``"kr300"``,
            ``"kr500"``), a notional arm ``"notional_l<λ mm>_m<μ mm>"``, or an
            example-robot-data arm (``"ur5"``, ``"panda"``, ...); see
            :func:`calib_oed.model.registry.robot_names`.
        tool_frame: Name of the tool frame; defaults to the registry's choice,
            or ``tool0`` if the URDF has it, or the last frame of the chain.
        joint_limits: Overrides ``{joint: (lower, upper)}`` [rad or m].
        lock_joints: Joints to hold fixed ``{joint: value}`` [rad or m]; needed
            when the URDF branches (grippers) beside the tool chain.
        package_dirs: Folders for ``package://`` mesh paths and ``$(find pkg)``
            (default: the URDF's folder, or the registry's); ``ROS_PACKAGE_PATH``
            is searched after them.
        xacro_args: Arguments of a xacro file, ``{name: value}`` (as
            ``xacro file.xacro name:=value``).

    Raises:
        RobotLoadError: missing or malformed URDF, xacro that fails to expand.
        UnknownRobotError: unknown robot name.
        UnknownFrameError: unknown tool frame.
        UnknownJointError: an override names a joint the robot does not have.
        UnsupportedModelError: not a serial chain, continuous or mimic joints.
        JointLimitError: inconsistent limits.
    """
    given = None if package_dirs is None else tuple(str(d) for d in package_dirs)
    src = _resolve(source, given, xacro_args)
    where = str(src.path or src.name)
    text, dirs = resolve_package_paths(src.text, src.package_dirs if given is None else given,
                                       where, strict=False)
    src = src._replace(text=text)
    locks = {**src.locked_joints, **(lock_joints or {})}
    mimic = _mimic_joints(src.text, where)
    try:
        full = pin.buildModelFromXML(src.text)
    except (ValueError, RuntimeError) as exc:
        raise RobotLoadError(f"{where}: not a valid URDF model ({exc})") from exc
    model = _reduce_to_chain(full, locks, mimic, where=where)
    tool = tool_frame or src.tool_frame or _default_tool_frame(model)
    tool_id = frame_index(model, tool)
    lower, upper = _limits(model, joint_limits)
    lower.setflags(write=False)
    upper.setflags(write=False)
    return Robot(
        name=src.name,
        model=model,
        tool_frame=tool,
        tool_frame_id=tool_id,
        lower=lower,
        upper=upper,
        urdf_path=src.path,
        urdf_text=src.text,
        package_dirs=dirs,
        locked_joints=locks,
        xacro_args={str(k): str(v) for k, v in (xacro_args or {}).items()},
    )


class _Source(NamedTuple):
    """Where a robot description comes from, and its registry defaults."""

    name: str
    path: Path | None
    text: str
    tool_frame: str | None = None
    locked_joints: Mapping[str, float] = {}
    package_dirs: tuple[str, ...] = ()


def _resolve(source: str | os.PathLike, package_dirs: tuple[str, ...] | None,
             xacro_args: Mapping[str, object] | None) -> _Source:
    src = str(source)
    if xacro_args and not is_xacro(src):
        raise RobotLoadError(f"xacro_args given for {src!r}, which is not a xacro file "
                             "(*.xacro); a URDF takes no arguments")
    if src in OWN_ROBOTS:
        path = own_urdf_path(src)
        return _Source(src, path, path.read_text(), OWN_ROBOTS[src])
    match = NOTIONAL_PATTERN.match(src)
    if match:
        from calib_oed.model.kuka import kuka_urdf, notional_dimensions

        dims = notional_dimensions(int(match.group(1)) / 1000.0, int(match.group(2)) / 1000.0)
        return _Source(src, None, kuka_urdf(dims), "tool0")
    if src in EXAMPLE_ROBOTS:
        share = example_robot_data_share()
        if share is None:
            raise RobotLoadError(
                f"robot {src!r} comes from example-robot-data, which is not installed "
                "(pip install example-robot-data)"
            )
        entry = EXAMPLE_ROBOTS[src]
        path = share / "example-robot-data" / "robots" / entry.urdf
        return _Source(src, path, path.read_text(), entry.tool_frame, entry.locked_joints,
                       (str(share),))
    path = Path(src)
    looks_like_path = (os.sep in src or src.endswith((".urdf", ".xml")) or is_xacro(src)
                       or path.exists())
    if not looks_like_path:
        raise UnknownRobotError(src, robot_names())
    if not path.is_file():
        raise RobotLoadError(f"{'xacro' if is_xacro(src) else 'URDF'} file not found: {path}")
    here = default_package_dirs(path)
    if is_xacro(src):
        text = expand_xacro(path, xacro_args, package_dirs if package_dirs is not None else here)
        stem = path.name.removesuffix(".xacro").removesuffix(".urdf")
        return _Source(stem, path.resolve(), text, package_dirs=here)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise RobotLoadError(f"{path}: cannot read URDF ({exc})") from exc
    return _Source(path.stem, path.resolve(), text, package_dirs=here)


def _mimic_joints(text: str, where: str) -> set[str]:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotLoadError(f"{where}: malformed XML ({exc})") from exc
    if root.tag != "robot":
        raise RobotLoadError(f"{where}: root element is <{root.tag}>, expected <robot>")
    return {j.get("name") for j in root.iter("joint") if j.find("mimic") is not None}


def _reduce_to_chain(full: pin.Model, locks: Mapping[str, float], mimic: set[str], where: str):
    names = list(full.names)
    for joint in locks:
        if joint not in names[1:]:
            raise UnknownJointError(joint, names[1:])
    lock_ids = [full.getJointId(j) for j in locks]
    if lock_ids:
        q_ref = pin.neutral(full)
        for j, value in locks.items():
            jid = full.getJointId(j)
            q_ref[full.joints[jid].idx_q] = float(value)
        model = pin.buildReducedModel(full, lock_ids, q_ref)
    else:
        model = full
    bad = [
        f"{n} ({j.shortname()})"
        for n, j in zip(model.names[1:], model.joints[1:], strict=True)
        if j.shortname() not in _SUPPORTED_JOINTS or j.nq != 1
    ]
    if bad:
        raise UnsupportedModelError(
            f"{where}: joints {bad} are not single-coordinate revolute or prismatic joints "
            "(continuous joints have two coordinates in Pinocchio); give them limits as "
            "'revolute' joints in the URDF, or lock them (the scene's robot.lock_joints: "
            "{name: value}; lock_joints= in Python)"
        )
    on_chain_mimic = sorted(set(model.names[1:]) & mimic)
    if on_chain_mimic:
        raise UnsupportedModelError(
            f"{where}: mimic joints {on_chain_mimic} cannot be calibrated as independent joints; "
            "lock them (the scene's robot.lock_joints: {name: value}; lock_joints= in Python)"
        )
    branches = [
        model.names[i] for i in range(1, model.njoints) if model.parents[i] != i - 1
    ]
    if branches:
        raise UnsupportedModelError(
            f"{where}: not a serial chain: joints {branches} branch off the chain "
            f"{list(model.names[1:])}; lock the joints that are not on the path from the "
            "base to the tool frame with lock_joints={name: value}"
        )
    if model.njoints < 2:
        raise UnsupportedModelError(f"{where}: the model has no movable joint")
    return model


# When a URDF names a joint and a link alike, prefer the link (body) frame.
_FRAME_PREFERENCE = (pin.FrameType.OP_FRAME, pin.FrameType.BODY, pin.FrameType.FIXED_JOINT,
                     pin.FrameType.JOINT, pin.FrameType.SENSOR)


def frame_index(model: pin.Model, name: str) -> int:
    """Index of the frame called ``name`` (link frames preferred over joint frames).

    Raises:
        UnknownFrameError: no frame has that name; the error lists the frames.
    """
    matches = [i for i, f in enumerate(model.frames) if f.name == name]
    if not matches:
        raise UnknownFrameError(name, list(dict.fromkeys(f.name for f in model.frames)))
    rank = {t: k for k, t in enumerate(_FRAME_PREFERENCE)}
    return min(matches, key=lambda i: rank.get(model.frames[i].type, len(rank)))


def _default_tool_frame(model: pin.Model) -> str:
    if model.existFrame("tool0"):
        return "tool0"
    return model.frames[len(model.frames) - 1].name


def _limits(model: pin.Model, overrides: Mapping[str, Sequence[float]] | None):
    lower = np.array(model.lowerPositionLimit, dtype=float)
    upper = np.array(model.upperPositionLimit, dtype=float)
    names = list(model.names[1:])
    for joint, bounds in (overrides or {}).items():
        if joint not in names:
            raise UnknownJointError(joint, names)
        b = np.asarray(bounds, dtype=float)
        if b.shape != (2,):
            raise ShapeError(f"joint_limits[{joint!r}]", "(2,) = (lower, upper)", b.shape)
        lower[names.index(joint)], upper[names.index(joint)] = b
    for i, joint in enumerate(names):
        if not (np.isfinite(lower[i]) and np.isfinite(upper[i])):
            raise JointLimitError(
                f"joint {joint!r} has no finite limits; give them with joint_limits="
                f"{{{joint!r}: (lower, upper)}}"
            )
        if lower[i] >= upper[i]:
            raise JointLimitError(
                f"joint {joint!r}: lower limit {lower[i]:.6g} is not below upper limit "
                f"{upper[i]:.6g}"
            )
    return lower, upper
