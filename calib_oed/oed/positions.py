r"""Distinct arm positions of a design: where the reflectors are, not which joint vector reached them.

Two poses of a design are the *same arm position* when every reflector is
within a tolerance :math:`\tau` of itself in the other pose, in the world frame
at nominal parameters:

.. math::
    q_a \sim q_b \iff \max_j \lVert c_j^W(q_a) - c_j^W(q_b)\rVert \le \tau,
    \qquad c_j^W(q) = t_{W,F}(q) + R_{W,F}(q)\,c_j,

and positions group by chaining this relation (union-find over the pairs, as
:func:`calib_oed.oed.starts.multiplicities` groups joint vectors). A pose that
turns only the last joint, whose axis carries the reflector, is a new joint
vector but the same arm position: it measures the same point again.
:data:`POSITION_TOL` = 1 mm is the default :math:`\tau`: about 100 times the
tracker noise (0.01 mm per axis) and far below the distance at which the
model error of an arm changes (hundreds of mm of travel, ``docs/oed.md``).
"""

from __future__ import annotations

import numpy as np
import scipy.spatial

from calib_oed.exceptions import DesignError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.model.parameters import ParameterSpace

#: Default tolerance [m] below which two reflector positions count as one.
POSITION_TOL = 1e-3


def check_position_tol(tol: float) -> None:
    """The tolerance of distinct arm positions must be a number >= 0 [m] (else DesignError)."""
    try:
        ok = float(tol) >= 0 and np.isfinite(float(tol))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise DesignError("position_tol", tol, "a distance >= 0 [m] (default 1e-3: 1 mm)")


def group_counts(n: int, pairs) -> list[int]:
    """Sizes of the groups of ``n`` items joined by ``pairs`` (chained), in order of first occurrence."""
    parent = np.arange(n)

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in pairs:
        ri, rj = root(i), root(j)
        parent[max(ri, rj)] = min(ri, rj)
    roots = [root(i) for i in range(n)]
    order = list(dict.fromkeys(roots))
    return [roots.count(r) for r in order]


def reflector_positions(space: ParameterSpace, q: np.ndarray) -> np.ndarray:
    r"""World positions :math:`c_j^W(q)` of every reflector at nominal parameters, (n, k, 3) [m]."""
    state = evaluate_setup(space, None, q, regressor=False, jacobian=False)
    offsets = space.reflector_offsets(None)
    return np.stack([state.tool_point(c, "world") for c in offsets], axis=1)


def position_multiplicities(points: np.ndarray, tol: float = POSITION_TOL) -> list[int]:
    """How often each distinct arm position of ``points`` (n, k, 3) [m] is measured.

    Poses whose reflectors are all within ``tol`` [m] of each other (Euclidean
    per reflector, chained) are one position; order of first occurrence.
    """
    if not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"position tolerance must be a finite number >= 0 [m], got {tol!r}")
    points = np.asarray(points, dtype=float)
    n = points.shape[0]
    pairs = None
    for j in range(points.shape[1]):
        near = scipy.spatial.cKDTree(points[:, j]).query_pairs(tol)
        pairs = near if pairs is None else pairs & near
    return group_counts(n, sorted(pairs or ()))


def distinct_positions(space: ParameterSpace, q: np.ndarray, tol: float = POSITION_TOL) -> list[int]:
    """:func:`position_multiplicities` of design ``q`` (n, nq) [rad]."""
    return position_multiplicities(reflector_positions(space, q), tol)
