r"""Geometric primitives and settings of the feasibility model (records only).

A :class:`Capsule` is the set of points within ``radius`` of the segment
:math:`[a, b]`; its end points are expressed in the frame of a robot link
(``frame`` = link name) or in the world (``frame is None``, a cell
obstacle). A :class:`HalfSpace` is the free side
:math:`\{x \in \mathbb{R}^3 : n^\top x \ge c\}` of a plane fixed in the world
(floor :math:`z \ge z_0`: ``normal=(0, 0, 1), offset=z0``).

All lengths in [m], angles in [rad].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_oed.exceptions import NonFiniteError, ShapeError


def _vector(value, what: str, size: int = 3) -> np.ndarray:
    arr = np.array(value, dtype=float).reshape(-1)
    if arr.shape != (size,):
        raise ShapeError(what, f"({size},)", np.shape(value))
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(what)
    arr.setflags(write=False)
    return arr


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
    """

    a: np.ndarray
    b: np.ndarray
    radius: float
    frame: str | None = None
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "a", _vector(self.a, f"capsule {self.name!r} a"))
        object.__setattr__(self, "b", _vector(self.b, f"capsule {self.name!r} b"))
        r = float(self.radius)
        if not np.isfinite(r) or r <= 0.0:
            raise ValueError(f"capsule {self.name!r}: radius must be > 0 [m], got {self.radius!r}")
        object.__setattr__(self, "radius", r)

    @property
    def length(self) -> float:
        """Length of the axis segment [m]."""
        return float(np.linalg.norm(self.b - self.a))

    def inflated(self, margin: float) -> Capsule:
        """The same capsule with its radius grown by ``margin`` [m]."""
        return Capsule(self.a, self.b, self.radius + margin, self.frame, self.name)


@dataclass(frozen=True, eq=False)
class HalfSpace:
    r"""World-fixed free half-space :math:`n^\top x \ge c`.

    Attributes:
        normal: Normal :math:`n` pointing into the free side, (3,). Normalised on
            construction together with ``offset``, so the half-space is unchanged.
        offset: :math:`c` [m]: the plane is :math:`n^\top x = c` (after normalisation,
            its signed distance from the origin).
        name: Label used in reports (``"floor"``, ``"wall"``).
    """

    normal: np.ndarray
    offset: float
    name: str = ""

    def __post_init__(self):
        n = np.array(_vector(self.normal, f"half-space {self.name!r} normal"))
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            raise ValueError(f"half-space {self.name!r}: normal must be non-zero")
        n = n / norm
        n.setflags(write=False)
        object.__setattr__(self, "normal", n)
        # n^T x >= c is the same half-space as (n/|n|)^T x >= c/|n|
        object.__setattr__(self, "offset", float(self.offset) / norm)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance [m] of points (..., 3) to the plane, positive on the free side."""
        return np.asarray(points) @ self.normal - self.offset


@dataclass(frozen=True, eq=False)
class Cell:
    """The world-fixed obstacles of a cell.

    Attributes:
        capsules: Obstacle capsules (``frame is None``), e.g. a car body as two capsules.
        halfspaces: Free half-spaces (floor, walls).
    """

    capsules: tuple[Capsule, ...] = ()
    halfspaces: tuple[HalfSpace, ...] = ()

    def __post_init__(self):
        for c in self.capsules:
            if c.frame is not None:
                raise ValueError(f"cell capsule {c.name!r} must be world-fixed (frame=None), got frame {c.frame!r}")


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
        incidence_limit: Largest angle [rad] between the reflector axis (tool z)
            and the direction to the tracker (30°, paper eq. 4).
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
