r"""The QP subproblem with a structured Hessian by a primal-dual interior-point method, O(n) per iteration.

Same QP as :mod:`calib_oed.solver.qp` (signs and multipliers there),

.. math::
    \min_d\ \tfrac12 d^\top H d + g^\top d \quad \text{s.t.} \quad C d \ge \ell,
    \quad \underline{b} \le d \le \overline{b},

with :math:`H = D + U U^\top`, :math:`D = \mathrm{blkdiag}(D_1, \dots, D_b) \succ 0`,
:math:`D_j \in \mathbb{R}^{s \times s}` (one pose), :math:`U \in \mathbb{R}^{n \times r}`
(:class:`~calib_oed.solver.result.StructuredHessian`). Mehrotra's
predictor-corrector method (Nocedal & Wright, *Numerical Optimization*, 2nd ed.,
2006, §16.6; Gertz & Wright, OOQP, *ACM TOMS* 29(1), 2003) with slacks
:math:`t = C d - \ell \ge 0` and the box distances :math:`d - \underline{b}`,
:math:`\overline{b} - d`. Each Newton step solves, after eliminating the slacks
and multipliers,

.. math::
    \bigl(D + \Sigma + C_\text{loc}^\top W_\text{loc} C_\text{loc} + V V^\top\bigr)\,\Delta d = r,
    \qquad V = [\,U,\ C_\times^\top W_\times^{1/2}\,],

:math:`W = \mathrm{diag}(\lambda_i / t_i)`, :math:`\Sigma` the box's diagonal.
A row whose nonzeros lie in one pose's :math:`s` columns (every row of the
design problem: joint limits, incidence, collisions of one pose) adds to that
pose's block, so :math:`B = D + \Sigma + C_\text{loc}^\top W C_\text{loc}` stays
block diagonal and is factored per block, :math:`O(b s^3)`; the coupling
:math:`U` and the rows :math:`C_\times` spanning several poses go through the
Woodbury identity with the :math:`(r + k_\times)^2` capacitance
:math:`I + V^\top B^{-1} V`: :math:`O(n (r + k_\times)^2)` per step, linear in
:math:`n` for fixed rows per pose. Two steps of iterative refinement against
the exact matrix keep the solve accurate when :math:`W` spans many decades
near the end.

The iteration stops when the dual residual is below ``eps_abs`` (times
:math:`\max(1, \|g\|_\infty)`), the rows' violation below ``eps_abs`` and
every complementarity product below ``eps_abs / 100``; then the multipliers of
rows and box sides with :math:`\lambda_i \le t_i` (inactive) are set to 0, so
:math:`\lambda > 0` marks the active set as ProxQP's answer does
(:mod:`calib_oed.solver.subproblem` keeps rows with :math:`\lambda > 0`).
The step's residuals are then computed as for every backend
(:meth:`~calib_oed.solver.qp.QPSubproblem.residuals`) and the SQP's own test
(:meth:`~calib_oed.solver.qp.QPStep.is_solved`) decides, as for ProxQP.
Status ``"solved"``, or ``"max_iter"`` after ``max_iter`` steps (an
infeasible QP: ProxQP does not flag those either, it runs to its limit),
or ``"primal_infeasible"`` when the multipliers diverge while the rows'
violation stays. An interior-point method has no use for a warm start: the
duals passed are ignored (:attr:`BlockQPWorkspace.warm_starts` is False, so
the caller does not retry cold).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from calib_oed.solver.qp import QPStep, QPSubproblem
from calib_oed.solver.result import StructuredHessian

_STEP_TO_BOUNDARY = 0.995
"""Fraction of the step to the boundary of the positive orthant taken (Nocedal & Wright §16.6)."""

_REFINE = 2
"""Iterative refinement steps of each Newton solve."""

_ACCEPT = 10.0
"""A stalled iteration's best point counts as solved with residuals up to this many ``eps_abs``
(scaled as in the stopping test): the SQP's own acceptance test allows ten (:mod:`calib_oed.solver.subproblem`)."""

_GAP_FLOOR = 1e-4
"""Complementarity below this many ``eps_abs``: the iteration stops with the best point seen."""

_STALLED = 1e-8
"""Step lengths below this: the iteration stops (it cannot improve in double precision)."""

_TINY = 1e-300
"""Floor of slacks and multipliers (kept positive through rounding)."""

_DIVERGED = 1e12
"""Multipliers above this with rows still violated: the QP is taken as infeasible."""


class _Rows:
    r"""The rows of :math:`G`, split into one-pose rows (local vectors, one slot each in their
    pose's stack) and the others (CSR)."""

    def __init__(self, C, b: int, s: int):
        C = sp.csr_matrix(C)
        C.sum_duplicates()
        self.C, self.CT = C, C.T.tocsr()
        k = C.shape[0]
        row_id = np.repeat(np.arange(k), np.diff(C.indptr))
        first, last = np.zeros(k, dtype=int), np.zeros(k, dtype=int)
        if C.nnz:  # the first and last pose each row touches (an empty row: pose 0)
            first[:] = b
            np.minimum.at(first, row_id, C.indices // s)
            np.maximum.at(last, row_id, C.indices // s)
            first[first == b] = 0
        local = first == last
        self.local, self.cross = np.flatnonzero(local), np.flatnonzero(~local)
        self.block = first[self.local]
        self.a = np.zeros((self.local.size, s))
        Cl = C[self.local]
        row_of = np.repeat(np.arange(self.local.size), np.diff(Cl.indptr))
        self.a[row_of, Cl.indices - self.block[row_of] * s] = Cl.data
        # slot of each local row among its pose's rows
        order = np.argsort(self.block, kind="stable")
        counts = np.bincount(self.block, minlength=b)
        self.slot = np.empty(self.local.size, dtype=int)
        self.slot[order] = np.arange(self.local.size) - np.repeat(np.cumsum(counts) - counts, counts)
        self.width = int(counts.max(initial=0))
        self.Cx = C[self.cross]

    def _active_transposed(self, z: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Per pose the active one-pose rows as columns (b, s, width) and the mask of active local rows."""
        s = self.a.shape[1]
        on = z[self.local] > 0
        At = np.zeros((b, s, max(self.width, 1)))
        At[self.block[on], :, self.slot[on]] = self.a[on]
        return At, on

    def null_space_step(self, H: StructuredHessian, rd: np.ndarray, z: np.ndarray) -> np.ndarray:
        r"""The Newton step on the QP with the active rows held, :math:`A_j \Delta d_j = 0`:
        :math:`\Delta d = N y`, :math:`(N^\top H N) y = -N^\top r_d`, with :math:`N = \mathrm{blkdiag}(N_j)`
        the per-pose null spaces of the active rows (SVD), so :math:`N^\top H N` is again blocks plus
        :math:`(N^\top U)(N^\top U)^\top`, solved as the Newton steps are. No huge weights: this
        gives the accuracy the interior steps lose to rounding near the end."""
        b, s, _ = H.blocks.shape
        At, _ = self._active_transposed(z, b)
        _, sv, vt = np.linalg.svd(At.transpose(0, 2, 1))
        sv_full = np.zeros((b, s))
        sv_full[:, :sv.shape[1]] = sv[:, :s]
        rank = (sv_full > 1e-10 * np.max(sv_full, axis=1, keepdims=True, initial=0.0)).sum(axis=1)
        keep = np.arange(s)[None, :] >= rank[:, None]
        N = vt.transpose(0, 2, 1) * keep[:, None, :]
        red = np.einsum("jai,jab,jbk->jik", N, H.blocks, N)
        red[:, np.arange(s), np.arange(s)] += ~keep
        U = H.low_rank if H.low_rank is not None else np.zeros((b * s, 0))
        V = np.einsum("jai,jar->jir", N, U.reshape(b, s, -1)).reshape(b * s, -1)
        y = _Newton(np.linalg.cholesky(red).transpose(0, 2, 1), V).solve(
            -np.einsum("jai,ja->ji", N, rd.reshape(b, s)).reshape(-1))
        return np.einsum("jai,ji->ja", N, y.reshape(b, s)).reshape(-1)

    def dual_correction(self, rd: np.ndarray, z: np.ndarray) -> np.ndarray:
        r""":math:`z + \delta z`, :math:`\delta z` on the active (:math:`z > 0`) one-pose rows minimising
        :math:`\|A_j^\top \delta z_j - r_{d,j}\|` pose by pose (:math:`r_d` the dual residual), kept :math:`\ge 0`."""
        s = self.a.shape[1]
        b = rd.size // s
        At, on = self._active_transposed(z, b)
        dz = np.einsum("jwa,ja->jw", np.linalg.pinv(At), rd.reshape(b, s))
        out = z.copy()
        out[self.local[on]] = np.maximum(z[self.local[on]] + dz[self.block[on], self.slot[on]], 0.0)
        return out

    def stack(self, chol_t: np.ndarray, w: np.ndarray) -> np.ndarray:
        r"""Per pose :math:`S_j = [L_j^\top;\ W_j^{1/2} A_j]` (b, s + width, s): :math:`S_j^\top S_j = D_j + A_j^\top W_j A_j`."""
        b, s, _ = chol_t.shape
        S = np.zeros((b, s + self.width, s))
        S[:, :s] = chol_t
        S[self.block, s + self.slot] = np.sqrt(w[self.local])[:, None] * self.a
        return S


class _Newton:
    r"""Factors of :math:`B + V V^\top` (module docstring) and solves with them.

    :math:`B_j = R_j^\top R_j` from the QR factorisation of the stack :math:`S_j`
    (:meth:`_Rows.stack`), not the Cholesky factorisation of the assembled
    :math:`D_j + A_j^\top W_j A_j`: near the end :math:`W` reaches 1e15 and the
    assembled block's rounding errors exceed its small eigenvalues (indefinite),
    while QR is backward stable on :math:`S_j`.
    """

    def __init__(self, S: np.ndarray, V: np.ndarray):
        self.S, self.V = S, V
        b, _, s = S.shape
        self.b, self.s = b, s
        self.R = np.linalg.qr(S, mode="r")
        self.RT = self.R.transpose(0, 2, 1)
        if V.shape[1]:
            Y = self._block_solve(V)
            cap = np.eye(V.shape[1]) + V.T @ Y
            self.Y, self.cap = Y, scipy.linalg.cho_factor(cap)

    def _block_solve(self, R: np.ndarray) -> np.ndarray:
        b, s = self.b, self.s
        Z = np.linalg.solve(self.RT, R.reshape(b, s, -1))
        return np.linalg.solve(self.R, Z).reshape(R.shape)

    def _apply(self, x: np.ndarray) -> np.ndarray:
        b, s = self.b, self.s
        out = np.einsum("jra,jr->ja", self.S, np.einsum("jra,ja->jr", self.S, x.reshape(b, s))).reshape(-1)
        if self.V.shape[1]:
            out += self.V @ (self.V.T @ x)
        return out

    def _solve_once(self, r: np.ndarray) -> np.ndarray:
        x = self._block_solve(r)
        if self.V.shape[1]:
            x -= self.Y @ scipy.linalg.cho_solve(self.cap, self.V.T @ x)
        return x

    def solve(self, r: np.ndarray) -> np.ndarray:
        """:math:`(B + V V^\top)^{-1} r` by Woodbury, with iterative refinement."""
        x = self._solve_once(r)
        for _ in range(_REFINE):
            x += self._solve_once(r - self._apply(x))
        return x


def _max_step(v: np.ndarray, dv: np.ndarray) -> float:
    """Largest :math:`\\alpha \\le 1` with :math:`v + \\alpha\\, dv \\ge 0` (``v > 0``)."""
    neg = dv < 0
    return float(min(1.0, np.min(-v[neg] / dv[neg], initial=np.inf)))


class BlockQPWorkspace:
    """Interior-point solver of a QP with a :class:`StructuredHessian` (module docstring)."""

    warm_starts = False

    def __init__(self, n: int, eps_abs: float, max_iter: int):
        self.n, self.eps_abs, self.max_iter = n, eps_abs, max_iter

    def solve(self, sub: QPSubproblem, d0=None, lam0=None, nu0=None) -> QPStep:  # noqa: ARG002 (no warm start)
        r"""Solve ``sub`` (``sub.H`` a :class:`StructuredHessian`); the guesses are ignored.

        The finite box sides join the rows, :math:`G = [C; I_\text{lo}; -I_\text{hi}]`,
        :math:`G d - h = t \ge 0`, each a one-pose row.
        """
        H: StructuredHessian = sub.H
        b, s, _ = H.blocks.shape
        n = b * s
        U = H.low_rank if H.low_rank is not None else np.zeros((n, 0))
        k = sub.lower.size
        lo, hi = np.asarray(sub.box_lower, float), np.asarray(sub.box_upper, float)
        i_lo, i_hi = np.flatnonzero(np.isfinite(lo)), np.flatnonzero(np.isfinite(hi))
        eye = sp.identity(n, format="csr")
        C = sp.csr_matrix(sub.C) if k else sp.csr_matrix((0, n))
        rows = _Rows(sp.vstack([C, eye[i_lo], -eye[i_hi]], format="csr"), b, s)
        G, GT = rows.C, rows.CT
        h = np.concatenate([np.asarray(sub.lower, float), lo[i_lo], -hi[i_hi]])
        g = np.asarray(sub.g, float)
        m = h.size
        chol_t = np.linalg.cholesky(H.blocks).transpose(0, 2, 1)
        # start: inside the box, slacks and multipliers of order one
        width = np.where(np.isfinite(lo) & np.isfinite(hi), hi - lo, np.inf)
        d = np.clip(np.zeros(n), lo + np.minimum(0.1 * width, 1.0), hi - np.minimum(0.1 * width, 1.0))
        t = np.maximum(G @ d - h, 1.0)
        z = np.ones(m)
        tol_d = self.eps_abs * max(1.0, float(np.max(np.abs(g), initial=0.0)))
        status, it, best, best_err = "max_iter", 0, None, np.inf
        for it in range(1, self.max_iter + 1):
            rd = H @ d + g - GT @ z
            rp = G @ d - t - h
            viol = float(np.max(np.abs(rp), initial=0.0))
            gap = float(np.max(t * z, initial=0.0))
            if viol <= self.eps_abs and gap <= self.eps_abs:
                step = self._step(sub, d, t, z, k, i_lo, i_hi, status, it, rows, H, g)
                err = max(step.primal_residual / self.eps_abs, step.dual_residual / tol_d,
                          step.complementarity / self.eps_abs)
                if err <= 1.0:
                    return step._replace(status="solved")
                if err < best_err:
                    best, best_err = step, err
                if gap <= _GAP_FLOOR * self.eps_abs:  # complementarity beyond need: rounding only from here
                    break
            if float(np.max(z, initial=0.0)) > _DIVERGED and viol > self.eps_abs:
                status = "primal_infeasible"
                break
            mu = (t @ z) / max(m, 1)
            w = z / t
            V = U
            if rows.cross.size:
                V = np.hstack([U, (rows.Cx.T.multiply(np.sqrt(w[rows.cross]))).toarray()])
            newton = _Newton(rows.stack(chol_t, w), V)

            def direction(r_c, newton=newton, rd=rd, rp=rp, t=t, z=z):
                dd = newton.solve(-rd - GT @ ((r_c + z * rp) / t))
                dt = G @ dd + rp
                return dd, dt, -(r_c + z * dt) / t

            # predictor (affine scaling), then Mehrotra's centring and corrector
            dd, dt, dz = direction(t * z)
            ap, ad = _max_step(t, dt), _max_step(z, dz)
            mu_aff = ((t + ap * dt) @ (z + ad * dz)) / max(m, 1)
            sigma = (mu_aff / mu) ** 3 if mu > 0 else 0.0
            dd, dt, dz = direction(t * z + dt * dz - sigma * mu)
            ap = _STEP_TO_BOUNDARY * _max_step(t, dt)
            ad = _STEP_TO_BOUNDARY * _max_step(z, dz)
            if max(ap, ad) < _STALLED:  # rounding now dominates the Newton steps
                break
            d, t, z = d + ap * dd, np.maximum(t + ap * dt, _TINY), np.maximum(z + ad * dz, _TINY)
        if best is not None:  # the SQP holds the step to 10 eps_abs (scaled): its own test decides
            return best._replace(status="solved" if best_err <= _ACCEPT else status, iterations=it)
        return self._step(sub, d, t, z, k, i_lo, i_hi, status, it, rows, H, g)

    @staticmethod
    def _step(sub, d, t, z, k, i_lo, i_hi, status, it, rows=None, H=None, g=None) -> QPStep:
        r"""The step with the multipliers of inactive rows and box sides (:math:`z \le t`) set to 0;
        polished on that active set (:meth:`_Rows.null_space_step`, :meth:`_Rows.dual_correction`)
        where that lowers the largest residual."""
        z = np.where(z > t, z, 0.0)

        def record(d, z):
            nu = np.zeros(d.size)
            nu[i_lo] += z[k:k + i_lo.size]
            nu[i_hi] -= z[k + i_lo.size:]
            primal, dual, comp = sub.residuals(d, z[:k], nu)
            return QPStep(d, z[:k], nu, status, it, primal, dual, comp)

        step = record(d, z)
        if rows is not None and not np.any(z[rows.cross] > 0):
            d2 = d + rows.null_space_step(H, H @ d + g - rows.CT @ z, z)
            polished = record(d2, rows.dual_correction(H @ d2 + g - rows.CT @ z, z))
            if max(polished[5:8]) < max(step[5:8]):
                return polished
        return step
