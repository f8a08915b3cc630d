r"""Several capsules per link, fitted to its collision meshes: slabs along an axis.

One capsule per link (:func:`calib_oed.feasibility.capsules.fit_capsule`) is
1.5-2.5 times the volume of the link's convex hull for the bent or stepped
links of mesh robots. Here a link is cut into :math:`k` slabs by parallel
planes :math:`u^\top x = c_1 < \dots < c_{k-1}` (link frame, :math:`\|u\| = 1`)
and one capsule is fitted to each slab's part of the link.

**Enclosure.** A triangle clipped to a slab
:math:`\{c_{i-1} \le u^\top x \le c_i\}` is a convex polygon whose corners are
the triangle's vertices inside the slab and the points where its edges cross
the two planes. The capsule of slab :math:`i` encloses all those points, hence
their convex hull, hence every triangle's part in the slab; and the solid a
closed mesh bounds, since any of its points in the slab lies on a chord of the
plane section through it. The union of the :math:`k` capsules thus encloses the
link. Two consecutive capsules both contain the cut polygon (the edge-plane
crossings), so the union has no gap at the cuts.

**Choice, by measurement.** The objective is the sum of the capsule volumes
:math:`\sum_i \pi r_i^2 L_i + \tfrac43 \pi r_i^3` [m³] (an upper bound of the
union's). For each candidate axis (the axis of the single fitted capsule and
the three principal axes of the vertices) the cuts are chosen on a grid of
``grid`` equally spaced positions across the link; the volume :math:`V(g, h)`
of the capsule of every slab between grid positions :math:`g < h` is
estimated once (the smallest capsule on the slab axis or a principal axis of
the slab's points, through their centroid or the centre of their extent
across the axis, without refinement) and dynamic programming gives the best
partition into :math:`k = 1..K` slabs.
A slab more must pay for itself: :math:`k` is chosen to minimise
:math:`V_k / (1 - \gamma)^{k-1}` with :math:`\gamma` = ``min_gain`` (10 %), so
a split is kept only if it reduces the volume materially. The chosen slabs'
capsules are then refined (Nelder-Mead over the axis, as for one capsule),
which only makes them tighter.

Links whose geometry is not all meshes (primitives: cylinders, boxes, spheres,
e.g. the KUKA-class URDFs of :mod:`calib_oed.model.kuka`) keep one capsule for
the link (with ``split_primitives``: one per primitive when that is smaller by
the same rule).

All lengths in [m], volumes in [m³].
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin
from scipy.spatial import ConvexHull, QhullError

from calib_oed.exceptions import LinkFitSettingsError
from calib_oed.feasibility import fit_cache
from calib_oed.feasibility.capsules import (
    _capsule_on_line,
    _local_balls,
    _perpendicular_basis,
    capsules_from_table,
    check_margin,
    fit_capsule,
    link_geometry_points,
    link_names,
    load_collision_model,
)
from calib_oed.feasibility.shapes import Capsule

__all__ = ["LinkFit", "LinkFitSettings", "LinkMesh", "capsule_volume", "fit_link", "fit_link_capsules",
           "fit_robot_links", "fitted_robot_capsules", "geometry_key", "link_meshes", "slab_points"]  # fmt: skip


@dataclass(frozen=True)
class LinkFitSettings:
    """How many capsules a link may get.

    Attributes:
        max_capsules: Largest number of slabs (capsules) per link, >= 1.
        min_gain: A slab more is kept only if it cuts the total capsule volume by
            at least this fraction (0.10 = 10 %).
        grid: Number of candidate cut positions across the link, >= 1.
        split_primitives: Let a link of several primitives (no meshes) have one
            capsule per primitive when that is smaller by the ``min_gain`` rule;
            off by default: robots without meshes keep one capsule per link.
    """

    max_capsules: int = 3
    min_gain: float = 0.10
    grid: int = 9
    split_primitives: bool = False

    def __post_init__(self):
        for name in ("max_capsules", "grid"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise LinkFitSettingsError(name, value, "must be an integer >= 1")
        gain = self.min_gain
        if isinstance(gain, bool) or not isinstance(gain, (int, float)) or not 0.0 <= gain < 1.0:
            raise LinkFitSettingsError("min_gain", gain, "must be a fraction in [0, 1) (0.10 = 10 %)")


@dataclass(frozen=True, eq=False)
class LinkMesh:
    """A link's collision meshes as one triangle soup, in the link frame.

    Attributes:
        vertices: (n, 3) [m].
        edges: Unique vertex-index pairs of the triangle edges, (e, 2).
    """

    vertices: np.ndarray
    edges: np.ndarray


@dataclass(frozen=True, eq=False)
class LinkFit:
    """The capsules of one link and how tight they are.

    Attributes:
        link: Link name.
        capsules: Its capsules (link frame), named ``"<link>#<k>"``.
        hull_volume: Volume of the convex hull of its geometry [m³] (NaN if flat).
        capsule_volume: Sum of the capsule volumes [m³].
        single_volume: Volume of the one capsule fitted to the whole link [m³].
        meshes: Whether the link's geometry is all meshes (slab split tried).
    """

    link: str
    capsules: tuple[Capsule, ...]
    hull_volume: float
    capsule_volume: float
    single_volume: float
    meshes: bool

    @property
    def ratio(self) -> float:
        """Capsule volume over hull volume (the sum of capsule volumes, an upper bound)."""
        return self.capsule_volume / self.hull_volume

    @property
    def single_ratio(self) -> float:
        """The same ratio for the one-capsule fit."""
        return self.single_volume / self.hull_volume


def capsule_volume(a: np.ndarray, b: np.ndarray, radius: float) -> float:
    r""":math:`\pi r^2 \|b - a\| + \tfrac43 \pi r^3` [m³]."""
    return float(np.pi * radius**2 * np.linalg.norm(np.asarray(b) - np.asarray(a)) + 4.0 / 3.0 * np.pi * radius**3)


def _triangles(geometry) -> np.ndarray:
    return np.array([[geometry.tri_indices(i)[k] for k in range(3)] for i in range(geometry.num_tris)],
                    dtype=int).reshape(-1, 3)


def link_meshes(robot, geometry_model: pin.GeometryModel) -> dict[str, LinkMesh | None]:
    """Per link (model frame order), its meshes as one :class:`LinkMesh`, or ``None``
    when any of its geometries is not a triangle mesh."""
    out: dict[str, list] = {}
    for go in geometry_model.geometryObjects:
        frame = robot.model.frames[go.parentFrame]
        entry = out.setdefault(frame.name, [])
        geom = go.geometry
        if entry is None or not isinstance(geom, coal.BVHModelBase) or geom.num_tris == 0:
            out[frame.name] = None
            continue
        M = frame.placement.actInv(go.placement)  # T_{link, geometry}
        verts = np.asarray(geom.vertices(), dtype=float).reshape(-1, 3) @ M.rotation.T + M.translation
        entry.append((verts, _triangles(geom)))
    result: dict[str, LinkMesh | None] = {}
    for name in [n for n in link_names(robot) if n in out] + [n for n in out if n not in link_names(robot)]:
        parts = out[name]
        if parts is None:
            result[name] = None
            continue
        verts, tris, base = [], [], 0
        for v, t in parts:
            verts.append(v)
            tris.append(t + base)
            base += len(v)
        tri = np.vstack(tris)
        edges = np.sort(np.vstack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        result[name] = LinkMesh(np.vstack(verts), np.unique(edges, axis=0))
    return result


def slab_points(mesh: LinkMesh, axis: np.ndarray, lo: float, hi: float) -> np.ndarray:
    r"""The corners of every triangle clipped to the slab :math:`lo \le u^\top x \le hi`, (m, 3) [m].

    The vertices inside the slab and the crossings of the edges with the planes
    :math:`u^\top x = lo` and :math:`u^\top x = hi` (``-inf``/``inf``: no plane).
    """
    v, e = mesh.vertices, mesh.edges
    t = v @ axis
    pts = [v[(t >= lo) & (t <= hi)]]
    t0, t1 = t[e[:, 0]], t[e[:, 1]]
    for c in (lo, hi):
        if not np.isfinite(c):
            continue
        cross = (t0 - c) * (t1 - c) < 0.0
        if cross.any():
            s = (c - t0[cross]) / (t1[cross] - t0[cross])
            p0, p1 = v[e[cross, 0]], v[e[cross, 1]]
            pts.append(p0 + s[:, None] * (p1 - p0))
    return np.vstack(pts)


def _fit(points, axes, refine):
    if len(points) == 0:
        return None
    a, b, r = fit_capsule(points, None, axes, refine=refine)
    r = max(r, 1e-9)
    return a, b, r, capsule_volume(a, b, r)


def _quick_volume(points: np.ndarray, axis: np.ndarray) -> float:
    """Volume [m³] of the smallest capsule on the best of ``axis`` and the principal axes
    through the centroid (no hull reduction, no refinement: the search's estimate)."""
    if len(points) == 0:
        return 0.0
    centroid = points.mean(axis=0)
    zeros = np.zeros(len(points))
    best = np.inf
    for u in (axis, *np.linalg.svd(points - centroid, full_matrices=False)[2]):
        e1, e2 = _perpendicular_basis(u)
        side = points @ np.column_stack([e1, e2])  # coordinates across the axis
        mid = 0.5 * (side.min(axis=0) + side.max(axis=0))
        origin = centroid + (mid - centroid @ np.column_stack([e1, e2])) @ np.vstack([e1, e2])
        best = min(best, _capsule_on_line(points, zeros, centroid, u)[3], _capsule_on_line(points, zeros, origin, u)[3])
    return best


def slab_partitions(mesh: LinkMesh, axis: np.ndarray, positions: np.ndarray, volume,
                    k_max: int) -> list[tuple[float, np.ndarray]]:
    r"""Per k = 1..``k_max``: (total volume, cut positions) of the best k-slab partition of ``mesh``.

    Slabs along ``axis`` between cuts taken from ``positions`` (increasing, the first
    :math:`-\infty` and the last :math:`+\infty`), each slab costing
    ``volume(points)`` of its part (:func:`slab_points`); dynamic programming over the
    cut pairs. ``k_max`` is capped at ``len(positions) - 1``.
    """
    n = len(positions)
    vol = np.full((n, n), np.inf)
    for i in range(n):
        for j in range(i + 1, n):
            vol[i, j] = volume(slab_points(mesh, axis, positions[i], positions[j]))
    K = min(int(k_max), n - 1)
    best = np.full((K + 1, n), np.inf)
    arg = np.zeros((K + 1, n), dtype=int)
    best[1] = vol[0]
    for k in range(2, K + 1):
        for j in range(k, n):
            tot = best[k - 1, :j] + vol[:j, j]
            arg[k, j] = int(np.argmin(tot))
            best[k, j] = tot[arg[k, j]]
    out = []
    for k in range(1, K + 1):
        idx, j = [n - 1], n - 1
        for kk in range(k, 1, -1):
            j = arg[kk, j]
            idx.append(j)
        idx.append(0)
        out.append((float(best[k, n - 1]), positions[idx[::-1]]))
    return out


def _best_partitions(mesh: LinkMesh, axis: np.ndarray, settings: LinkFitSettings):
    """Per k = 1..K: (volume, cut positions) of the best k-slab partition on the grid."""
    t = mesh.vertices @ axis
    g = int(settings.grid)
    cuts = np.concatenate([[-np.inf], t.min() + (t.max() - t.min()) * np.arange(1, g + 1) / (g + 1), [np.inf]])
    return slab_partitions(mesh, axis, cuts, lambda points: _quick_volume(points, axis),
                           settings.max_capsules)


def _hull_volume(points: np.ndarray) -> float:
    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):
        return float("nan")


def fit_link(link: str, mesh: LinkMesh | None, balls, settings: LinkFitSettings = LinkFitSettings(),
             per_geometry=()) -> LinkFit:
    """Capsules of one link (module docstring).

    Args:
        link: Link name.
        mesh: Its meshes (:func:`link_meshes`), or ``None`` for primitive geometry.
        balls: ``(centres, radii, axes)`` of the whole link (:func:`link_geometry_points`).
        settings: Split settings.
        per_geometry: For primitive links, ``(centres, radii, axes)`` per geometry.
    """
    pts, rad, axes = balls
    a, b, r = fit_capsule(pts, rad, axes)
    r = max(r, 1e-9)
    single = [(a, b, r)]
    single_volume = capsule_volume(a, b, r)
    hull_volume = _hull_volume(mesh.vertices if mesh is not None else pts[rad == 0.0]) if len(pts) >= 4 else float("nan")
    gain = 1.0 / (1.0 - float(settings.min_gain))
    chosen, chosen_score = single, single_volume
    if mesh is not None and int(settings.max_capsules) > 1:
        u_single = (b - a) / np.linalg.norm(b - a) if np.linalg.norm(b - a) > 1e-9 else None
        centred = mesh.vertices - mesh.vertices.mean(axis=0)
        candidates = [] if u_single is None else [u_single]
        for u in np.linalg.svd(centred, full_matrices=False)[2]:
            if all(abs(u @ w) < 0.999 for w in candidates):
                candidates.append(u)
        options = []
        for u in candidates:
            parts = _best_partitions(mesh, u, settings)
            base = parts[0][0]
            for k, (volume, cuts) in enumerate(parts, start=1):
                options.append((volume / base * single_volume * gain ** (k - 1), k, u, cuts))
        score, k, u, cuts = min(options, key=lambda o: o[0])
        if k > 1:
            caps = []
            for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
                fit = _fit(slab_points(mesh, u, lo, hi), [u], refine=True)
                if fit is not None:
                    caps.append(fit[:3])
            volume = sum(capsule_volume(*c) for c in caps)
            if volume * gain ** (len(caps) - 1) < chosen_score:
                chosen, chosen_score = caps, volume
    elif len(per_geometry) > 1 and settings.split_primitives:
        caps = []
        for p, rr, ax in per_geometry:
            ca, cb, cr = fit_capsule(p, rr, ax)
            caps.append((ca, cb, max(cr, 1e-9)))
        volume = sum(capsule_volume(*c) for c in caps)
        if volume * gain ** (len(caps) - 1) < chosen_score:
            chosen = caps
    capsules = tuple(Capsule(ca, cb, cr, frame=link, name=f"{link}#{k}") for k, (ca, cb, cr) in enumerate(chosen))
    total = float(sum(capsule_volume(c.a, c.b, c.radius) for c in capsules))
    return LinkFit(link, capsules, hull_volume, total, single_volume, mesh is not None)


def _per_geometry_balls(robot, geometry_model) -> dict[str, list]:
    out: dict[str, list] = {}
    for go in geometry_model.geometryObjects:
        frame = robot.model.frames[go.parentFrame]
        M = frame.placement.actInv(go.placement)
        centres, radii, axis = _local_balls(go.geometry)
        axes = [] if axis is None else [M.rotation @ axis]
        out.setdefault(frame.name, []).append((centres @ M.rotation.T + M.translation, radii, axes))
    return out


def geometry_key(robot, geometry_model: pin.GeometryModel, settings: LinkFitSettings) -> str:
    """SHA-256 of everything the fit depends on: the geometry (kind, size, vertices,
    triangles, placement in its link) and the settings."""
    h = hashlib.sha256(repr((settings.max_capsules, settings.min_gain, settings.grid, settings.split_primitives, 1)).encode())
    for go in geometry_model.geometryObjects:
        frame = robot.model.frames[go.parentFrame]
        h.update(frame.name.encode())
        h.update(np.asarray(frame.placement.actInv(go.placement).homogeneous).tobytes())
        geom = go.geometry
        h.update(type(geom).__name__.encode())
        if isinstance(geom, coal.BVHModelBase):
            h.update(np.asarray(geom.vertices(), dtype=float).tobytes())
            h.update(_triangles(geom).tobytes())
        else:
            centres, radii, _ = _local_balls(geom)
            h.update(np.asarray(centres).tobytes())
            h.update(np.asarray(radii).tobytes())
    return h.hexdigest()


_CACHE: dict[str, tuple[LinkFit, ...]] = {}


def _fit_to_json(fit: LinkFit) -> dict:
    return {"link": fit.link, "hull": fit.hull_volume, "volume": fit.capsule_volume, "single": fit.single_volume,
            "meshes": fit.meshes, "capsules": [[c.a.tolist(), c.b.tolist(), c.radius] for c in fit.capsules]}


def _fit_from_json(entry: dict) -> LinkFit:
    link = entry["link"]
    caps = tuple(Capsule(a, b, r, frame=link, name=f"{link}#{k}") for k, (a, b, r) in enumerate(entry["capsules"]))
    return LinkFit(link, caps, float(entry["hull"]), float(entry["volume"]), float(entry["single"]),
                   bool(entry["meshes"]))


def fit_robot_links(robot, geometry_model: pin.GeometryModel,
                    settings: LinkFitSettings = LinkFitSettings()) -> tuple[LinkFit, ...]:
    """:func:`fit_link` for every link with collision geometry, base to tip.

    Cached per geometry and settings (:func:`geometry_key`), in the process and
    on disk (:mod:`calib_oed.feasibility.fit_cache`), so a scene loaded again, in
    this process or a new one, does not fit again.
    """
    key = geometry_key(robot, geometry_model, settings)
    if key not in _CACHE:
        cached = fit_cache.load("link_fit", key)
        if cached is not None:
            _CACHE[key] = tuple(_fit_from_json(entry) for entry in cached)
    if key not in _CACHE:
        balls = link_geometry_points(robot, geometry_model)
        meshes = link_meshes(robot, geometry_model)
        per_geom = _per_geometry_balls(robot, geometry_model)
        _CACHE[key] = tuple(
            fit_link(link, meshes.get(link), balls[link], settings, per_geom.get(link, ())) for link in balls
        )
        fit_cache.store("link_fit", key, [_fit_to_json(f) for f in _CACHE[key]])
    return _CACHE[key]


def fit_link_capsules(robot, geometry_model: pin.GeometryModel | None = None, margin: float = 0.0,
                      settings: LinkFitSettings = LinkFitSettings()) -> tuple[Capsule, ...]:
    """The capsules of every link (:func:`fit_robot_links`), inflated by ``margin`` [m].

    Raises:
        RobotLoadError: the collision meshes cannot be loaded.
        ValueError: ``margin`` is negative or not finite.
    """
    margin = check_margin(margin)
    geom = load_collision_model(robot) if geometry_model is None else geometry_model
    return tuple(c.inflated(margin) if margin else c for fit in fit_robot_links(robot, geom, settings)
                 for c in fit.capsules)


def fitted_robot_capsules(robot, settings) -> tuple[Capsule, ...]:
    """``settings.robot_capsules`` validated (:func:`capsules_from_table`), or the
    capsules of :func:`fit_link_capsules` inflated by ``settings.capsule_margin``."""
    if settings.robot_capsules is not None:
        return capsules_from_table(robot, settings.robot_capsules)
    return fit_link_capsules(robot, margin=settings.capsule_margin)
