r"""The ``fms_kr16`` cell scaled for another KUKA-class arm (the paper's scaled FMS scene).

The paper's second study measures 90 notional arms (:func:`calib_oed.model.kuka.notional_grid`)
"in the FMS scene"; an arm of 2.4 m reach cannot use a cell drawn around a
1.6 m arm, so each arm gets the ``fms_kr16`` cell scaled by the ratio of the
nominal reaches (:attr:`calib_oed.model.kuka.KukaDimensions.reach`, axis A1 to the
stretched wrist centre),

.. math::
    s = \frac{\mathrm{reach}(\text{arm})}{\mathrm{reach}(\text{template arm})}
    \quad (\text{kr16: } 1610.91\ \text{mm}),

the rule the shipped ``fms_kr300`` and ``fms_kr500`` follow (docs/scenes.md),
here without rounding to whole millimetres.

**Scaled by s** (every length of the cell, in the file's length unit):

- the tracker position :math:`t_{WT}`;
- the world-fixed obstacle capsules (end points and radii), except the
  tracker stand;
- the half-space offsets (``x_min`` ... ``z_max`` values and ``offset``; the
  floor's 0 stays 0).

**Rebuilt** from the scaled tracker: the tracker stand (``tracker_stand``)
stands vertically under the tracker head, its foot at the template's height
(the floor) and its top the template's gap (300 mm) below the head; its radius
is the template's (the same stand). The tracker rpy is recomputed with the
rule of ``fms_kr16``: roll 0, the x axis aimed at the midpoint of the shoulder
(the ``joint_a2`` origin) at the first working configuration and the mean
working TCP (the KPI point in the world); not rounded.

**Not scaled** (the same instrument, the same task in joint space): the
working configurations' joint angles :math:`q`, the reflector offsets, σ and
σ_angle, the KPI point and frame, the measurement model, the generic design,
the joint limits, and every feasibility setting (incidence limit, beam and
reflector radii, margins, excluded pairs, pruning).

The result goes through :func:`calib_oed.scene.reader.scene_from_dict`, so it is
validated exactly like a scene file.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from calib_oed.exceptions import SceneError, UnknownRobotError
from calib_oed.model.kuka import KUKA_ROBOTS, KukaDimensions, notional_dimensions
from calib_oed.model.registry import NOTIONAL_PATTERN
from calib_oed.model.robot import load_robot
from calib_oed.scene.cell import HALFSPACE_SHORTHANDS
from calib_oed.scene.reader import SHIPPED, scene_from_dict, scene_names
from calib_oed.scene.records import Scene
from calib_oed.scene.yaml_file import load_yaml_file, shipped_file
from calib_oed.units import ANGLE_UNITS

__all__ = ["STAND_NAME", "TEMPLATE", "kuka_dimensions", "scale_factor", "scaled_scene",
           "scaled_scene_dict"]

#: The template scene of the paper's scaled FMS cell.
TEMPLATE = "fms_kr16"
#: Name of the template's tracker-stand capsule (rebuilt, not scaled).
STAND_NAME = "tracker_stand"
#: The shoulder: index of ``joint_a2`` in the Pinocchio model (``oMi``).
_SHOULDER_JOINT = 2


def kuka_dimensions(robot: str) -> KukaDimensions:
    """Dimensions of a KUKA-class arm by name: ``kr16``, ``kr300``, ``kr500`` or a notional arm.

    Raises:
        UnknownRobotError: not a KUKA-class arm with known dimensions.
    """
    if robot in KUKA_ROBOTS:
        return KUKA_ROBOTS[robot]
    match = NOTIONAL_PATTERN.match(str(robot))
    if match:
        return notional_dimensions(int(match.group(1)) / 1000.0, int(match.group(2)) / 1000.0)
    raise UnknownRobotError(str(robot), [*KUKA_ROBOTS, "notional_l<lambda_mm>_m<mu_mm>"])


def scale_factor(robot: str, template_robot: str = "kr16") -> float:
    """:math:`s` = reach(``robot``) / reach(``template_robot``) [1]."""
    return kuka_dimensions(robot).reach / kuka_dimensions(template_robot).reach


def _template_data(template: str | os.PathLike | Mapping[str, Any]) -> tuple[dict, str | None]:
    """The template as a parsed mapping, and the file it came from."""
    if isinstance(template, Mapping):
        return copy.deepcopy(dict(template)), None
    text = os.fspath(template)
    path = shipped_file(SHIPPED, text)
    if path is None:
        path = Path(text)
        if not path.is_file():
            raise SceneError(f"template scene not found: {text!r} is neither a shipped scene "
                             f"({', '.join(scene_names())}) nor a file")
    try:
        data = load_yaml_file(path, "template scene")
    except (OSError, yaml.YAMLError) as exc:
        raise SceneError(f"cannot read the template scene ({exc})", source=str(path)) from exc
    if not isinstance(data, dict):
        raise SceneError("expected a scene mapping", source=str(path))
    return data, str(path)


def _scaled(values, s: float) -> list[float]:
    return [float(v) * s for v in values]


def _aim_rpy(robot: str, tool_frame: str | None, q_work: np.ndarray, point: np.ndarray,
             tracker: np.ndarray) -> np.ndarray:
    """rpy [rad] of a tracker at ``tracker`` [m] whose x axis aims at the working volume."""
    arm = load_robot(robot, tool_frame=tool_frame)
    model, data = arm.model, arm.model.createData()
    tcps = []
    for q in q_work:
        pin.framesForwardKinematics(model, data, q)
        tcps.append(data.oMf[arm.tool_frame_id].act(point))
        if len(tcps) == 1:
            shoulder = data.oMi[_SHOULDER_JOINT].translation.copy()
    d = 0.5 * (shoulder + np.mean(tcps, axis=0)) - tracker
    yaw = math.atan2(d[1], d[0])
    pitch = -math.atan2(d[2], math.hypot(d[0], d[1]))  # x = (cp cy, cp sy, -sp): + tips down
    return np.array([0.0, pitch, yaw])


def scaled_scene_dict(
    robot: str,
    template: str | os.PathLike | Mapping[str, Any] = TEMPLATE,
    *,
    name: str | None = None,
) -> dict:
    """The scene mapping (schema of docs/scenes.md) of ``template`` scaled for ``robot``.

    Args:
        robot: A KUKA-class arm: ``kr16``, ``kr300``, ``kr500`` or
            ``notional_l<λ mm>_m<μ mm>``.
        template: A shipped scene name, a scene file or a parsed scene whose
            robot is KUKA-class (default ``fms_kr16``).
        name: Scene name; default the template's with its robot suffix
            replaced (``fms_kr16`` → ``fms_notional_l650_m600``).

    Returns:
        A new mapping in the template's units; see the module docstring for
        what is scaled.

    Raises:
        UnknownRobotError: ``robot`` or the template's robot has no KUKA dimensions.
        SceneError: the template cannot be read or lacks ``robot.name`` or
            ``tracker.position``.
    """
    data, source = _template_data(template)
    base_robot = (data.get("robot") or {}).get("name")
    if not isinstance(base_robot, str):
        raise SceneError("the template must name its robot (robot.name), a KUKA-class arm",
                         key="robot.name", source=source)
    s = scale_factor(robot, base_robot)
    tracker = data.get("tracker") or {}
    if "position" not in tracker:
        raise SceneError("the template needs a tracker position", key="tracker.position",
                         source=source)
    old_tracker = np.array(tracker["position"], dtype=float)
    new_tracker = old_tracker * s
    tracker["position"] = new_tracker.tolist()

    cell = data.get("cell") or {}
    for cap in cell.get("capsules", []):
        if cap.get("name") == STAND_NAME:
            a, b = np.array(cap["a"], dtype=float), np.array(cap["b"], dtype=float)
            cap["a"] = [float(new_tracker[0]), float(new_tracker[1]), float(a[2])]
            cap["b"] = (b - old_tracker + new_tracker).tolist()  # the same gap below the head
        else:
            cap["a"], cap["b"] = _scaled(cap["a"], s), _scaled(cap["b"], s)
            cap["radius"] = float(cap["radius"]) * s
    for half in cell.get("halfspaces", []):
        for key in (*HALFSPACE_SHORTHANDS, "offset"):
            if key in half:
                half[key] = float(half[key]) * s

    # rpy by the aiming rule, on the loaded geometry (SI), written in the file's angle unit.
    data["robot"] = {**data["robot"], "name": robot}
    probe = scene_from_dict(data, source=source)
    rpy = _aim_rpy(robot, probe.robot.tool_frame, probe.kpi.q, probe.kpi.point,
                   probe.tracker.position)
    angle = ANGLE_UNITS[probe.units["angle"]]
    tracker["rpy"] = (rpy / angle).tolist()
    old_name = str(data.get("name", "scene"))
    suffix = f"_{base_robot}"
    data["name"] = name or (old_name[: -len(suffix)] if old_name.endswith(suffix)
                            else old_name) + f"_{robot}"
    data["description"] = (f"{old_name} scaled for {robot} by s = {s:.6g} (reach ratio "
                           f"to {base_robot}; calib_oed.scene.scaling)")
    return data


def scaled_scene(
    robot: str,
    template: str | os.PathLike | Mapping[str, Any] = TEMPLATE,
    *,
    name: str | None = None,
) -> Scene:
    """:func:`scaled_scene_dict` loaded through :func:`calib_oed.scene.reader.scene_from_dict`."""
    data = scaled_scene_dict(robot, template, name=name)
    return scene_from_dict(data, source=None)
