r"""Design criteria: scalar functions of the information matrix, all minimised.

A design of :math:`n` poses stacks the weighted, unit-scaled sensitivity
blocks :math:`F_j \in \mathbb{R}^{d \times n_p}` of its poses (rows
dimensionless, columns in 1/mm or 1/mrad, so that the parameters are in mm
and mrad). Its information matrix and parameter covariance are

.. math::
    M = \sum_j F_j^\top F_j \in \mathbb{R}^{n_p \times n_p}
    \quad [\mathrm{mm}^{-2},\ \mathrm{mm^{-1}\,mrad^{-1}},\ \mathrm{mrad}^{-2}],
    \qquad C = M^{-1} \quad [\mathrm{mm}^2,\ \mathrm{mm\,mrad},\ \mathrm{mrad}^2].

A :class:`Criterion` maps :math:`M` (symmetric positive definite) to a value
:math:`\phi(M)` to *minimise* and its gradient :math:`\partial\phi/\partial M`,
the symmetric matrix :math:`G` with :math:`d\phi = \mathrm{tr}(G\,dM)` for
every symmetric :math:`dM`. :meth:`Criterion.compute_index` gives the quantity
in its usual literature sense (the observability indices are maximised
there; their value here is :math:`-\log O_k`).

A singular or indefinite :math:`M` raises
:class:`~calib_oed.exceptions.NotIdentifiableError`, naming the columns that
carry its (near-)null space.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from calib_oed.exceptions import (
    NonFiniteError,
    NotIdentifiableError,
    ShapeError,
    UnknownCriterionError,
)

#: Names accepted by :func:`make_criterion`.
CRITERIA = ("kpi", "params", "D", "E", "O1", "O2", "O3", "O4", "O5")

#: Relative asymmetry :math:`\max|M - M^\top| / \max|M|` above which an input is rejected.
SYMMETRY_RTOL = 1e-8


# ----------------------------------------------------------------- helpers
def _check_symmetric(m: np.ndarray, what: str) -> None:
    asym = np.abs(m - np.swapaxes(m, -1, -2)).max(axis=(-2, -1))
    scale = np.abs(m).max(axis=(-2, -1))
    bad = asym > SYMMETRY_RTOL * scale
    if np.any(bad):
        j = int(np.flatnonzero(np.atleast_1d(bad))[0])
        a, s = np.atleast_1d(asym)[j], np.atleast_1d(scale)[j]
        where = f" (batch member {j})" if m.ndim == 3 else ""
        raise ValueError(f"{what}{where}: not symmetric, max |M - M^T| = {a:.3g} for max |M| = {s:.3g}")


def as_information(info, what: str = "information matrix") -> np.ndarray:
    """Validated float copy of a square, finite, symmetric (n_p, n_p) matrix, exactly symmetrised."""
    m = np.array(info, dtype=float)
    if m.ndim != 2 or m.shape[0] != m.shape[1] or m.shape[0] == 0:
        raise ShapeError(what, "(n_p, n_p)", m.shape)
    if not np.all(np.isfinite(m)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(m)).tolist())
    _check_symmetric(m, what)
    return 0.5 * (m + m.T)


def _as_informations(infos, what: str = "information matrices") -> np.ndarray:
    m = np.asarray(infos, dtype=float)
    if m.ndim != 3 or m.shape[1] != m.shape[2] or m.shape[1] == 0:
        raise ShapeError(what, "(k, n_p, n_p)", m.shape)
    if not np.all(np.isfinite(m)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(m)).tolist())
    if m.shape[0]:
        _check_symmetric(m, what)
    return 0.5 * (m + np.swapaxes(m, 1, 2))


def _forward_substitution(low: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:math:`L^{-1} B` for a stack of lower-triangular ``low`` (k, n, n) and ``b`` (k, n, r).

    Vectorised over the stack, one step per row (numpy has no batched
    triangular solve; this is much faster than a batched LU for small n).
    """
    z = np.empty(np.broadcast_shapes(low.shape[:-1], b.shape[:-2] + (low.shape[-1],)) + b.shape[-1:])
    for j in range(low.shape[-1]):
        acc = b[..., j, :] - np.einsum("...k,...kr->...r", low[..., j, :j], z[..., :j, :])
        z[..., j, :] = acc / low[..., j, j, None]
    return z


def _not_identifiable(info: np.ndarray, where: str = "") -> NotIdentifiableError:
    """The error for a singular or indefinite ``info``, naming the columns of its null space."""
    w, v = np.linalg.eigh(info)
    tol = max(abs(w[-1]), np.finfo(float).tiny) * info.shape[0] * np.finfo(float).eps
    null = v[:, w <= tol] if np.any(w <= tol) else v[:, :1]
    weight = np.sum(null**2, axis=1)
    cols = np.flatnonzero(weight >= 0.1 * weight.max())
    return NotIdentifiableError(
        [f"column {i}" for i in cols],
        f"{where}the information matrix is singular or indefinite: eigenvalues from "
        f"{w[0]:.3g} to {w[-1]:.3g}; the listed columns carry its (near-)null space",
    )


def _cholesky(info: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor :math:`L` of :math:`M = L L^\\top`, or NotIdentifiableError."""
    try:
        return scipy.linalg.cholesky(info, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        raise _not_identifiable(info) from None


def _batched_cholesky(infos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower Cholesky factors of a stack and a mask of the positive definite members.

    Members that are not positive definite get the identity as factor.
    """
    k, n, _ = infos.shape
    try:
        return np.linalg.cholesky(infos), np.ones(k, dtype=bool)
    except np.linalg.LinAlgError:
        low, ok = np.broadcast_to(np.eye(n), infos.shape).copy(), np.zeros(k, dtype=bool)
        for j in range(k):
            try:
                low[j] = np.linalg.cholesky(infos[j])
                ok[j] = True
            except np.linalg.LinAlgError:
                pass
        return low, ok


def _positive_eigh(info: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ascending eigenvalues and eigenvectors of a positive definite ``info``."""
    w, v = np.linalg.eigh(info)
    if w[0] <= 0.0:
        raise _not_identifiable(info)
    return w, v


# -------------------------------------------------------------- interface
class Criterion(abc.ABC):
    r"""A scalar design criterion :math:`\phi(M)` of the information matrix, to minimise.

    Attributes:
        name: Short name (one of :data:`CRITERIA` for the shipped ones).
        label: Human description.
    """

    name: str
    label: str

    @abc.abstractmethod
    def compute_value(self, info: np.ndarray) -> float:
        r"""Value :math:`\phi(M)` of the information matrix ``info`` (n_p, n_p)."""

    @abc.abstractmethod
    def compute_gradient(self, info: np.ndarray) -> np.ndarray:
        r"""Gradient :math:`G = \partial\phi/\partial M`, symmetric (n_p, n_p): :math:`d\phi = \mathrm{tr}(G\,dM)`."""

    def compute_values(self, infos: np.ndarray, *, singular: str = "raise") -> np.ndarray:
        r"""Values :math:`\phi(M_k)` of a stack ``infos`` (k, n_p, n_p), shape (k,).

        Args:
            infos: Stack of symmetric information matrices.
            singular: ``"raise"`` (NotIdentifiableError for the first member
                that is not positive definite) or ``"inf"`` (its value is
                :math:`+\infty`, so that a search ranks it last).
        """
        if singular not in ("raise", "inf"):
            raise ValueError(f"singular must be 'raise' or 'inf', got {singular!r}")
        infos = _as_informations(infos)
        values, ok = self._batched_values(infos)
        if not np.all(ok):
            if singular == "raise":
                j = int(np.flatnonzero(~ok)[0])
                raise _not_identifiable(infos[j], f"batch member {j}: ")
            values = np.where(ok, values, np.inf)
        return values

    def _batched_values(self, infos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values and positive-definite mask of a validated stack; subclasses vectorise this."""
        values, ok = np.full(infos.shape[0], np.inf), np.ones(infos.shape[0], dtype=bool)
        for j, info in enumerate(infos):
            try:
                values[j] = self.compute_value(info)
            except NotIdentifiableError:
                ok[j] = False
        return values, ok

    def compute_index(self, info: np.ndarray, n_rows: int | None = None) -> float:
        """The criterion in its usual literature sense; by default the value itself.

        Args:
            info: Information matrix (n_p, n_p).
            n_rows: Number :math:`m` of stacked rows of :math:`F` (used by O1 only).
        """
        return self.compute_value(info)


# ------------------------------------------------------------- A-criterion
@dataclass(frozen=True, eq=False)
class ACriterion(Criterion):
    r"""Weighted A-criterion :math:`\phi_A(M) = \mathrm{tr}(W M^{-1})/k`.

    .. math::
        \phi_A = \tfrac{1}{k}\,\mathrm{tr}(W C) = \tfrac{1}{k}\,\| L^{-1} R^\top \|_F^2
        = \tfrac{1}{k}\,\mathrm{tr}\big(R\,(M^{-1} R^\top)\big),
        \qquad \frac{\partial \phi_A}{\partial M} = -\tfrac{1}{k}\, M^{-1} W M^{-1},

    with :math:`W = R^\top R` symmetric positive semidefinite and
    :math:`M = L L^\top` (Cholesky; no inverse is formed). With
    :meth:`kpi`, :math:`R = G` and :math:`\phi_A` is the mean variance of the
    KPI, :math:`\mathrm{tr}(G C G^\top)/n_s` [mm²], the paper's
    :math:`\mathrm{tr}(P^\top C_v P)/k`; with :meth:`parameters`, the mean
    variance of the unit-scaled parameters [mm² for lengths, mrad² for angles].

    Attributes:
        weight: :math:`W`, (n_p, n_p), read-only.
        dim: Divisor :math:`k` (number of averaged quantities).
        name: Short name.
        label: Human description.
        root: :math:`R` with :math:`R^\top R = W`, (r, n_p), read-only;
            computed from :math:`W` by an eigen-decomposition when not given.
    """

    weight: np.ndarray
    dim: int
    name: str = "A"
    label: str = "A-criterion tr(W C)/k"
    root: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        w = as_information(self.weight, "weight W")
        if int(self.dim) != self.dim or self.dim < 1:
            raise ValueError(f"dim must be a positive integer, got {self.dim!r}")
        if self.root is None:
            lam, vec = np.linalg.eigh(w)
            top = max(abs(lam[-1]), np.finfo(float).tiny)
            if lam[0] < -1e-10 * top:
                raise ValueError(f"weight W must be positive semidefinite; smallest eigenvalue {lam[0]:.3g}")
            keep = lam > w.shape[0] * np.finfo(float).eps * top
            root = np.sqrt(lam[keep])[:, None] * vec[:, keep].T
        else:
            root = np.array(self.root, dtype=float)
            if root.ndim != 2 or root.shape[1] != w.shape[0]:
                raise ShapeError("root R", f"(r, {w.shape[0]})", root.shape)
            if not np.allclose(root.T @ root, w, rtol=1e-10, atol=1e-12 * np.abs(w).max()):
                raise ValueError("root R does not satisfy R^T R = W")
        if root.shape[0] == 0:
            raise ValueError("weight W is zero: the criterion would be constant")
        w.setflags(write=False)
        root.setflags(write=False)
        object.__setattr__(self, "weight", w)
        object.__setattr__(self, "dim", int(self.dim))
        object.__setattr__(self, "root", root)

    @classmethod
    def kpi(cls, g: np.ndarray, weights=None) -> ACriterion:
        r"""Mean KPI variance :math:`\mathrm{tr}(G C G^\top)/n_s` [mm²], optionally weighted.

        With weights :math:`w_i \ge 0` of the :math:`t = n_s/3` KPI points
        (rows :math:`3i..3i+2` of :math:`G` are point :math:`i`) the value is the
        weighted mean of the per-point variances
        :math:`v_i = \mathrm{tr}(G_i C G_i^\top)/3`,

        .. math::
            \phi = \frac{\sum_i w_i\,\mathrm{tr}(G_i C G_i^\top)}{3\sum_i w_i}
                  = \tfrac{1}{n_s}\,\mathrm{tr}(R C R^\top),\qquad
            R = \mathrm{diag}\big(\sqrt{w_i/\bar w}\big)\,G

        (each factor repeated for x, y, z; :math:`\bar w` the mean weight).
        Equal weights give exactly the unweighted criterion (same root).

        Args:
            g: Unit-scaled KPI Jacobian :math:`G`, (n_s, n_p) [mm/mm, mm/mrad].
            weights: One weight >= 0 per KPI point (n_s/3,), not all zero; None: all 1.
        """
        g = np.atleast_2d(np.array(g, dtype=float))
        if g.ndim != 2:
            raise ShapeError("KPI Jacobian G", "(n_s, n_p)", g.shape)
        if not np.all(np.isfinite(g)):
            raise NonFiniteError("KPI Jacobian G", np.flatnonzero(~np.isfinite(g)).tolist())
        root = g
        if weights is not None:
            w = np.asarray(weights, dtype=float).reshape(-1)
            if g.shape[0] % 3 or w.shape != (g.shape[0] // 3,):
                raise ShapeError("KPI weights", f"({g.shape[0] // 3},), one per KPI point", w.shape)
            if not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
                raise ValueError(f"KPI weights must be finite, >= 0 and not all 0, got {w}")
            if np.any(w != w[0]):  # equal weights: exactly the unweighted criterion
                root = np.repeat(np.sqrt(w / w.mean()), 3)[:, None] * g
        label = ("A-criterion on the KPI covariance, tr(G C G^T)/n_s [mm^2]" if root is g else
                 "weighted A-criterion on the KPI covariance, sum_i w_i tr(C_s,ii)/(3 sum_i w_i) [mm^2]")
        return cls(root.T @ root, g.shape[0], "kpi", label, root)

    @classmethod
    def parameters(cls, n_p: int) -> ACriterion:
        r"""Mean parameter variance :math:`\mathrm{tr}(C)/n_p` on the unit-scaled parameters.

        Lengths are in mm and angles in mrad, so the value mixes [mm²] and
        [mrad²]: a variance of 1 mm² weighs as much as one of 1 mrad².
        """
        n_p = int(n_p)
        if n_p < 1:
            raise ValueError(f"n_p must be >= 1, got {n_p}")
        eye = np.eye(n_p)
        return cls(eye, n_p, "params", "A-criterion on the parameter covariance, tr(C)/n_p [mm^2, mrad^2]", eye)

    def _check_size(self, n: int) -> None:
        if n != self.weight.shape[0]:
            raise ShapeError("information matrix", f"({self.weight.shape[0]}, {self.weight.shape[0]})", (n, n))

    def compute_value(self, info):
        m = as_information(info)
        self._check_size(m.shape[0])
        # tr(R M^-1 R^T) by cho_solve: scipy's solve_triangular was ~100x slower on
        # small matrices with a multithreaded OpenBLAS on a busy machine
        y = scipy.linalg.cho_solve((_cholesky(m), True), self.root.T, check_finite=False)
        return float(np.sum(self.root.T * y) / self.dim)

    def compute_gradient(self, info):
        m = as_information(info)
        self._check_size(m.shape[0])
        y = scipy.linalg.cho_solve((_cholesky(m), True), self.root.T, check_finite=False)  # M^-1 R^T
        return -(y @ y.T) / self.dim

    def _batched_values(self, infos):
        self._check_size(infos.shape[1])
        low, ok = _batched_cholesky(infos)
        z = _forward_substitution(low, self.root.T)
        return np.sum(z**2, axis=(1, 2)) / self.dim, ok


# ---------------------------------------------------------- D, E criteria
@dataclass(frozen=True, eq=False)
class DCriterion(Criterion):
    r"""D-criterion :math:`\phi_D(M) = \log\det C = -\log\det M = -2\sum_i \log L_{ii}`.

    .. math::
        \frac{\partial \phi_D}{\partial M} = -M^{-1}.

    Units: :math:`\log` of [mm^(2a) mrad^(2b)] for :math:`a` length and
    :math:`b` angle parameters; changing units shifts it by a constant.
    The index is the value.
    """

    name = "D"
    label = "D-criterion, log det C"

    def compute_value(self, info):
        low = _cholesky(as_information(info))
        return float(-2.0 * np.sum(np.log(np.diag(low))))

    def compute_gradient(self, info):
        m = as_information(info)
        return -scipy.linalg.cho_solve((_cholesky(m), True), np.eye(m.shape[0]), check_finite=False)

    def _batched_values(self, infos):
        low, ok = _batched_cholesky(infos)
        return -2.0 * np.sum(np.log(np.diagonal(low, axis1=1, axis2=2)), axis=1), ok


@dataclass(frozen=True, eq=False)
class ECriterion(Criterion):
    r"""E-criterion :math:`\phi_E(M) = \lambda_{\max}(C) = 1/\lambda_{\min}(M)`.

    .. math::
        \frac{\partial \phi_E}{\partial M} = -\frac{v v^\top}{\lambda_{\min}^2},

    with :math:`v` the unit eigenvector of :math:`\lambda_{\min}(M)`. The
    criterion is not differentiable where :math:`\lambda_{\min}` is repeated;
    there the formula gives one element of the generalised gradient.
    Units: [mm²] or [mrad²] (the variance of the worst-determined combination
    of unit-scaled parameters). The index is the value.
    """

    name = "E"
    label = "E-criterion, largest eigenvalue of C"

    def compute_value(self, info):
        w, _ = _positive_eigh(as_information(info))
        return float(1.0 / w[0])

    def compute_gradient(self, info):
        w, v = _positive_eigh(as_information(info))
        return -np.outer(v[:, 0], v[:, 0]) / w[0] ** 2

    def _batched_values(self, infos):
        lam_min = np.linalg.eigvalsh(infos)[:, 0]
        ok = lam_min > 0.0
        return 1.0 / np.where(ok, lam_min, 1.0), ok


# --------------------------------------------------- observability indices
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


# ----------------------------------------------------------------- factory
def make_criterion(name: str, *, kpi_jacobian=None, n_params: int | None = None,
                   kpi_weights=None) -> Criterion:
    """The criterion called ``name`` (one of :data:`CRITERIA`).

    Args:
        name: ``"kpi"``, ``"params"``, ``"D"``, ``"E"`` or ``"O1"`` .. ``"O5"``.
        kpi_jacobian: Unit-scaled KPI Jacobian :math:`G` (n_s, n_p)
            [mm/mm, mm/mrad]; needed by ``"kpi"``.
        n_params: Number of parameters :math:`n_p`; needed by ``"params"``
            (taken from ``kpi_jacobian`` when not given).
        kpi_weights: Weights of the KPI points for ``"kpi"`` (:meth:`ACriterion.kpi`);
            None: all 1.

    Raises:
        UnknownCriterionError: ``name`` is not in :data:`CRITERIA`.
        ValueError: ``"kpi"`` without ``kpi_jacobian``, ``"params"`` without
            ``n_params``.
    """
    if not isinstance(name, str) or name not in CRITERIA:
        raise UnknownCriterionError(name, CRITERIA)
    if name == "kpi":
        if kpi_jacobian is None:
            raise ValueError(
                "criterion 'kpi' needs kpi_jacobian=G, the unit-scaled KPI Jacobian "
                "(n_s, n_p) [mm/mm, mm/mrad]"
            )
        return ACriterion.kpi(kpi_jacobian, kpi_weights)
    if name == "params":
        if n_params is None and kpi_jacobian is not None:
            n_params = np.atleast_2d(kpi_jacobian).shape[1]
        if n_params is None:
            raise ValueError("criterion 'params' needs n_params, the number of parameters")
        return ACriterion.parameters(n_params)
    if name == "D":
        return DCriterion()
    if name == "E":
        return ECriterion()
    return ObservabilityIndex(int(name[1]))
