r"""Efficient rounding of an approximate design to n measurements (Pukelsheim & Rieder 1992).

An approximate design puts weights :math:`w_1..w_\ell > 0`,
:math:`\sum w_i = 1`, on :math:`\ell` support poses
(:mod:`calib_oed.oed.approximate`); an exact design of :math:`n` measurements
measures support pose :math:`i` exactly :math:`n_i` times,
:math:`\sum n_i = n`. Its information is
:math:`M_n = \sum_i n_i F_i^\top F_i \succeq \varepsilon\, n\, M(w)` with

.. math::
    \varepsilon = \min_i \frac{n_i}{n\,w_i},

so for every criterion that is antitonic in the Loewner order and
homogeneous (the A-type: :math:`\Phi(tM) = \Phi(M)/t`) the rounded design is
within the factor :math:`\varepsilon` of the approximate one:
:math:`\Phi(M_n) \le \Phi(M(w))/(\varepsilon n)`.

**Efficient apportionment** (F. Pukelsheim and S. Rieder, "Efficient
rounding of approximate designs", *Biometrika* 79(4), 763–770, 1992):
start from :math:`n_i = \lceil (n - \ell/2)\,w_i \rceil`, then, while
:math:`\sum n_i < n`, add one to a pose with the smallest :math:`n_j/w_j`,
and while :math:`\sum n_i > n`, take one from a pose with the largest
:math:`(n_k - 1)/w_k`. The result maximises :math:`\varepsilon` over all
apportionments of :math:`n` (the paper's Theorem; checked by enumeration in
``tests/oed/test_rounding.py``). With a cap :math:`K` (at most :math:`K`
measurements per pose, ``--replicates K``) a pose at the cap takes no more
increments; the result then maximises :math:`\varepsilon` over the capped
apportionments. Ties go to the lower index.
"""

from __future__ import annotations

import numpy as np

from calib_oed.exceptions import DesignError

__all__ = ["efficient_rounding"]


def efficient_rounding(weights, n: int, cap: int | None = None) -> np.ndarray:
    r"""Counts :math:`n_i \ge 0`, :math:`\sum n_i = n`, :math:`n_i \le` ``cap``, apportioning ``weights`` (module docstring).

    Args:
        weights: Weights :math:`w_i > 0` of the support poses, (ℓ,); normalised here.
        n: Number of measurements, >= 1.
        cap: Most measurements of one pose (default: no limit).

    Returns:
        The counts, an integer array (ℓ,).

    Raises:
        DesignError: weights not finite and positive, ``n < 1``, ``cap < 1``, or
            ``ℓ * cap < n`` (the support cannot carry n measurements).
    """
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w)) or w.min() <= 0:
        raise DesignError("weights", f"array of shape {w.shape}",
                          "the support weights must be a non-empty 1-D array of positive numbers")
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise DesignError("n", n, "the number of measurements must be an integer >= 1")
    n = int(n)
    cap = n if cap is None else cap
    if isinstance(cap, bool) or int(cap) != cap or cap < 1:
        raise DesignError("cap", cap, "the most measurements of one pose must be an integer >= 1")
    cap = int(cap)
    if w.size * cap < n:
        raise DesignError("n", n, f"{w.size} support poses measured at most {cap} time(s) each carry "
                          f"at most {w.size * cap} measurements")
    w = w / w.sum()
    counts = np.minimum(np.maximum(np.ceil((n - w.size / 2.0) * w), 0), cap).astype(np.int64)
    while counts.sum() < n:
        j = int(np.argmin(np.where(counts < cap, counts / w, np.inf)))
        counts[j] += 1
    while counts.sum() > n:
        k = int(np.argmax(np.where(counts > 0, (counts - 1) / w, -np.inf)))
        counts[k] -= 1
    return counts

