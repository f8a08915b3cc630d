r"""Geometric primitives and settings of the feasibility model (records only).

A :class:`Capsule` is the set of points within ``radius`` of the segment
:math:`[a, b]`; its end points are expressed in the frame of a robot link
(``frame`` = link name) or in the world (``frame is None``, a cell
obstacle; ``a == b`` is a sphere). A :class:`HalfSpace` is the free side
:math:`\{x \in \mathbb{R}^3 : n^\top x \ge c\}` of a plane fixed in the world
(floor :math:`z \ge z_0`: ``normal=(0, 0, 1), offset=z0``). The solid obstacles
:class:`Box`, :class:`Cylinder` and :class:`MeshObstacle` (a convex hull) are
placed in the world by a rotation :math:`R_{W,O}` and a centre; their
distances are in :mod:`calib_oed.feasibility.solids`. Every obstacle may name
robot links it is never checked against (``ignore_links``: the floor the base
stands on).

All lengths in [m], angles in [rad].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.values import finite_vector

#: Capsule fits to the URDF collision meshes (:attr:`FeasibilitySettings.link_fit`).
LINK_FITS = ("single", "hulls")


def _links(value, what: str) -> tuple[str, ...]:
    links = (value,) if isinstance(value, str) else tuple(value)
    if not all(isinstance(v, str) for v in links):
        raise ValueError(f"{what}: ignore_links must be link names, got {value!r}")
    return links


def _rotation(value, what: str) -> np.ndarray:
    rot = np.array(value, dtype=float)
    if rot.shape != (3, 3):
        raise ShapeError(what, "(3, 3)", rot.shape)
    if not np.all(np.isfinite(rot)):
        raise NonFiniteError(what)
    if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-9 or np.linalg.det(rot) < 0:
        raise ValueError(f"{what} must be a rotation matrix (orthonormal, det +1)")
    rot.setflags(write=False)
    return rot


def _positive(value, what: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise ValueError(f"{what} must be > 0 [m], got {value!r}")
    return v


#: How a reflector is aimed: its axis fixed on the tool, or turned towards the tracker by hand.
AIMS = ("fixed", "manual")


@dataclass(frozen=True, eq=False)
class Capsule:
    """A capsule: segment ``a``–``b`` [m] swept by a sphere of ``radius`` [m].

    Attributes:
        a: First end point, in ``frame`` [m], (3,).
        b: Second end point, in ``frame`` [m], (3,) (``a == b`` is a sphere).
        radius: Radius [m], > 0.
        frame: Name of the robot link (URDF link = Pinocchio body frame) the
            end points are fixed in, or ``None`` for a world-fixed obstacle.
        name: Label used in reports (``"link_2#0"``, ``"car_front"``).
        ignore_links: Robot links an obstacle capsule is not checked against.
    """

    a: np.ndarray
    b: np.ndarray
    radius: float
    frame: str | None = None
    name: str = ""
    ignore_links: tuple[str, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "a", finite_vector(self.a, f"capsule {self.name!r} a", 3))
        object.__setattr__(self, "b", finite_vector(self.b, f"capsule {self.name!r} b", 3))
        r = float(self.radius)
        if not np.isfinite(r) or r <= 0.0:
            raise ValueError(f"capsule {self.name!r}: radius must be > 0 [m], got {self.radius!r}")
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "ignore_links", _links(self.ignore_links, f"capsule {self.name!r}"))

    @property
    def length(self) -> float:
        """Length of the axis segment [m]."""
        return float(np.linalg.norm(self.b - self.a))

    def inflated(self, margin: float) -> Capsule:
        """The same capsule with its radius grown by ``margin`` [m]."""
        return Capsule(self.a, self.b, self.radius + margin, self.frame, self.name, self.ignore_links)


@dataclass(frozen=True, eq=False)
class HalfSpace:
    r"""World-fixed free half-space :math:`n^\top x \ge c`.

    Attributes:
        normal: Normal :math:`n` pointing into the free side, (3,). Normalised on
            construction together with ``offset``, so the half-space is unchanged.
        offset: :math:`c` [m]: the plane is :math:`n^\top x = c` (after normalisation,
            its signed distance from the origin).
        name: Label used in reports (``"floor"``, ``"wall"``).
        ignore_links: Robot links not checked against it.
    """

    normal: np.ndarray
    offset: float
    name: str = ""
    ignore_links: tuple[str, ...] = ()

    def __post_init__(self):
        n = np.array(finite_vector(self.normal, f"half-space {self.name!r} normal", 3))
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            raise ValueError(f"half-space {self.name!r}: normal must be non-zero")
        n = n / norm
        n.setflags(write=False)
        object.__setattr__(self, "normal", n)
        # n^T x >= c is the same half-space as (n/|n|)^T x >= c/|n|
        object.__setattr__(self, "offset", float(self.offset) / norm)
        object.__setattr__(self, "ignore_links", _links(self.ignore_links, f"half-space {self.name!r}"))

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance [m] of points (..., 3) to the plane, positive on the free side."""
        return np.asarray(points) @ self.normal - self.offset


def _check_placement(solid, kind: str) -> str:
    """Check and set a placed solid's ``center``, ``rotation`` and ``ignore_links`` (frozen record);
    returns its label in messages, ``kind`` and name (``box 'car'``)."""
    what = f"{kind} {solid.name!r}"
    object.__setattr__(solid, "center", finite_vector(solid.center, f"{what} center", 3))
    object.__setattr__(solid, "rotation", _rotation(solid.rotation, f"{what} rotation"))
    object.__setattr__(solid, "ignore_links", _links(solid.ignore_links, what))
    return what


@dataclass(frozen=True, eq=False)
class Box:
    r"""A world-fixed box :math:`\{x : |R^\top(x - c)|_i \le h_i\}`, :math:`h` = ``size``/2.

    Attributes:
        center: Centre :math:`c` in the world [m], (3,).
        size: Side lengths along the box's own x, y, z axes [m], (3,), > 0.
        rotation: :math:`R_{W,O}`, the box axes in the world, (3, 3).
        name: Label used in reports (``"car"``).
        ignore_links: Robot links not checked against it.
    """

    center: np.ndarray
    size: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    name: str = ""
    ignore_links: tuple[str, ...] = ()

    def __post_init__(self):
        what = _check_placement(self, "box")
        object.__setattr__(self, "size", finite_vector(self.size, f"{what} size", 3))
        if np.any(self.size <= 0):
            raise ValueError(f"{what}: size must be > 0 [m] along x, y, z, got {self.size.tolist()}")

    @property
    def half(self) -> np.ndarray:
        """Half side lengths :math:`h` [m], (3,)."""
        return 0.5 * self.size


@dataclass(frozen=True, eq=False)
class Cylinder:
    """A world-fixed solid cylinder, its axis the local z axis through ``center``.

    Attributes:
        center: Centre of the axis segment in the world [m], (3,).
        radius: Radius [m], > 0.
        length: Length along the axis [m], > 0.
        rotation: :math:`R_{W,O}` (the axis is its third column), (3, 3).
        name: Label used in reports.
        ignore_links: Robot links not checked against it.
    """

    center: np.ndarray
    radius: float
    length: float
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    name: str = ""
    ignore_links: tuple[str, ...] = ()

    def __post_init__(self):
        what = _check_placement(self, "cylinder")
        object.__setattr__(self, "radius", _positive(self.radius, f"{what}: radius"))
        object.__setattr__(self, "length", _positive(self.length, f"{what}: length"))


@dataclass(frozen=True, eq=False)
class MeshObstacle:
    """A world-fixed mesh obstacle, checked as the convex hull of its vertices.

    Attributes:
        vertices: Mesh vertices in the world [m], (V, 3), V >= 4 (scale and
            placement already applied).
        name: Label used in reports.
        ignore_links: Robot links not checked against it.
        source: The mesh file it was read from (for reports), or ``""``.
    """

    vertices: np.ndarray
    name: str = ""
    ignore_links: tuple[str, ...] = ()
    source: str = ""

    def __post_init__(self):
        what = f"mesh {self.name!r}"
        v = np.array(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 4:
            raise ShapeError(f"{what} vertices", "(V >= 4, 3)", v.shape)
        if not np.all(np.isfinite(v)):
            raise NonFiniteError(f"{what} vertices")
        if np.linalg.matrix_rank(v - v.mean(axis=0), tol=1e-9) < 3:
            raise ValueError(f"{what}: the vertices are flat (no volume); a mesh obstacle needs a solid")
        v.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "ignore_links", _links(self.ignore_links, what))


#: A solid obstacle: distances by :mod:`calib_oed.feasibility.solids`.
Solid = Box | Cylinder | MeshObstacle


@dataclass(frozen=True, eq=False)
class Cell:
    """The world-fixed obstacles of a cell.

    Attributes:
        capsules: Obstacle capsules (``frame is None``) and spheres (``a == b``).
        halfspaces: Free half-spaces (floor, walls).
        boxes: Boxes (car bodies, tables, fixtures).
        cylinders: Cylinders (columns, tracker stands).
        meshes: Mesh obstacles (convex hulls).
    """

    capsules: tuple[Capsule, ...] = ()
    halfspaces: tuple[HalfSpace, ...] = ()
    boxes: tuple[Box, ...] = ()
    cylinders: tuple[Cylinder, ...] = ()
    meshes: tuple[MeshObstacle, ...] = ()

    def __post_init__(self):
        for c in self.capsules:
            if c.frame is not None:
                raise ValueError(f"cell capsule {c.name!r} must be world-fixed (frame=None), got frame {c.frame!r}")

    @property
    def solids(self) -> tuple[Solid, ...]:
        """Boxes, cylinders and meshes, in this order (the solid rows' order)."""
        return (*self.boxes, *self.cylinders, *self.meshes)


@dataclass(frozen=True)
class Margins:
    """Safety margins every constraint keeps (defaults a cautious user accepts).

    Attributes:
        clearance: Extra distance [m] between capsules, to obstacles and to the beam (10 mm).
        incidence: Angle [rad] kept below the incidence limit (2°).
        joint: Angle [rad] (or length [m] for prismatic joints) kept inside the joint limits (1°).
    """

    clearance: float = 0.010
    incidence: float = float(np.deg2rad(2.0))
    joint: float = float(np.deg2rad(1.0))


@dataclass(frozen=True, eq=False)
class FeasibilitySettings:
    """What makes a measurement configuration executable.

    Attributes:
        incidence_limit: Largest angle [rad] between the reflector axis (its
            ``normal``, default tool z) and the direction to the tracker (30°, paper eq. 4).
        beam_radius: Radius [m] of the laser-beam capsule (5 mm).
        reflector_radius: Radius [m] of the capsule from the tool frame origin
            to each reflector (stem and SMR; 19.05 mm = a 1.5" SMR).
        capsule_margin: Inflation [m] of capsules fitted to the URDF collision geometry.
        margins: Safety margins.
        excluded_pairs: Link-name pairs never checked against each other.
        robot_capsules: A capsule table (link frames) replacing the automatic fit,
            or ``None`` to fit capsules to the URDF collision geometry.
        prune_samples: Size of the seeded sampling pass that drops pairs which
            cannot come close within the joint limits.
        prune_seed: Seed of that pass.
        prune_distance: A pair is dropped if its clearance stays above this [m]
            over the whole sampling pass.
        link_fit: How the link geometry is modelled (:data:`LINK_FITS`): ``"hulls"``
            (default) up to three capsules per mesh link
            (:func:`calib_oed.feasibility.link_fit.fit_link_capsules`), the self pairs
            decided on the meshes (:mod:`calib_oed.feasibility.mesh_pairs`), and the
            self pairs of links at most three joints apart checked on convex pieces
            of their geometry (:mod:`calib_oed.feasibility.hulls`): 92-98 % of the
            mesh-feasible poses accepted, none of the infeasible (docs/feasibility.md).
            ``"single"``: one capsule per link (21-25 % accepted). With every
            fit, a link pair whose fitted capsules are never separated by the margin
            in the pruning pass is checked on convex pieces too.
        joint_window: The joint ranges the design may use
            (:mod:`calib_oed.feasibility.window`): ``"one_turn"`` (default) limits a
            revolute joint with more than one turn of range to one turn about home,
            ``"full"`` keeps every range.
    """

    incidence_limit: float = float(np.deg2rad(30.0))
    beam_radius: float = 0.005
    reflector_radius: float = 0.01905
    capsule_margin: float = 0.0
    margins: Margins = field(default_factory=Margins)
    excluded_pairs: tuple[tuple[str, str], ...] = ()
    robot_capsules: tuple[Capsule, ...] | None = None
    prune_samples: int = 2000
    prune_seed: int = 0
    prune_distance: float = 0.10
    link_fit: str = "hulls"
    joint_window: str = "one_turn"

    def __post_init__(self):
        if self.link_fit not in LINK_FITS:
            raise ValueError(f"link_fit {self.link_fit!r}: expected one of {LINK_FITS}")
