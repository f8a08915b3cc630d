r"""Scenes that check themselves: impossible working configurations and trackers are errors.

:func:`check_scene` runs when a scene is loaded (:func:`calib_oed.scene.reader.load_scene`)
and raises :class:`~calib_oed.exceptions.SceneError` listing every violation
with the pair and its penetration depth in the scene's length unit. It checks
on the URDF collision geometry (meshes and primitives, as the independent
mesh check :mod:`calib_oed.feasibility.mesh_check` does) with coal, because a
working configuration is where the robot really works, not where the
conservative fitted capsules of the design's feasibility model say it could:

1. **The robot at the working configurations** (``kpi.working_configurations``
   and the samples of ``kpi.paths``): every pair of link geometries not on the
   same or adjacent bodies and not in ``feasibility.excluded_pairs``, and every
   moving link against every obstacle of the cell (capsules, half-spaces,
   boxes, cylinders, meshes; an obstacle's ``ignore_links`` are skipped).
   **The tool works on the part**: the body carrying the tool frame may touch
   obstacles, but the KPI point itself (the TCP, or the reflector of
   ``kpi.reflector``) must not be inside one. When the KPI is a reflector
   (``kpi.reflector``), the reflector is on the tool at work, so its ball
   (``feasibility.reflector_radius``) and its laser beam to the tracker
   (``feasibility.beam_radius``) must be clear of the obstacles there too.
2. **The tracker**: its head, a sphere of :data:`TRACKER_HEAD_RADIUS` around
   ``tracker.position``, must not overlap any obstacle of the cell (a tracker
   inside the car) nor the robot at a working configuration. Model the stand
   as an obstacle of the cell (``fms_kr16``'s ``tracker_stand``): the design
   then keeps the robot and the beam clear of it like any other.

An overlap counts when it exceeds :data:`CONTACT_TOLERANCE`. Depths are
computed in [m] and converted to the file's unit only in the message.
"""

from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from calib_oed.exceptions import CalibOedError, SceneError
from calib_oed.feasibility.capsules import load_collision_model
from calib_oed.feasibility.mesh_check import segment_shape, shape_distance
from calib_oed.feasibility.shapes import Cell
from calib_oed.feasibility.solids import solid_collision_objects
from calib_oed.units import LENGTH_UNITS

#: Overlap [m] accepted: URDF collision meshes are approximations of the real
#: links; 1 mm is below what a cell layout can mean.
CONTACT_TOLERANCE = 1e-3
#: Radius [m] of the sphere standing for the tracker head (a Leica AT960 or
#: FARO Vantage head is about 200 mm across).
TRACKER_HEAD_RADIUS = 0.10


@dataclass(frozen=True)
class Violation:
    """One thing a scene gets wrong.

    Attributes:
        where: ``"working configuration 'car_side'"`` or ``"tracker"``.
        pair: What overlaps what (``"link_6 / car_body"``, ``"TCP / floor"``).
        depth: Penetration depth [m], > 0.
        geometry: What it was measured on: ``"URDF collision geometry"`` (robot links),
            or ``"exact"`` (the TCP, the reflector, the beam and the tracker head
            against the obstacles).
    """

    where: str
    pair: str
    depth: float
    geometry: str


#: Distances beyond which a scene's lengths are surely in the wrong unit [m]: no laser
#: tracker measures beyond 160 m, no reflector sits 5 m from the flange.
_MAX_TRACKER_DISTANCE, _MAX_REFLECTOR_OFFSET = 160.0, 5.0


def check_magnitudes(scene) -> None:
    """Catch a unit mistake: numbers in mm with ``units: {length: m}`` put a tracker km away;
    numbers no unit makes plausible are refused without a unit hint."""
    distance = float(np.linalg.norm(scene.tracker.placement().translation))
    offsets = [float(np.linalg.norm(r.offset)) for r in scene.reflectors]
    declared = (scene.units or {}).get("length", "m")
    farthest = max(offsets, default=0.0)
    if distance <= _MAX_TRACKER_DISTANCE and farthest <= _MAX_REFLECTOR_OFFSET:
        return
    source = str(scene.source) if scene.source else None
    in_mm = distance / 1e3 <= _MAX_TRACKER_DISTANCE and farthest / 1e3 <= _MAX_REFLECTOR_OFFSET
    if declared != "m" or not in_mm:  # no unit makes these numbers plausible
        raise SceneError(
            f"the tracker is {distance:.4g} m from the robot base and the farthest reflector "
            f"{farthest:.4g} m from the tool frame (lengths in {declared!r}): no laser tracker "
            f"measures beyond {_MAX_TRACKER_DISTANCE:g} m and no reflector sits "
            f"{_MAX_REFLECTOR_OFFSET:g} m from the flange; check tracker.position and "
            "reflectors[].offset", key="tracker.position" if distance > _MAX_TRACKER_DISTANCE
            else "reflectors", source=source)
    raise SceneError(
        f"the tracker is {distance:.4g} m from the robot base and the farthest reflector "
        f"{farthest:.4g} m from the tool frame, with lengths declared in "
        f"{declared!r}: are the numbers in mm? Then write `units: {{length: mm}}` (valid "
        "length units: m, mm)", key="units.length", source=source)


def check_scene(scene) -> None:
    """Raise :class:`SceneError` if the lengths are surely in the wrong unit
    (:func:`check_magnitudes`) or :func:`scene_violations` finds anything."""
    check_magnitudes(scene)
    found = scene_violations(scene)
    if not found:
        return
    unit = scene.units.get("length", "m")
    scale = LENGTH_UNITS.get(unit, 1.0)
    digits = max(0, 4 - round(-np.log10(scale)))  # 0.1 mm in any unit: mm 1, m 4
    lines = [f"{v.where}: {v.pair} overlap by {v.depth / scale:.{digits}f} {unit} ({v.geometry})"
             for v in found[:12]]
    more = f"; and {len(found) - 12} more" if len(found) > 12 else ""
    raise SceneError(
        "the scene is impossible: " + "; ".join(lines) + more + ". Move the working "
        "configurations, the tracker or the obstacles (kpi.working_configurations, "
        "tracker.position, cell)",
        source=str(scene.source) if scene.source else None,
    )


def scene_violations(scene) -> list[Violation]:
    """Every violation of the scene: working configurations in order, then the tracker."""
    robot, kpi = scene.robot, scene.kpi
    try:
        geom = load_collision_model(robot)
    except CalibOedError as exc:
        raise SceneError(f"cannot check the scene: {exc}", key="robot",
                         source=str(scene.source) if scene.source else None) from exc
    obstacles = cell_obstacles(scene.cell)
    tracker = np.asarray(scene.tracker.position, dtype=float)
    head = (coal.Sphere(TRACKER_HEAD_RADIUS), coal.Transform3s(np.eye(3), tracker))
    out: list[Violation] = []
    for wc in kpi.configurations:
        out += _configuration(scene, geom, obstacles, head, wc)
    for name, _, shape, placement in obstacles:
        depth = -shape_distance(*head, shape, placement)
        if depth > CONTACT_TOLERANCE:
            out.append(Violation("tracker", f"tracker head / {name}", depth, "exact"))
    return out


def cell_obstacles(cell: Cell) -> list[tuple[str, tuple[str, ...], object, coal.Transform3s]]:
    """Every obstacle of ``cell`` as (name, ignored links, coal shape, world placement)."""
    out = []
    for k, cap in enumerate(cell.capsules):
        out.append((cap.name or f"obstacle#{k}", cap.ignore_links,
                    *segment_shape(np.asarray(cap.a, dtype=float), np.asarray(cap.b, dtype=float),
                                   cap.radius)))
    for k, hs in enumerate(cell.halfspaces):
        out.append((hs.name or f"halfspace#{k}", hs.ignore_links,
                    coal.Halfspace(np.asarray(hs.normal, dtype=float), float(hs.offset)),
                    coal.Transform3s()))
    for k, (name, shape, placement, ignored) in enumerate(solid_collision_objects(cell)):
        out.append((name or f"solid#{k}", ignored, shape, placement))
    return out


def _transform(placement: pin.SE3) -> coal.Transform3s:
    return coal.Transform3s(placement.rotation, placement.translation)


def _configuration(scene, geom, obstacles, head, wc) -> list[Violation]:
    robot, kpi = scene.robot, scene.kpi
    model = robot.model
    data, gdata = model.createData(), pin.GeometryData(geom)
    pin.forwardKinematics(model, data, wc.q)
    pin.updateGeometryPlacements(model, data, geom, gdata)
    tool_body = robot.tool_joint
    where = f"working configuration {wc.name!r}"
    objs = list(geom.geometryObjects)
    links = [model.frames[g.parentFrame].name for g in objs]
    joints = [int(g.parentJoint) for g in objs]
    parents = model.parents
    excluded = {frozenset(p) for p in scene.feasibility.excluded_pairs}
    worst: dict[str, float] = {}

    def hit(pair: str, depth: float) -> None:
        if depth > CONTACT_TOLERANCE:
            worst[pair] = max(depth, worst.get(pair, 0.0))

    placements = [_transform(gdata.oMg[k]) for k in range(len(objs))]
    for k in range(len(objs)):
        for m in range(k + 1, len(objs)):
            i, j = joints[k], joints[m]
            if i == j or parents[i] == j or parents[j] == i or frozenset((links[k], links[m])) in excluded:
                continue
            hit(f"{links[k]} / {links[m]}",
                -shape_distance(objs[k].geometry, placements[k], objs[m].geometry, placements[m]))
        hit(f"{links[k]} / tracker head", -shape_distance(objs[k].geometry, placements[k], *head))
        if joints[k] == 0:
            continue  # the fixed base: the floor it stands on is not an obstacle to it
        if joints[k] == tool_body:
            continue  # the tool works on the part
        for name, ignored, shape, placement in obstacles:
            if links[k] not in ignored:
                hit(f"{links[k]} / {name}",
                    -shape_distance(objs[k].geometry, placements[k], shape, placement))
    out = [Violation(where, pair, depth, "URDF collision geometry") for pair, depth in worst.items()]
    tool = pin.updateFramePlacement(model, data, robot.tool_frame_id)
    if kpi.reflector is None:
        points = [("TCP", tool.act(np.asarray(kpi.point, dtype=float)), 0.0)]
    else:
        reflector = scene.reflectors[kpi.reflector]
        centre = tool.act(np.asarray(reflector.offset, dtype=float))
        points = [(f"reflector {reflector.name}", centre, scene.feasibility.reflector_radius)]
        tracker = np.asarray(scene.tracker.position, dtype=float)
        beam = segment_shape(centre, tracker, scene.feasibility.beam_radius)
        for name, _, shape, placement in obstacles:
            depth = -shape_distance(*beam, shape, placement)
            if depth > CONTACT_TOLERANCE:
                out.append(Violation(where, f"laser beam of {reflector.name} / {name}", depth, "exact"))
    for label, x, radius in points:
        ball = (coal.Sphere(max(radius, 1e-9)), coal.Transform3s(np.eye(3), x))
        for name, _, shape, placement in obstacles:
            depth = -shape_distance(*ball, shape, placement)
            if depth > CONTACT_TOLERANCE:
                out.append(Violation(where, f"{label} / {name}", depth, "exact"))
    return out
