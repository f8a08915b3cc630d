r"""Covariances of the estimated parameters and KPIs (linear error propagation).

On the free parameters :math:`p_f` chosen by the gauge rule (the paper's
parameter covariance of §1.1, and the explicit form of its KKT covariance,
Theorem of §2.1, eq. 19):

.. math::
    C_p = (F_1^\top F_1)^{-1}, \qquad C_s = G\,C_p\,G^\top,

with :math:`F_1 = \Sigma^{-1}\partial h/\partial p_f` and
:math:`G = \partial s/\partial p_f`. Units: :math:`C_p` in SI
[m², m·rad, rad²]; :math:`C_s` in [m²]. A non-estimable KPI's covariance is
relative to the gauge (see :mod:`calib_oed.model.identifiability`).

:func:`kkt_covariance` computes the paper's KKT form of the joint covariance
:math:`C_v` of :math:`v = (p, s)` (eq. 19), :func:`covariance_blocks` splits
it, and :class:`Projection` is the scaled selection :math:`P` of eq. 24a whose
:math:`\mathrm{tr}(P^\top C_v P)/k` is the A-criterion. Derivations:
``docs/derivations.md`` §9–10.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg

from calib_oed.exceptions import NonFiniteError, NotIdentifiableError, ShapeError


def information_cholesky(f1: np.ndarray, names=None) -> np.ndarray:
    r"""Upper Cholesky factor :math:`U` of :math:`F_1^\top F_1 = U^\top U`.

    Raises:
        NotIdentifiableError: the information matrix is singular on these
            parameters (names given when known).
    """
    f1 = np.asarray(f1, dtype=float)
    if f1.ndim != 2:
        raise ShapeError("F1", "(m, n_p)", f1.shape)
    if f1.shape[0] < f1.shape[1]:
        labels = list(names) if names is not None else [str(i) for i in range(f1.shape[1])]
        raise NotIdentifiableError(
            labels,
            f"the design gives {f1.shape[0]} measured values for {f1.shape[1]} free "
            "parameters; measure more configurations",
        )
    # QR of F1 is better conditioned than Cholesky of F1^T F1.
    r = scipy.linalg.qr(f1, mode="r")[0][: f1.shape[1]]
    diag = np.abs(np.diag(r))
    if diag.size and diag.min() <= diag.max() * 1e-12:
        weak = np.flatnonzero(diag <= diag.max() * 1e-12)
        labels = [names[i] for i in weak] if names is not None else [str(i) for i in weak]
        raise NotIdentifiableError(labels, "F1 is rank-deficient on these columns")
    return r


def parameter_covariance(f1: np.ndarray, names=None) -> np.ndarray:
    r""":math:`C_p = (F_1^\top F_1)^{-1}` on the columns of ``f1``."""
    r = information_cholesky(f1, names)
    r_inv = scipy.linalg.solve_triangular(r, np.eye(r.shape[0]))
    return r_inv @ r_inv.T


def kpi_covariance(f1: np.ndarray, g: np.ndarray, names=None) -> np.ndarray:
    r""":math:`C_s = G (F_1^\top F_1)^{-1} G^\top` for KPI Jacobian ``g`` (n_s, n_p)."""
    g = np.atleast_2d(np.asarray(g, dtype=float))
    r = information_cholesky(f1, names)
    if g.shape[1] != r.shape[0]:
        raise ShapeError("G", f"(n_s, {r.shape[0]})", g.shape)
    w = scipy.linalg.solve_triangular(r, g.T, trans="T")  # U^-T G^T
    return w.T @ w


# --------------------------------------------------------------- KKT form
def _equilibrate(k: np.ndarray, iterations: int = 8) -> np.ndarray:
    """Symmetric diagonal scaling :math:`S` with rows of :math:`SKS` of max-norm near 1.

    Ruiz's iteration, rounded to powers of two so that scaling is exact in
    floating point. Without it the KKT matrix mixes :math:`F_1^\\top F_1`
    (about :math:`10^{10}` per row for a 0.01 mm tracker) with the O(1) entries
    of :math:`F_2`, and the symmetric indefinite solve loses digits.
    """
    s = np.ones(k.shape[0])
    for _ in range(iterations):
        row = np.abs(k * s[:, None] * s[None, :]).max(axis=1)
        row[row == 0.0] = 1.0
        step = np.exp2(-np.round(0.5 * np.log2(row)))
        if np.all(step == 1.0):
            break
        s *= step
    return s


def kkt_covariance(f1: np.ndarray, g: np.ndarray, names=None) -> np.ndarray:
    r"""Covariance :math:`C_v` of :math:`v = (p, s)` from the paper's KKT system (§2.1, eq. 19).

    The constrained least-squares problem (paper eq. 13) estimates
    :math:`v = (p, s) \in \mathbb{R}^{n_v}`, :math:`n_v = n_p + n_s`, subject
    to :math:`f_2(v) = \mathrm{TCP}(p, q^\mathrm{work}) - s = 0`. Linearised,

    .. math::
        F_1^v = [\,F_1 \;\; 0\,] \in \mathbb{R}^{m \times n_v}, \qquad
        F_2 = [\,G \;\; -I\,] \in \mathbb{R}^{n_s \times n_v},

        K = \begin{bmatrix} F_1^{v\top} F_1^v & F_2^\top \\ F_2 & 0 \end{bmatrix}
        \in \mathbb{R}^{(n_v + n_s) \times (n_v + n_s)}, \qquad
        C_v = [\,I \;\; 0\,]\, K^{-1} \begin{bmatrix} I \\ 0 \end{bmatrix}
        = \begin{bmatrix} C_p & C_{ps} \\ C_{sp} & C_s \end{bmatrix}.

    :math:`K` is never inverted: the code solves :math:`K X = [I;\,0]` for the
    :math:`n_v` columns by a symmetric indefinite :math:`LDL^\top` factorisation
    (LAPACK ``?sysv`` via ``scipy.linalg.solve(assume_a="sym")``) after a
    power-of-two equilibration :math:`S K S`, and keeps the first :math:`n_v`
    rows. In exact arithmetic :math:`C_p = (F_1^\top F_1)^{-1}`,
    :math:`C_{ps} = C_p G^\top`, :math:`C_s = G C_p G^\top`
    (``docs/derivations.md`` §10); like any covariance its rounding error
    grows as :math:`\varepsilon\,\kappa(F_1)^2`.

    Args:
        f1: Weighted sensitivity :math:`F_1` on the free parameters, (m, n_p),
            columns in 1/m or 1/rad.
        g: KPI Jacobian :math:`G = \partial s/\partial p` on the same
            parameters, (n_s, n_p) [m/m, m/rad].
        names: Parameter names, used in the error when (PD) fails.

    Returns:
        :math:`C_v`, (n_p + n_s, n_p + n_s), symmetric. Units: the
        :math:`p` block [m², m·rad, rad²], the cross block [m², m·rad], the
        :math:`s` block [m²]. Split it with :func:`covariance_blocks`.

    Raises:
        ShapeError: ``g`` does not have n_p columns.
        NotIdentifiableError: (PD) fails, i.e. :math:`F_1` is rank-deficient
            ((CQ) always holds because of the :math:`-I`).
    """
    f1 = np.asarray(f1, dtype=float)
    g = np.atleast_2d(np.asarray(g, dtype=float))
    information_cholesky(f1, names)  # (PD) <=> rank F1 = n_p; clear error otherwise
    n_p = f1.shape[1]
    if g.ndim != 2 or g.shape[1] != n_p:
        raise ShapeError("G", f"(n_s, {n_p})", g.shape)
    n_s = g.shape[0]
    n_v = n_p + n_s
    k = np.zeros((n_v + n_s, n_v + n_s))
    k[:n_p, :n_p] = f1.T @ f1
    k[n_v:, :n_p] = g
    k[:n_p, n_v:] = g.T
    k[n_v:, n_p:n_v] = -np.eye(n_s)
    k[n_p:n_v, n_v:] = -np.eye(n_s)
    s = _equilibrate(k)
    rhs = np.zeros((n_v + n_s, n_v))
    rhs[:n_v] = np.diag(s[:n_v])  # S [I; 0]
    y = scipy.linalg.solve(k * s[:, None] * s[None, :], rhs, assume_a="sym")
    c_v = s[:n_v, None] * y[:n_v]  # X = S Y, first n_v rows
    return 0.5 * (c_v + c_v.T)


class CovarianceBlocks(NamedTuple):
    r"""The blocks of :math:`C_v = \begin{bmatrix} C_p & C_{ps} \\ C_{ps}^\top & C_s \end{bmatrix}`.

    Attributes:
        p: :math:`C_p`, (n_p, n_p) [m², m·rad, rad²].
        ps: :math:`C_{ps} = \mathrm{Cov}(p, s)`, (n_p, n_s) [m², m·rad].
        s: :math:`C_s`, (n_s, n_s) [m²].
    """

    p: np.ndarray
    ps: np.ndarray
    s: np.ndarray


def covariance_blocks(c_v: np.ndarray, n_p: int) -> CovarianceBlocks:
    """Split :math:`C_v` (n_v, n_v) after its first ``n_p`` rows and columns (views, not copies)."""
    c_v = np.asarray(c_v, dtype=float)
    if c_v.ndim != 2 or c_v.shape[0] != c_v.shape[1]:
        raise ShapeError("C_v", "(n_v, n_v)", c_v.shape)
    if not 0 <= int(n_p) <= c_v.shape[0]:
        raise ValueError(f"n_p must be in [0, {c_v.shape[0]}], got {n_p}")
    n_p = int(n_p)
    return CovarianceBlocks(c_v[:n_p, :n_p], c_v[:n_p, n_p:], c_v[n_p:, n_p:])


# ------------------------------------------------------------- projection
#: Entry of :math:`P` that turns metres into millimetres (1 / 1e-3 m).
MM_PER_M = 1e3


def _positive_vector(value, k: int, what: str) -> np.ndarray:
    """A (k,) float copy of a scalar or vector of finite, positive numbers."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(k, float(arr))
    if arr.shape != (k,):
        raise ShapeError(what, f"({k},) or a scalar", arr.shape)
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ValueError(f"{what}: every entry must be finite and > 0, got {arr}")
    return arr.copy()


@dataclass(frozen=True, eq=False)
class Projection:
    r"""A scaled selection :math:`P \in \mathbb{R}^{n_v \times k}` of the components of :math:`v = (p, s)`.

    Column :math:`j` of :math:`P` is :math:`w_j\, e_{i_j}`: it picks component
    :math:`i_j` of :math:`v` and multiplies it by :math:`w_j = 1/u_j`, where
    :math:`u_j` is the SI value of the unit it is reported in. A scaled quantity
    is value / unit: a length in mm is the value in m times
    :math:`1/10^{-3} = 10^3`, an angle in mrad the value in rad times
    :math:`10^3`. Then

    .. math::
        P^\top C_v P = \mathrm{Cov}(P^\top v) \quad [\mathrm{mm}^2,\ \mathrm{mm\,mrad},\ \mathrm{mrad}^2],
        \qquad \phi_A = \tfrac{1}{k}\,\mathrm{tr}(P^\top C_v P),

    the paper's A-criterion (eq. 24a, divided by :math:`k`: the mean of the
    diagonal). Vocabulary: a *scale* is an entry :math:`w_j` of :math:`P`; a
    *unit scale* is :math:`u_j` (as ``ParameterSpace.unit_scale``: 1e-3 for
    mm and mrad), and :math:`w_j = 1/u_j`.

    Attributes:
        P: The matrix, (n_v, k), read-only; each column has exactly one
            non-zero, positive entry, and no two columns pick the same row.
    """

    P: np.ndarray

    def __post_init__(self):
        p = np.array(self.P, dtype=float)
        if p.ndim != 2 or p.shape[1] < 1:
            raise ShapeError("P", "(n_v, k) with k >= 1", p.shape)
        if not np.all(np.isfinite(p)):
            raise NonFiniteError("P", np.flatnonzero(~np.isfinite(p)).tolist())
        nonzero = np.count_nonzero(p, axis=0)
        if np.any(nonzero != 1):
            bad = np.flatnonzero(nonzero != 1).tolist()
            raise ValueError(f"P: every column must select exactly one component; columns {bad} do not")
        rows = np.argmax(p != 0, axis=0)
        if np.any(p[rows, np.arange(p.shape[1])] < 0):
            raise ValueError("P: scales must be > 0")
        if len(set(rows.tolist())) != len(rows):
            raise ValueError(f"P: a component is selected twice (rows {rows.tolist()})")
        p.setflags(write=False)
        object.__setattr__(self, "P", p)

    # ---------------------------------------------------------- constructors
    @classmethod
    def select(cls, indices, scales, n_v: int) -> Projection:
        """Components ``indices`` of :math:`v` (length n_v), multiplied by ``scales`` (scalar or (k,))."""
        idx = np.asarray(indices, dtype=int).ravel()
        n_v = int(n_v)
        if idx.size == 0:
            raise ValueError("a projection must select at least one component")
        if np.any((idx < 0) | (idx >= n_v)):
            raise ValueError(f"indices must be in [0, {n_v}), got {idx.tolist()}")
        w = _positive_vector(scales, idx.size, "scales")
        p = np.zeros((n_v, idx.size))
        p[idx, np.arange(idx.size)] = w
        return cls(p)

    @classmethod
    def kpi(cls, n_p: int, n_s: int, scale: float = MM_PER_M) -> Projection:
        r"""The KPI block :math:`s` (last ``n_s`` components), [m] times ``scale`` (default: mm)."""
        return cls.select(np.arange(n_p, n_p + n_s), scale, n_p + n_s)

    @classmethod
    def parameters(cls, n_p: int, n_s: int, unit_scale) -> Projection:
        r"""The parameter block :math:`p`, each divided by its unit.

        Args:
            unit_scale: SI value of each parameter's report unit, scalar or
                (n_p,): pass ``space.unit_scale[free]`` (1e-3 m = 1 mm,
                1e-3 rad = 1 mrad). The entries of :math:`P` are ``1 / unit_scale``.
        """
        units = _positive_vector(unit_scale, int(n_p), "unit_scale")
        return cls.select(np.arange(n_p), 1.0 / units, n_p + n_s)

    @classmethod
    def both(cls, n_p: int, n_s: int, unit_scale, kpi_scale: float = MM_PER_M) -> Projection:
        """Parameters (as :meth:`parameters`) then the KPI (as :meth:`kpi`)."""
        units = _positive_vector(unit_scale, int(n_p), "unit_scale")
        w = np.concatenate([1.0 / units, _positive_vector(kpi_scale, int(n_s), "kpi_scale")])
        return cls.select(np.arange(n_p + n_s), w, n_p + n_s)

    # ------------------------------------------------------------ properties
    @property
    def n_v(self) -> int:
        """Length of :math:`v`."""
        return self.P.shape[0]

    @property
    def dim(self) -> int:
        """Number :math:`k` of projected quantities."""
        return self.P.shape[1]

    @property
    def indices(self) -> np.ndarray:
        """Component :math:`i_j` picked by column :math:`j`, (k,)."""
        return np.argmax(self.P != 0, axis=0)

    @property
    def scales(self) -> np.ndarray:
        """Scale :math:`w_j` of column :math:`j`, (k,)."""
        return self.P[self.indices, np.arange(self.dim)]

    # ---------------------------------------------------------------- action
    def _check(self, c_v: np.ndarray) -> np.ndarray:
        c_v = np.asarray(c_v, dtype=float)
        if c_v.shape != (self.n_v, self.n_v):
            raise ShapeError("C_v", f"({self.n_v}, {self.n_v})", c_v.shape)
        return c_v

    def apply(self, c_v: np.ndarray) -> np.ndarray:
        r""":math:`P^\top C_v P`, (k, k), in the scaled units (mm², mm·mrad, mrad²)."""
        c_v = self._check(c_v)
        idx, w = self.indices, self.scales
        return c_v[np.ix_(idx, idx)] * np.outer(w, w)

    def trace_average(self, c_v: np.ndarray) -> float:
        r"""A-criterion :math:`\mathrm{tr}(P^\top C_v P)/k` in the scaled units (e.g. mm²)."""
        c_v = self._check(c_v)
        idx, w = self.indices, self.scales
        return float(np.sum(np.diag(c_v)[idx] * w**2) / self.dim)
