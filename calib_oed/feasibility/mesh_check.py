r"""Independent feasibility check of a design against the URDF collision meshes.

The design constraints work on capsules; this module checks the same poses
against the real collision geometry (Pinocchio :class:`~pinocchio.GeometryModel`,
distances by coal), to validate designs and the capsule model itself.

Checked pairs, each a coal distance per pose:

- robot–robot: every two collision geometries of links on joints :math:`i \ne j`
  that are not parent and child in the chain (links on one joint are one body,
  so fixed base links pair with neither the base nor joint 1), minus
  ``excluded_pairs``;
- robot–cell: every geometry of a moving link against every obstacle capsule
  (a ``coal.Capsule`` at the segment midpoint, local :math:`z` along the segment)
  and every half-space (``coal.Halfspace(n, c)``, the solid :math:`n^\top x \le c`);
  links fixed to the base are not checked (the base stands on the floor);
- beam (given a tracker position and reflector offsets): the segment from reflector
  :math:`c_j` (tool frame) to the tracker, a capsule of ``beam_radius``, against
  every robot geometry not on the tool frame's joint and every cell capsule; against
  a half-space its signed distance is :math:`\min(n^\top x_0, n^\top x_1) - c - r`
  over its end points :math:`x_0, x_1`.

A pose is feasible if every distance is > ``clearance``. Distances are signed
for pairs of primitives (negative: penetration depth); coal reports 0 for
intersecting meshes. A mesh is a surface: a body wholly inside a closed mesh,
touching none of its triangles, is not detected.

All lengths in [m]; :meth:`MeshCheckReport.summary` prints mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from calib_oed.exceptions import NonFiniteError, ShapeError, UnknownLinkError
from calib_oed.feasibility.capsules import link_names, load_collision_model
from calib_oed.feasibility.shapes import Cell
from calib_oed.feasibility.solids import solid_collision_objects
from calib_oed.model.robot import Robot
from calib_oed.values import readonly

__all__ = ["MeshCheckReport", "check_design_meshes"]

Pair = tuple[str, str]


@dataclass(frozen=True, eq=False)
class MeshCheckReport:
    """Distances of a design's poses to collision, from the collision meshes.

    Attributes:
        pairs: Names of every checked pair (link, link / obstacle / ``"beam#j"``),
            one per geometry pair, so a name pair may repeat, (n_pairs,).
        kinds: ``"robot"``, ``"cell"`` or ``"beam"`` per pair.
        distances: Distance of each pair in each pose [m], (n, n_pairs), read-only.
        clearance: Distance a pair must exceed [m].
        min_distance: Smallest distance per pose [m], (n,) (``inf`` if no pair).
        closest_pair: Names of the closest pair per pose (``None`` if no pair).
        feasible: Whether every distance of the pose exceeds ``clearance``, (n,).
        colliding_pairs: Per pose, the distinct name pairs within ``clearance``,
            closest first.
    """

    pairs: tuple[Pair, ...]
    kinds: tuple[str, ...]
    distances: np.ndarray
    clearance: float
    min_distance: np.ndarray
    closest_pair: tuple[Pair | None, ...]
    feasible: np.ndarray
    colliding_pairs: tuple[tuple[Pair, ...], ...]

    @classmethod
    def from_distances(
        cls, pairs: Sequence[Pair], kinds: Sequence[str], distances: np.ndarray, clearance: float
    ) -> MeshCheckReport:
        """Build the report from the pair distances ``(n, n_pairs)`` [m]."""
        dist = np.array(distances, dtype=float).reshape(-1, len(pairs))
        pairs = tuple((str(a), str(b)) for a, b in pairs)
        n = dist.shape[0]
        if pairs:
            closest = dist.argmin(axis=1)
            min_distance = dist[np.arange(n), closest]
            closest_pair = tuple(pairs[k] for k in closest)
        else:
            min_distance, closest_pair = np.full(n, np.inf), (None,) * n
        colliding = []
        for row in dist:
            hits = [pairs[k] for k in np.argsort(row, kind="stable") if row[k] <= clearance]
            colliding.append(tuple(dict.fromkeys(hits)))
        return cls(
            pairs=pairs,
            kinds=tuple(kinds),
            distances=readonly(dist),
            clearance=float(clearance),
            min_distance=readonly(np.asarray(min_distance, dtype=float)),
            closest_pair=closest_pair,
            feasible=readonly(np.asarray(min_distance, dtype=float) > clearance),
            colliding_pairs=tuple(colliding),
        )

    @property
    def n_pairs(self) -> int:
        """Number of checked geometry pairs per pose."""
        return len(self.pairs)

    @property
    def n_poses(self) -> int:
        """Number of poses."""
        return int(self.distances.shape[0])

    def all_feasible(self) -> bool:
        """Whether every pose is feasible."""
        return bool(np.all(self.feasible))

    def summary(self, max_lines: int = 20) -> str:
        """Text summary in mm: counts, then every infeasible pose (up to ``max_lines``)."""
        counts = ", ".join(f"{self.kinds.count(k)} {k}" for k in ("robot", "cell", "beam"))
        lines = [
            f"mesh check: {self.n_poses} poses, {self.n_pairs} pairs per pose ({counts}), "
            f"clearance [mm] {self.clearance * 1e3:.1f}",
            f"feasible: {int(self.feasible.sum())} / {self.n_poses} poses",
        ]
        if self.n_poses and self.n_pairs:
            k = int(np.argmin(self.min_distance))
            lines.append(
                f"smallest distance [mm]: {self.min_distance[k] * 1e3:.1f} at pose {k} "
                f"({' / '.join(self.closest_pair[k])})"
            )
        bad = np.flatnonzero(~self.feasible)
        for i in bad[:max_lines]:
            names = "; ".join(" / ".join(p) for p in self.colliding_pairs[i][:5])
            more = len(self.colliding_pairs[i]) - 5
            extra = f" (+{more} more)" if more > 0 else ""
            lines.append(
                f"  pose {i:4d}: min distance [mm] {self.min_distance[i] * 1e3:8.1f}; "
                f"within clearance: {names}{extra}"
            )
        if len(bad) > max_lines:
            lines.append(f"  ... ({len(bad) - max_lines} more infeasible poses)")
        return "\n".join(lines)


def segment_shape(a: np.ndarray, b: np.ndarray, radius: float):
    """coal capsule (or sphere) of the segment a-b and its placement in the world."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    centre = 0.5 * (a + b)
    if length < 1e-12:
        return coal.Sphere(radius), pin.SE3(np.eye(3), centre)
    rot = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), axis / length).matrix()
    return coal.Capsule(radius, length), pin.SE3(rot, centre)


def shape_distance(g1, M1, g2, M2) -> float:
    """Signed distance [m] of two coal shapes at their world placements (negative: penetration depth)."""
    return float(coal.distance(g1, M1, g2, M2, coal.DistanceRequest(), coal.DistanceResult()))


def _obstacle_names(cell: Cell) -> tuple[list[str], list[str]]:
    caps = [c.name or f"obstacle#{i}" for i, c in enumerate(cell.capsules)]
    halves = [h.name or f"halfspace#{i}" for i, h in enumerate(cell.halfspaces)]
    return caps, halves


def check_design_meshes(
    robot: Robot,
    q: np.ndarray,
    cell: Cell | None = None,
    *,
    tracker_position: np.ndarray | None = None,
    reflector_offsets: np.ndarray | None = None,
    beam_radius: float = 0.005,
    excluded_pairs: Sequence[tuple[str, str]] = (),
    clearance: float = 0.0,
    geometry_model: pin.GeometryModel | None = None,
) -> MeshCheckReport:
    """Check poses ``q`` (n, nq) against the collision meshes (module docstring).

    Args:
        robot: The robot.
        q: Configurations (n, nq) or (nq,) [rad or m].
        cell: World-fixed obstacles; ``None`` for an empty cell.
        tracker_position: Tracker position in the world (3,) [m]; with
            ``reflector_offsets``, the laser beams are checked.
        reflector_offsets: Reflector centres in ``robot.tool_frame`` (k, 3) [m].
        beam_radius: Radius of the beam capsule [m].
        excluded_pairs: Link-name pairs never checked against each other.
        clearance: A pose is feasible if every distance exceeds this [m].
        geometry_model: Collision geometry from :func:`load_collision_model`
            (loaded if ``None``).

    Raises:
        ShapeError, NonFiniteError: bad ``q``, tracker position or reflector offsets.
        UnknownLinkError: ``excluded_pairs`` names an unknown link.
        ValueError: only one of ``tracker_position`` and ``reflector_offsets`` given,
            or a negative ``beam_radius``.
        RobotLoadError: the collision meshes cannot be loaded.
    """
    qs = robot.check_configurations(q)
    cell = Cell() if cell is None else cell
    model = robot.model
    geom = load_collision_model(robot) if geometry_model is None else geometry_model
    tool_id = robot.frame_id(robot.tool_frame)
    tool_joint = int(model.frames[tool_id].parentJoint)
    beams = _beam_inputs(tracker_position, reflector_offsets, beam_radius)

    valid = link_names(robot)
    excluded = set()
    for pair in excluded_pairs:
        first, second = pair
        for name in (first, second):
            if name not in valid:
                raise UnknownLinkError(name, valid)
        excluded |= {(first, second), (second, first)}

    objs = list(geom.geometryObjects)
    links = [model.frames[go.parentFrame].name for go in objs]
    joints = [int(go.parentJoint) for go in objs]
    parents = list(model.parents)

    def adjacent(i: int, j: int) -> bool:
        return i == j or parents[i] == j or parents[j] == i

    pairs: list[Pair] = []
    kinds: list[str] = []
    robot_pairs = [
        (k, m)
        for k in range(len(objs))
        for m in range(k + 1, len(objs))
        if not adjacent(joints[k], joints[m]) and (links[k], links[m]) not in excluded
    ]
    pairs += [(links[k], links[m]) for k, m in robot_pairs]
    kinds += ["robot"] * len(robot_pairs)
    moving = [k for k in range(len(objs)) if joints[k] != 0]
    cap_names, half_names = _obstacle_names(cell)
    cell_shapes = [segment_shape(c.a, c.b, c.radius) for c in cell.capsules]
    solids = solid_collision_objects(cell)  # boxes, cylinders, meshes: checked like the capsules
    cap_names += [s[0] for s in solids]
    cell_shapes += [s[1:3] for s in solids]
    cell_shapes += [
        (coal.Halfspace(np.asarray(h.normal), float(h.offset)), pin.SE3.Identity())
        for h in cell.halfspaces
    ]
    cell_names = cap_names + half_names
    ignored = [o.ignore_links for o in cell.capsules] + [s[3] for s in solids] + [h.ignore_links for h in cell.halfspaces]
    cell_pairs = [(k, o) for k in moving for o in range(len(cell_shapes)) if links[k] not in ignored[o]]
    pairs += [(links[k], cell_names[o]) for k, o in cell_pairs]
    kinds += ["cell"] * len(cell_pairs)
    beam_geoms = [k for k in range(len(objs)) if joints[k] != tool_joint]
    n_refl = 0 if beams is None else len(beams[1])
    for j in range(n_refl):
        pairs += [(f"beam#{j}", links[k]) for k in beam_geoms]
        pairs += [(f"beam#{j}", name) for name in cap_names + half_names]
    kinds += ["beam"] * (n_refl * (len(beam_geoms) + len(cell_names)))

    data = model.createData()
    gdata = pin.GeometryData(geom)
    dist = np.empty((len(qs), len(pairs)))
    for i, qi in enumerate(qs):
        pin.forwardKinematics(model, data, qi)
        pin.updateGeometryPlacements(model, data, geom, gdata)
        oMg = gdata.oMg
        row = [
            shape_distance(objs[k].geometry, oMg[k], objs[m].geometry, oMg[m]) for k, m in robot_pairs
        ]
        row += [shape_distance(objs[k].geometry, oMg[k], *cell_shapes[o]) for k, o in cell_pairs]
        if beams is not None:
            tracker, offsets, radius = beams
            oMf = pin.updateFramePlacement(model, data, tool_id)
            for c in offsets:
                start = oMf.act(c)
                beam, M = segment_shape(start, tracker, radius)
                row += [shape_distance(objs[k].geometry, oMg[k], beam, M) for k in beam_geoms]
                row += [shape_distance(beam, M, *cell_shapes[o]) for o in range(len(cap_names))]
                row += [
                    float(min(h.signed_distance(start), h.signed_distance(tracker)) - radius)
                    for h in cell.halfspaces
                ]
        dist[i] = row
    return MeshCheckReport.from_distances(pairs, kinds, dist, clearance)


def _beam_inputs(tracker_position, reflector_offsets, beam_radius):
    """Validated ``(tracker (3,), offsets (k, 3), radius)``, or ``None`` without a beam."""
    if tracker_position is None and reflector_offsets is None:
        return None
    if tracker_position is None or reflector_offsets is None:
        raise ValueError(
            "the beam check needs both tracker_position (3,) [m] and reflector_offsets (k, 3) [m]"
        )
    tracker = np.asarray(tracker_position, dtype=float)
    if tracker.shape != (3,):
        raise ShapeError("tracker_position", "(3,)", tracker.shape)
    offsets = np.asarray(reflector_offsets, dtype=float)
    if offsets.ndim == 1:
        offsets = offsets[None, :]
    if offsets.ndim != 2 or offsets.shape[1] != 3:
        raise ShapeError("reflector_offsets", "(k, 3)", np.shape(reflector_offsets))
    for what, arr in (("tracker_position", tracker), ("reflector_offsets", offsets)):
        if not np.all(np.isfinite(arr)):
            raise NonFiniteError(what, np.flatnonzero(~np.isfinite(arr)).tolist())
    radius = float(beam_radius)
    if not (np.isfinite(radius) and radius > 0.0):
        raise ValueError(f"beam_radius must be > 0 [m], got {beam_radius!r}")
    return tracker, offsets, radius
