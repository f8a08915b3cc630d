r"""The design-criterion interface and what every criterion shares: checks and factorisations.

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

This module owns :class:`Criterion` and the helpers its implementations
share (validation of :math:`M`, Cholesky and eigen-factorisations, batched
too). The A, D and E criteria and :func:`~calib_oed.oed.criteria.make_criterion`
are in :mod:`calib_oed.oed.criteria`, the observability indices in
:mod:`calib_oed.oed.observability`.
"""

from __future__ import annotations

import abc

import numpy as np
import scipy.linalg

from calib_oed.exceptions import NonFiniteError, NotIdentifiableError, ShapeError

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
    return _symmetrised(np.array(info, dtype=float), 2, what, "(n_p, n_p)")


def _as_informations(infos, what: str = "information matrices") -> np.ndarray:
    """:func:`as_information` of a stack (k, n_p, n_p)."""
    return _symmetrised(np.asarray(infos, dtype=float), 3, what, "(k, n_p, n_p)")


def _symmetrised(m: np.ndarray, ndim: int, what: str, expected: str) -> np.ndarray:
    if m.ndim != ndim or m.shape[-1] != m.shape[-2] or m.shape[-1] == 0:
        raise ShapeError(what, expected, m.shape)
    if not np.all(np.isfinite(m)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(m)).tolist())
    if m.size:
        _check_symmetric(m, what)
    return 0.5 * (m + np.swapaxes(m, -1, -2))


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
        name: Short name (one of :data:`calib_oed.oed.criteria.CRITERIA` for the shipped ones).
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

