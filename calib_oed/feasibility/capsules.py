r"""Robot link capsules: fitted to the URDF collision geometry, or given as a table.

Every link with collision geometry gets one capsule that encloses all of it. The
geometry of a link is first reduced to a finite set of balls
:math:`\{(p_v, \rho_v)\}` in the link frame whose union's convex hull contains the
geometry:

- mesh: every vertex (:math:`\rho_v = 0`), as loaded by coal with the URDF scale;
- box: its 8 corners;
- cylinder of radius :math:`\rho`, half-length :math:`h`: the vertices of the prism
  over the regular :math:`N`-gon *circumscribed* about its end circles, circumradius
  :math:`\rho / \cos(\pi / N)`, :math:`N = 64` (radius overestimated by 0.12 %);
- cone: the circumscribed :math:`N`-gon of its base and its apex;
- sphere: one ball :math:`(c, \rho)`; capsule: the balls at its two end centres;
- any other coal shape: the corners of its local axis-aligned bounding box.

A capsule is convex, so a capsule containing every ball contains their convex hull
and therefore the geometry. For an axis line :math:`o + t u` (:math:`\|u\| = 1`),
with :math:`t_v = u^\top (p_v - o)` and :math:`d_v` the distance of :math:`p_v` to
the line, the smallest radius is :math:`r = \max_v (d_v + \rho_v)`. Ball :math:`v`
lies in the capsule iff the segment :math:`[a, b]` meets
:math:`[t_v - s_v, t_v + s_v]`, :math:`s_v = \sqrt{(r - \rho_v)^2 - d_v^2}`, so the
shortest segment is

.. math::

    a = \min_v (t_v + s_v), \qquad b = \max_v (t_v - s_v),

when :math:`a \le b`. Otherwise all intervals share :math:`[b, a]` and a sphere
centred on the axis in :math:`[b, a]` (near the centre minimising its radius) is used.
Plain points inside the convex hull of the others are dropped first. The axis
starts as whichever of the three principal axes of the points (SVD, through their
centroid) and the primitives' own axes gives the smallest capsule, and is then
refined by a Nelder-Mead search over its direction and offset minimising the
capsule volume :math:`\pi r^2 \|b - a\| + \tfrac{4}{3} \pi r^3`. Enclosure holds
for every axis, so the search only makes capsules tighter.

All lengths in [m].
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import coal
import numpy as np
import pinocchio as pin
from scipy.optimize import minimize
from scipy.spatial import ConvexHull, QhullError

from calib_oed.exceptions import RobotLoadError, UnknownLinkError
from calib_oed.feasibility.shapes import Capsule, FeasibilitySettings
from calib_oed.model.robot import Robot

__all__ = [
    "capsules_from_table", "fit_capsule", "fit_capsules", "link_geometry_points",
    "link_names", "load_collision_model", "robot_capsules",
]  # fmt: skip

POLYGON_SIDES = 64  # sides of the polygon circumscribed about cylinder and cone circles


def load_collision_model(robot: Robot) -> pin.GeometryModel:
    """The URDF's collision geometry attached to ``robot.model``.

    The geometry is built directly on the reduced serial model ``robot.model``:
    every link of the URDF, including those behind locked joints (gripper
    fingers), has its body frame there, placed at the locked joint values, so
    ``parentJoint`` and ``parentFrame`` index ``robot.model``. Meshes are loaded
    by coal as BVH models, with the URDF ``scale`` applied.

    Raises:
        RobotLoadError: a mesh cannot be found or read; the message names the
            folders searched (``robot.package_dirs``).
    """
    where = str(robot.urdf_path or robot.name)
    try:
        geom = pin.buildGeomFromUrdfString(
            robot.model, robot.urdf_text, pin.GeometryType.COLLISION,
            package_dirs=list(robot.package_dirs),
        )  # fmt: skip
    except (ValueError, RuntimeError) as exc:
        raise RobotLoadError(
            f"{where}: cannot load the collision geometry ({exc}); package:// and relative "
            f"mesh paths were searched in {list(robot.package_dirs)}; give the folders holding "
            "the mesh packages as robot.package_dirs in the scene file, or "
            "load_robot(..., package_dirs=[...]) in Python"
        ) from exc
    for go in geom.geometryObjects:
        frame = robot.model.frames[go.parentFrame] if go.parentFrame < robot.model.nframes else None
        if go.geometry is None or frame is None or frame.parentJoint != go.parentJoint:
            raise RobotLoadError(
                f"{where}: collision geometry {go.name!r} could not be attached to the robot model"
            )
    return geom


def link_names(robot: Robot) -> list[str]:
    """Names of the links (Pinocchio body frames) of ``robot.model``, base to tip."""
    return list(dict.fromkeys(f.name for f in robot.model.frames if f.type == pin.FrameType.BODY))


def _polygon(radius: float, z: float) -> np.ndarray:
    """Vertices of the regular polygon circumscribed about a circle at height ``z``."""
    angles = 2.0 * np.pi * np.arange(POLYGON_SIDES) / POLYGON_SIDES
    big = radius / np.cos(np.pi / POLYGON_SIDES)
    return np.column_stack([big * np.cos(angles), big * np.sin(angles), np.full_like(angles, z)])


def _local_balls(geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Balls ``(centres (m, 3), radii (m,))`` whose hull contains ``geometry``, and its axis."""
    z = np.array([0.0, 0.0, 1.0])
    if isinstance(geometry, coal.BVHModelBase):
        pts = np.asarray(geometry.vertices(), dtype=float).reshape(-1, 3)
        return pts, np.zeros(len(pts)), None
    if isinstance(geometry, coal.Box):
        h = np.asarray(geometry.halfSide, dtype=float)
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        return corners * h, np.zeros(8), None
    if isinstance(geometry, coal.Sphere):
        return np.zeros((1, 3)), np.array([float(geometry.radius)]), None
    if isinstance(geometry, coal.Capsule):
        h = float(geometry.halfLength)
        return np.array([[0, 0, -h], [0, 0, h]], float), np.full(2, float(geometry.radius)), z
    if isinstance(geometry, coal.Cylinder):
        r, h = float(geometry.radius), float(geometry.halfLength)
        pts = np.vstack([_polygon(r, -h), _polygon(r, h)])
        return pts, np.zeros(len(pts)), z
    if isinstance(geometry, coal.Cone):
        r, h = float(geometry.radius), float(geometry.halfLength)
        pts = np.vstack([_polygon(r, -h), [[0.0, 0.0, h]]])
        return pts, np.zeros(len(pts)), z
    geometry.computeLocalAABB()
    lo, hi = np.asarray(geometry.aabb_local.min_), np.asarray(geometry.aabb_local.max_)
    corners = np.array(
        [[x, y, w] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for w in (lo[2], hi[2])]
    )
    return corners, np.zeros(8), None


def link_geometry_points(
    robot: Robot, geometry_model: pin.GeometryModel | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray, list[np.ndarray]]]:
    """The enclosing balls of each link's collision geometry, in the link frame.

    Returns:
        ``{link: (centres (m, 3) [m], radii (m,) [m], axes)}`` for links with
        geometry, in model frame order; ``axes`` holds the unit axis (link frame)
        of each cylinder, cone or capsule of the link.
    """
    geom = load_collision_model(robot) if geometry_model is None else geometry_model
    out: dict[str, tuple[list, list, list]] = {}
    for go in geom.geometryObjects:
        frame = robot.model.frames[go.parentFrame]
        link_from_geom = frame.placement.actInv(go.placement)  # T_{link, geometry}
        centres, radii, axis = _local_balls(go.geometry)
        R, t = link_from_geom.rotation, link_from_geom.translation
        entry = out.setdefault(frame.name, ([], [], []))
        entry[0].append(centres @ R.T + t)
        entry[1].append(radii)
        if axis is not None:
            entry[2].append(R @ axis)
    order = {name: k for k, name in enumerate(link_names(robot))}
    return {
        name: (np.vstack(c), np.concatenate(r), ax)
        for name, (c, r, ax) in sorted(out.items(), key=lambda kv: order.get(kv[0], len(order)))
    }


def _capsule_on_line(points, radii, origin, axis):
    """Smallest capsule with its segment on the line ``origin + t axis``: (a, b, r, volume)."""
    axis = axis / np.sqrt(axis @ axis)
    rel = points - origin
    t = rel @ axis
    d2 = np.maximum((rel * rel).sum(axis=1) - t * t, 0.0)
    d = np.sqrt(d2)
    r = float((d + radii).max())
    s = np.sqrt(np.maximum((r - radii) ** 2 - d2, 0.0))
    lo, hi = float((t + s).min()), float((t - s).max())
    if lo <= hi:
        a, b = origin + lo * axis, origin + hi * axis
        return a, b, r, np.pi * r**2 * (hi - lo) + 4.0 / 3.0 * np.pi * r**3

    # Every ball reaches [hi, lo] on the axis: a sphere centred there encloses them all.
    # Its radius is convex in the centre; two grid passes find a near-best centre, and
    # the radius is exact for the centre chosen.
    def radii_at(cs):
        return np.max(np.sqrt((cs[:, None] - t) ** 2 + d**2) + radii, axis=1)

    cs = np.linspace(hi, lo, 17)
    k = int(np.argmin(radii_at(cs)))
    step = (lo - hi) / 16.0
    cs = np.linspace(max(hi, cs[k] - step), min(lo, cs[k] + step), 17)
    rs = radii_at(cs)
    k = int(np.argmin(rs))
    r = float(rs[k])
    centre = origin + cs[k] * axis
    return centre, centre.copy(), r, 4.0 / 3.0 * np.pi * r**3


def _hull_reduced(points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop plain points inside the convex hull of the plain points (a convex capsule
    containing the hull's vertices contains them all); balls are kept."""
    plain = radii == 0.0
    if plain.sum() < 5:
        return points, radii
    try:
        hull = ConvexHull(points[plain])
    except QhullError:  # flat or degenerate point sets: keep every point
        return points, radii
    keep = np.vstack([points[plain][hull.vertices], points[~plain]])
    return keep, np.concatenate([np.zeros(len(hull.vertices)), radii[~plain]])


def _perpendicular_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def fit_capsule(
    points: np.ndarray,
    radii: np.ndarray | None = None,
    axes: Sequence[np.ndarray] = (),
    refine: bool = True,
) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule enclosing the balls ``(points, radii)`` (module docstring).

    Args:
        points: Ball centres (m, 3) [m].
        radii: Ball radii (m,) [m]; zeros (plain points) by default.
        axes: Extra candidate axis directions (a primitive's own axis).
        refine: Improve the best candidate axis by a Nelder-Mead volume search.

    Returns:
        ``(a, b, radius)``: end points (3,) [m] and radius [m]; ``a == b`` for a sphere.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    rad = np.zeros(len(pts)) if radii is None else np.asarray(radii, dtype=float).reshape(-1)
    pts, rad = _hull_reduced(pts, rad)
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    candidates = [*vt, *(np.asarray(ax, dtype=float) for ax in axes)]
    fits = [(_capsule_on_line(pts, rad, centroid, u), u) for u in candidates]
    (a, b, r, volume), u0 = min(fits, key=lambda f: f[0][3])
    if refine and volume > 0.0:
        e1, e2 = _perpendicular_basis(u0 / np.linalg.norm(u0))
        scale = max(r, 1e-6)

        def line(x):
            return centroid + scale * (x[2] * e1 + x[3] * e2), u0 + x[0] * e1 + x[1] * e2

        def objective(x):
            return _capsule_on_line(pts, rad, *line(x))[3] / volume

        simplex = np.vstack([np.zeros(4), 0.05 * np.eye(4)])
        res = minimize(objective, np.zeros(4), method="Nelder-Mead",
                       options={"initial_simplex": simplex, "xatol": 1e-5, "fatol": 1e-6,
                                "maxiter": 1000})  # fmt: skip
        if res.fun < 1.0:
            a, b, r, _ = _capsule_on_line(pts, rad, *line(res.x))
    return np.asarray(a), np.asarray(b), float(r)


def check_margin(margin) -> float:
    """A capsule inflation margin [m] as a float.

    Raises:
        ValueError: ``margin`` is negative or not finite.
    """
    margin = float(margin)
    if not (np.isfinite(margin) and margin >= 0.0):
        raise ValueError(f"capsule margin must be a finite length >= 0 [m], got {margin!r}")
    return margin


def fit_capsules(
    robot: Robot, geometry_model: pin.GeometryModel | None = None, margin: float = 0.0
) -> tuple[Capsule, ...]:
    """One capsule per link enclosing its collision geometry, inflated by ``margin`` [m].

    Capsule ``frame`` is the link name (the body frame of ``robot.model``, fixed
    links of the base included), ``name`` is ``"<link>#0"``, end points are in
    the link frame. Links without collision geometry get no capsule.

    Raises:
        RobotLoadError: the collision meshes cannot be loaded.
        ValueError: ``margin`` is negative or not finite.
    """
    margin = check_margin(margin)
    out = []
    for link, (pts, rad, axes) in link_geometry_points(robot, geometry_model).items():
        a, b, r = fit_capsule(pts, rad, axes)
        r = max(r, 1e-9)  # a degenerate geometry (one point, a segment) still gets a capsule
        out.append(Capsule(a, b, r + margin, frame=link, name=f"{link}#0"))
    return tuple(out)


def capsules_from_table(
    robot: Robot, table: Sequence[Capsule | Mapping[str, object]]
) -> tuple[Capsule, ...]:
    """Validate a user capsule table against the links of ``robot.model``.

    Args:
        table: :class:`Capsule` records with ``frame`` = link name, or mappings
            ``{"link", "a", "b", "radius", "name" (optional)}`` in [m], end points
            in the link frame. Unnamed capsules are called ``"<link>#<k>"``.

    Raises:
        UnknownLinkError: a capsule names a link the robot does not have (or none);
            the error lists the links.
        ValueError: a table entry misses a key or has a bad radius or shape.
    """
    valid = link_names(robot)
    counts: dict[str, int] = {}
    out = []
    for k, entry in enumerate(table):
        if isinstance(entry, Capsule):
            link, cap = entry.frame, entry
        elif isinstance(entry, Mapping):
            missing = [key for key in ("link", "a", "b", "radius") if key not in entry]
            unknown = sorted(set(entry) - {"link", "a", "b", "radius", "name"})
            if missing or unknown:
                raise ValueError(
                    f"capsule table entry {k}: missing keys {missing}, unknown keys {unknown}; "
                    "expected {link, a, b, radius, name (optional)} in metres"
                )
            link, cap = entry["link"], None
        else:
            raise ValueError(
                f"capsule table entry {k}: expected a Capsule or a mapping, got {type(entry).__name__}"
            )
        if link not in valid:
            raise UnknownLinkError(str(link), valid)
        n = counts.get(link, 0)
        counts[link] = n + 1
        if cap is None:
            name = str(entry.get("name") or f"{link}#{n}")
            cap = Capsule(entry["a"], entry["b"], entry["radius"], frame=link, name=name)
        elif not cap.name:
            cap = Capsule(cap.a, cap.b, cap.radius, frame=link, name=f"{link}#{n}")
        out.append(cap)
    return tuple(out)


def robot_capsules(robot: Robot, settings: FeasibilitySettings) -> tuple[Capsule, ...]:
    """``settings.robot_capsules`` validated, or one capsule per link fitted with
    ``settings.capsule_margin``. The feasibility model uses
    :func:`calib_oed.feasibility.link_fit.fitted_robot_capsules` (several per mesh link)."""
    if settings.robot_capsules is not None:
        return capsules_from_table(robot, settings.robot_capsules)
    return fit_capsules(robot, margin=settings.capsule_margin)
