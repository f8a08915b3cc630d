r"""The exact Hessian of a design criterion in the configurations, in factored form.

For :math:`\phi(q) = \Phi(M(q))`, :math:`M = M_0 + \sum_j \tilde F_j^\top\tilde F_j`,
:math:`x = \mathrm{vec}(q)` pose-major, index :math:`a = (j, k)` (pose j, joint k):

.. math::
    \frac{\partial^2\phi}{\partial x_a\,\partial x_b}
      = \underbrace{\nabla^2\Phi(M)[M_a, M_b]}_{U U^\top}
      + \underbrace{\mathrm{tr}(\Gamma\,M_{ab})}_{\text{pose blocks}},
    \qquad \Gamma = \partial\Phi/\partial M .

:math:`M_{ab} = 0` unless a and b are joints k, l of the same pose, and then
:math:`\mathrm{tr}(\Gamma M_{ab}) = 2\langle\tilde F_j\Gamma, \partial_{kl}\tilde F_j\rangle
+ 2\langle\partial_k\tilde F_j\,\Gamma, \partial_l\tilde F_j\rangle` (symmetric, indefinite).
The coupling factors through :math:`M = LL^\top` (:math:`C = M^{-1} = RR^\top`,
:math:`R = L^{-\top}`):

- A, :math:`\Phi = \mathrm{tr}(WC)/k`, :math:`W = \sum_i w_i w_i^\top`
  (``ACriterion.root`` rows), :math:`v_i = C w_i`:
  :math:`\nabla^2\Phi[A, B] = \tfrac2k\,\mathrm{tr}(P A C B) = \tfrac2k\sum_i (R^\top A v_i)\cdot(R^\top B v_i)`,
  :math:`P = CWC`; column :math:`(i, f)` of :math:`U` is :math:`\sqrt{2/k}\,(L^{-1} M_a v_i)_f`.
- D, :math:`\Phi = -\log\det M`: :math:`\nabla^2\Phi[A, B] = \mathrm{tr}(CACB) = \langle S_A, S_B\rangle_F`,
  :math:`S_A = L^{-1} A L^{-\top}` symmetric; columns: its diagonal and
  :math:`\sqrt2` times its strict upper triangle.

:math:`U` has :math:`r_W n_f` columns for A (:math:`r_W` = rows of the root:
3 per KPI point, :math:`n_f` for ``params``) and :math:`n_f(n_f+1)/2` for D,
whatever the number of poses; it is returned as is (a thin QR of
:math:`U^\top` would cap the columns at :math:`n n_v` when that is smaller).
``docs/derivations.md`` §13.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from calib_oed.oed.criteria import ACriterion, DCriterion
from calib_oed.oed.criterion_base import Criterion, _cholesky
from calib_oed.oed.model_error_hessian import covers
from calib_oed.solver.result import StructuredHessian


def has_exact_hessian(criterion: Criterion) -> bool:
    """Whether :func:`structured_hessian` covers ``criterion`` (the A and D criteria), or
    :func:`calib_oed.oed.model_error_hessian.design_hessian` does (``kpi_model``, joint-space prior)."""
    return isinstance(criterion, (ACriterion, DCriterion)) or covers(criterion)


def pose_blocks(gamma: np.ndarray, rows: np.ndarray, d_rows: np.ndarray,
                dd_rows: np.ndarray) -> np.ndarray:
    r""":math:`\mathrm{tr}(\Gamma M_{ab})` per pose, (n, nv, nv), symmetric.

    ``rows`` :math:`\tilde F_j` (n, d, n_f), ``d_rows`` (n, d, n_f, nv),
    ``dd_rows`` :math:`\partial_{kl}\tilde F_j` (n, d, n_f, nv, nv).
    """
    n, d, nf, nv = d_rows.shape
    fg = (rows @ gamma).reshape(n, 1, d * nf)
    out = (fg @ dd_rows.reshape(n, d * nf, nv * nv)).reshape(n, nv, nv)
    per_joint = np.moveaxis(d_rows, 3, 1).reshape(n, nv, d, nf)  # (n, k, d, nf)
    out += (per_joint @ gamma).reshape(n, nv, -1) @ per_joint.reshape(n, nv, -1).transpose(0, 2, 1)
    return out + np.transpose(out, (0, 2, 1))  # 2 x the symmetric part


def coupling_factor(criterion: Criterion, info: np.ndarray, rows: np.ndarray,
                    d_rows: np.ndarray) -> np.ndarray:
    r""":math:`U` with :math:`UU^\top = \nabla^2\Phi(M)[M_a, M_b]`, (n nv, r) (module docstring).

    Both criteria use the whitened rows :math:`B = \tilde F_j L^{-\top}` and
    :math:`B_k = \partial_k\tilde F_j L^{-\top}`, for which
    :math:`L^{-1}M_a = B^\top\partial_k\tilde F_j + B_k^\top\tilde F_j`.
    """
    n, d, nf, nv = d_rows.shape
    low = _cholesky(info)  # NotIdentifiableError when M is singular
    inv_t = scipy.linalg.solve_triangular(low, np.eye(nf), lower=True, check_finite=False).T
    per_joint = np.moveaxis(d_rows, 3, 1)  # (n, k, d, nf)
    white = rows @ inv_t  # B (n, d, nf)
    d_white = per_joint @ inv_t  # B_k (n, k, d, nf)
    white_t = np.swapaxes(white, 1, 2)[:, None]  # B^T (n, 1, nf, d)
    if isinstance(criterion, ACriterion):
        v = scipy.linalg.cho_solve((low, True), criterion.root.T, check_finite=False)  # (nf, r)
        # L^-1 M_a v = B^T (F_k v) + B_k^T (F v), (n, k, nf, r)
        z = white_t @ (per_joint @ v) + np.swapaxes(d_white, 2, 3) @ (rows @ v)[:, None]
        return z.reshape(n * nv, -1) * np.sqrt(2.0 / criterion.dim)
    if isinstance(criterion, DCriterion):
        half = white_t @ d_white  # B^T B_k, (n, k, nf, nf)
        s = (half + np.swapaxes(half, 2, 3)).reshape(n * nv, nf, nf)
        iu = np.triu_indices(nf, 1)
        return np.concatenate([np.diagonal(s, axis1=1, axis2=2), np.sqrt(2.0) * s[:, iu[0], iu[1]]],
                              axis=1)
    raise TypeError(f"no exact Hessian for the {criterion.name} criterion")


def structured_hessian(criterion: Criterion, info: np.ndarray, rows: np.ndarray,
                       d_rows: np.ndarray, dd_rows: np.ndarray) -> StructuredHessian:
    r"""The exact :math:`\nabla^2_x\phi` as blkdiag(pose blocks) + :math:`UU^\top` (module docstring)."""
    gamma = np.asarray(criterion.compute_gradient(info))
    return StructuredHessian(pose_blocks(gamma, rows, d_rows, dd_rows),
                             coupling_factor(criterion, info, rows, d_rows))
