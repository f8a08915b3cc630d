r"""Closest points of segment pairs, batched (closed form).

For segments :math:`x(s) = a_1 + s\,d_1` and :math:`y(t) = a_2 + t\,d_2`,
:math:`s, t \in [0, 1]`, the closest points minimise
:math:`\lVert x(s) - y(t) \rVert^2`, a convex quadratic over the unit square.
With :math:`r = a_1 - a_2`, :math:`a = d_1^\top d_1`, :math:`b = d_1^\top d_2`,
:math:`c = d_1^\top r`, :math:`e = d_2^\top d_2`, :math:`f = d_2^\top r`, the
unconstrained minimiser is :math:`s = (bf - ce)/(ae - b^2)`; it is clamped to
[0, 1], :math:`t = (bs + f)/e` is computed and clamped, and :math:`s` is
recomputed for a clamped :math:`t` (the standard clamping sequence, C. Ericson,
*Real-Time Collision Detection*, 2005, §5.1.9).

Degenerate cases: a segment of zero length is a point (its parameter is 0).
For parallel segments (:math:`ae - b^2 \le 10^{-12} ae`, an angle below
1e-6 rad) ``s = 0`` is taken and ``t`` follows. For exactly parallel segments
that is a closest pair (the minimiser is not unique); for segments within that
angle it overestimates the distance by at most length × angle (0.6 µm for a
0.6 m capsule), negligible next to the 10 mm margins. The witness points jump
as segments turn through parallel: the distance is continuous there, its
gradient is one of the one-sided slopes (see ``docs/feasibility.md``).
"""

from __future__ import annotations

import numpy as np

#: Squared length [m²] below which a segment is a point; relative tolerance of the
#: parallel test (:math:`ae - b^2 \le` ``EPS`` :math:`\cdot ae`).
EPS = 1e-12


def closest_parameters(a1, b1, a2, b2) -> tuple[np.ndarray, np.ndarray]:
    """Parameters ``(s, t)`` of the closest points, arrays of shape ``a1.shape[:-1]``.

    Args:
        a1, b1: End points of the first segments [m], (..., 3).
        a2, b2: End points of the second segments [m], (..., 3).
    """
    d1 = b1 - a1
    d2 = b2 - a2
    r = a1 - a2
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    b = np.einsum("...i,...i->...", d1, d2)
    c = np.einsum("...i,...i->...", d1, r)
    f = np.einsum("...i,...i->...", d2, r)
    p1 = a > EPS  # first segment is not a point
    p2 = e > EPS
    a_safe = np.where(p1, a, 1.0)
    e_safe = np.where(p2, e, 1.0)
    denom = a * e - b * b
    general = p1 & p2 & (denom > EPS * np.maximum(a * e, EPS))
    s = np.where(general, np.clip((b * f - c * e) / np.where(general, denom, 1.0), 0.0, 1.0), 0.0)
    # second segment a point: t = 0, s from projecting a2 on the first segment
    s = np.where(p1 & ~p2, np.clip(-c / a_safe, 0.0, 1.0), s)
    t = np.where(p2, (b * s + f) / e_safe, 0.0)
    low = p2 & (t < 0.0)
    high = p2 & (t > 1.0)
    t = np.clip(t, 0.0, 1.0)
    s = np.where(p1 & low, np.clip(-c / a_safe, 0.0, 1.0), s)
    s = np.where(p1 & high, np.clip((b - c) / a_safe, 0.0, 1.0), s)
    return s, t


def segment_distance(a1, b1, a2, b2) -> np.ndarray:
    """Distance [m] between segments, (...,)."""
    s, t = closest_parameters(a1, b1, a2, b2)
    x = a1 + s[..., None] * (b1 - a1)
    y = a2 + t[..., None] * (b2 - a2)
    return np.linalg.norm(x - y, axis=-1)
