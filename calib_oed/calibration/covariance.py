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

Only this explicit form is computed; why it is the paper's KKT covariance
(eq. 19): ``docs/derivations.md`` §9–10.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from calib_oed.exceptions import NotIdentifiableError, ShapeError


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
