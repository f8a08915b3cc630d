r"""Observability indices :math:`O_1..O_5` of the stacked sensitivity matrix, as design criteria.

With :math:`\sigma_i = \sqrt{\lambda_i(M)}` the singular values of the stacked
:math:`F` [1/mm or 1/mrad], each index is maximised in the literature; as a
:class:`~calib_oed.oed.criterion_base.Criterion` its value is :math:`-\log O_k`
(minimised) and :meth:`ObservabilityIndex.compute_index` gives :math:`O_k`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.oed.criterion_base import Criterion, _positive_eigh, as_information

_OBSERVABILITY_LABELS = {
    1: "O1, geometric mean of the singular values / sqrt(m) (Borm & Menq 1991)",
    2: "O2, inverse condition number sigma_L/sigma_1 (Driels & Pathre 1990)",
    3: "O3, minimum singular value sigma_L (Nahvi, Hollerbach & Hayward 1994)",
    4: "O4, noise amplification index sigma_L^2/sigma_1 (Nahvi & Hollerbach 1996)",
    5: "O5, inverse sum 1/sum(1/sigma_i) (Sun & Hollerbach 2008)",
}


@dataclass(frozen=True, eq=False)
class ObservabilityIndex(Criterion):
    r"""Observability index :math:`O_k`, :math:`k = 1..5` (compared by Joubair & Bonev 2013).

    With :math:`\sigma_i = \sqrt{\lambda_i(M)}` the singular values of the
    stacked :math:`F \in \mathbb{R}^{m \times L}`, :math:`L = n_p`,
    :math:`\sigma_1 \ge \dots \ge \sigma_L` [1/mm or 1/mrad]:

    .. math::
        O_1 = \frac{(\sigma_1 \cdots \sigma_L)^{1/L}}{\sqrt{m}}, \quad
        O_2 = \frac{\sigma_L}{\sigma_1}, \quad
        O_3 = \sigma_L, \quad
        O_4 = \frac{\sigma_L^2}{\sigma_1}, \quad
        O_5 = \Big(\sum_{i=1}^{L} \frac{1}{\sigma_i}\Big)^{-1}.

    They are maximised in the literature; the value minimised here is
    :math:`\phi = -\log O_k` (for :math:`O_1` without the constant
    :math:`\log\sqrt{m}`, i.e. :math:`-\tfrac{1}{2L}\log\det M`). Its gradient
    follows from :math:`d\lambda_i = v_i^\top dM\, v_i`:

    .. math::
        \frac{\partial \phi}{\partial M} = \sum_i \frac{\partial \phi}{\partial \lambda_i}\, v_i v_i^\top,

    valid where the eigenvalues it uses are simple (O2–O4 use the extreme
    ones; O1 and O5 are smooth spectral functions). :meth:`compute_index`
    returns :math:`O_k` itself.

    Attributes:
        k: Which index, 1 to 5.
    """

    k: int

    def __post_init__(self):
        if self.k not in _OBSERVABILITY_LABELS or isinstance(self.k, bool):
            raise ValueError(f"observability index k must be one of 1, 2, 3, 4, 5, got {self.k!r}")
        object.__setattr__(self, "k", int(self.k))

    @property
    def name(self) -> str:
        return f"O{self.k}"

    @property
    def label(self) -> str:
        return _OBSERVABILITY_LABELS[self.k]

    def _phi(self, lam: np.ndarray) -> np.ndarray:
        """:math:`-\\log O_k` (O1 without :math:`\\sqrt{m}`) from ascending eigenvalues (..., L)."""
        lo, hi = lam[..., 0], lam[..., -1]
        if self.k == 1:
            return -0.5 * np.mean(np.log(lam), axis=-1)
        if self.k == 2:
            return -0.5 * (np.log(lo) - np.log(hi))
        if self.k == 3:
            return -0.5 * np.log(lo)
        if self.k == 4:
            return -np.log(lo) + 0.5 * np.log(hi)
        return np.log(np.sum(lam**-0.5, axis=-1))

    def _dphi(self, lam: np.ndarray) -> np.ndarray:
        """:math:`\\partial\\phi/\\partial\\lambda_i`, (L,)."""
        c = np.zeros_like(lam)
        if self.k == 1:
            c[:] = -0.5 / (lam.size * lam)
        elif self.k == 2:
            c[0] += -0.5 / lam[0]
            c[-1] += 0.5 / lam[-1]
        elif self.k == 3:
            c[0] = -0.5 / lam[0]
        elif self.k == 4:
            c[0] += -1.0 / lam[0]
            c[-1] += 0.5 / lam[-1]
        else:
            c[:] = -0.5 * lam**-1.5 / np.sum(lam**-0.5)
        return c

    def compute_value(self, info):
        w, _ = _positive_eigh(as_information(info))
        return float(self._phi(w))

    def compute_gradient(self, info):
        w, v = _positive_eigh(as_information(info))
        return (v * self._dphi(w)) @ v.T

    def _batched_values(self, infos):
        lam = np.linalg.eigvalsh(infos)
        ok = lam[:, 0] > 0.0
        return self._phi(np.where(ok[:, None], lam, 1.0)), ok

    def compute_index(self, info, n_rows=None):
        r""":math:`O_k` [1/mm or 1/mrad for O1, O3, O5; O2 is dimensionless]; O1 needs ``n_rows`` :math:`= m`."""
        value = self.compute_value(info)
        if self.k != 1:
            return float(np.exp(-value))
        if n_rows is None or int(n_rows) != n_rows or n_rows < 1:
            raise ValueError(f"O1 needs n_rows, the number m >= 1 of stacked rows of F; got {n_rows!r}")
        return float(np.exp(-value) / np.sqrt(n_rows))
