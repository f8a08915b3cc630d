"""Joint-space paths: configurations sampled along piecewise-linear waypoints."""

from __future__ import annotations

import numpy as np

from calib_oed.exceptions import ShapeError


def sample_joint_path(waypoints: np.ndarray, samples: int) -> np.ndarray:
    r"""``samples`` configurations along a piecewise-linear joint-space path, endpoints included.

    The path runs through the waypoints :math:`w_0..w_{K}` in order; the
    samples are equally spaced in joint-space arc length
    :math:`\ell = \sum_k \|w_{k+1} - w_k\|_2` [rad], so sample :math:`k`
    lies at :math:`\ell\,k/(m-1)`; every sample is a convex combination of two
    consecutive waypoints (inside the joint limits when they are).

    Args:
        waypoints: (K+1, nq), K+1 >= 2 [rad].
        samples: Number m >= 2 of samples.

    Returns:
        (m, nq) configurations; row 0 is the first waypoint, row m-1 the last.
    """
    w = np.asarray(waypoints, dtype=float)
    if w.ndim != 2 or w.shape[0] < 2:
        raise ShapeError("path waypoints", "(K+1 >= 2, nq)", w.shape)
    if int(samples) != samples or samples < 2:
        raise ValueError(f"a path needs samples >= 2 (its two endpoints), got {samples!r}")
    seg = np.linalg.norm(np.diff(w, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        raise ValueError("the path's waypoints are all equal: it has zero length")
    target = np.linspace(0.0, s[-1], int(samples))
    out = np.empty((int(samples), w.shape[1]))
    for j in range(w.shape[1]):
        out[:, j] = np.interp(target, s, w[:, j])
    out[0], out[-1] = w[0], w[-1]
    return out
