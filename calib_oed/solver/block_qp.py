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

Once the rows' violation and every complementarity product are below
``eps_abs``, the active set :math:`\{i : \lambda_i > t_i\}` is polished
(:meth:`_Rows.polish`): the exact KKT point with those rows and box sides held
as equalities, by per-pose null spaces and the same Woodbury solve, :math:`O(n)`,
no interior-point weights in it (as OSQP's solution polishing, Stellato et al.,
*Math. Prog. Comp.* 12, 2020, §5, and :mod:`calib_oed.solver.polish` for the
dense QPs). Of the point and its polish the one with the smaller residuals is
kept; the iteration returns it as ``"solved"`` when its primal and
complementarity residuals are below ``eps_abs`` and its dual residual below
``eps_abs`` times :math:`\max(1, \|g\|_\infty)`, and otherwise goes on until
complementarity falls below ``1e-4 eps_abs`` (then the best point seen counts
as solved up to ten times those tolerances, the SQP's own acceptance). Without
the polish the dual residual stopped near 4e-8 on the design QPs, whose
Hessian has directions of curvature 1e-8 (its eigenvalue floor), above the
SQP's 1e-8. :math:`\lambda > 0` marks the active set as ProxQP's answer does
(:mod:`calib_oed.solver.subproblem` keeps rows with :math:`\lambda > 0`).
The step's residuals are computed as for every backend
(:meth:`~calib_oed.solver.qp.QPSubproblem.residuals`) and the SQP's own test
(:meth:`~calib_oed.solver.qp.QPStep.is_solved`) decides, as for ProxQP.
Status ``"solved"``, or ``"max_iter"`` after ``max_iter`` steps (an
infeasible QP: ProxQP does not flag those either, it runs to its limit),
or ``"primal_infeasible"`` when the multipliers diverge while the rows'
violation stays.

**Warm start by the active set.** An interior-point method has no use for a
starting point, but the duals passed (the previous QP's multipliers: the last
SQP iteration's, or the QP of the step a second-order correction re-solves with
shifted constants) name an active set. That set is polished first; if its KKT
point passes the residual test above, it is the answer, without an interior-point
iteration (about one Newton step of work instead of 15-30). Otherwise the interior
point runs from its own start, so a wrong guess costs one polish. Near an SQP's
solution the active set settles, and the second-order correction's set is
nearly always the step's own.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.optimize
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

_POLISH_FROM = 1e5
"""The active set is polished (:meth:`_Rows.polish`) once violation and complementarity are below this many ``eps_abs``."""

_POLISH_ROUNDS = 20
r"""Rounds of a polish's active-set exchange: rows its point violates join (weakly active rows the
interior point's :math:`\lambda > t` missed: 275, 22, 2, 0 on a captured n = 500 design QP), rows
with negative multipliers leave; another captured n = 500 QP needed 9 rounds (3 rounds, before,
left 10 of 12 such QPs unsolved at a dual residual of 2e-8 to 1e-7)."""

_RANK_TOL = 1e-7
"""Singular values of a pose's active rows below this times the largest: dependent rows (a kinked
row and its piece differ by ~1e-9 where both are active; taken as two, their multipliers reach 1e5)."""

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

    def polish(self, H: StructuredHessian, g: np.ndarray, h: np.ndarray, act: np.ndarray,
               vtol: float, z0: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        r"""The exact KKT point of the QP with the rows ``act`` held as equalities, :math:`(d, z)`,
        or None (a row spanning poses is active, or the active set keeps growing).

        Per pose the active rows :math:`A_j` (box sides included) have the SVD
        :math:`A_j = P_j \Sigma_j Q_j^\top`; with :math:`Q_j = [R_j\ N_j]` split at its rank
        (singular values above ``_RANK_TOL`` times the largest),
        :math:`d = d_p + N y`, :math:`d_{p,j} = R_j \Sigma_j^{-1} P_j^\top h_j` (least norm on
        :math:`A_j d_j = h_j`) and

        .. math::
            (N^\top H N)\, y = -N^\top (H d_p + g), \qquad
            z_j = z_{0,j} + P_j \Sigma_j^{-1} R_j^\top \bigl((H d + g)_j - A_j^\top z_{0,j}\bigr),

        :math:`N^\top H N = \mathrm{blkdiag}(N_j^\top D_j N_j) + (N^\top U)(N^\top U)^\top`,
        factored per pose with Woodbury as the Newton steps are: :math:`O(n)`, and no
        interior-point weights, so the residuals are those of one well-scaled solve (the
        interior point's stop near 4e-8 on directions of curvature 1e-8 does not occur).
        Where a pose's active rows are dependent (a kinked row and its piece, a row along a
        box side) the multipliers are not unique: :math:`z_j` is the one nearest to the
        interior point's :math:`z_0`, and where that one is negative, nonnegative least squares
        (Lawson & Hanson) picks nonnegative ones if there are. Rows the point violates by more
        than ``vtol`` join ``act``, as in :func:`calib_oed.solver.polish.polish`, and rows held
        with a multiplier below ``-vtol`` leave it (a primal-dual active-set exchange, up to
        ``_POLISH_ROUNDS`` rounds; the caller's residual test decides whether the last point is the
        QP's solution). None if the rows held are inconsistent (more of
        them on a pose than it has variables, least squares not meeting them); negative
        multipliers are set to 0 and show in the dual residual the caller checks.
        """
        if np.any(act[self.cross]):
            return None
        b, s, _ = H.blocks.shape
        U = H.low_rank if H.low_rank is not None else np.zeros((b * s, 0))
        act = act.copy()
        for _ in range(_POLISH_ROUNDS):
            on = act[self.local]
            width = max(self.width, 1)
            A = np.zeros((b, width, s))
            A[self.block[on], self.slot[on]] = self.a[on]
            hj = np.zeros((b, width))
            hj[self.block[on], self.slot[on]] = h[self.local[on]]
            p, sv, qt = np.linalg.svd(A)
            sv_full = np.zeros((b, s))
            sv_full[:, :sv.shape[1]] = sv[:, :s]
            top = np.max(sv_full, axis=1, keepdims=True, initial=0.0)
            keep = sv_full > _RANK_TOL * top  # the range of A_j^T, per pose
            inv = np.where(keep, 1.0 / np.where(keep, sv_full, 1.0), 0.0)
            q = qt.transpose(0, 2, 1)  # (b, s, s), columns Q_j
            m = min(width, s)
            d_p = np.einsum("jai,ji,jwi,jw->ja", q[:, :, :m], inv[:, :m], p[:, :, :m], hj)
            N = q * ~keep[:, None, :]
            red = np.einsum("jai,jab,jbk->jik", N, H.blocks, N)
            red[:, np.arange(s), np.arange(s)] += keep
            V = np.einsum("jai,jar->jir", N, U.reshape(b, s, -1)).reshape(b * s, -1)
            rhs = -np.einsum("jai,ja->ji", N, (H @ d_p.reshape(-1) + g).reshape(b, s)).reshape(-1)
            y = _Newton(np.linalg.cholesky(red).transpose(0, 2, 1), V).solve(rhs)
            d = (d_p + np.einsum("jai,ji->ja", N, y.reshape(b, s))).reshape(-1)
            grad = (H @ d + g).reshape(b, s)
            z0j = np.zeros((b, width))
            z0j[self.block[on], self.slot[on]] = z0[self.local[on]]
            zj = z0j + np.einsum("jwi,ji,jai,ja->jw", p[:, :, :m], inv[:, :m], q[:, :, :m],
                                 grad - np.einsum("jwa,jw->ja", A, z0j))
            # dependent rows: the nearest multipliers may be negative where nonnegative ones exist
            dependent = keep.sum(axis=1) < np.count_nonzero(np.any(A != 0, axis=2), axis=1)
            for j in np.flatnonzero(dependent & np.any(zj < 0, axis=1)):
                zj[j] = scipy.optimize.nnls(A[j].T, grad[j])[0]
            z = np.zeros(h.size)
            z_raw = zj[self.block[on], self.slot[on]]
            z[self.local[on]] = np.maximum(z_raw, 0.0)
            slack = self.C @ d - h
            # inconsistent rows held: no KKT point here (a row and its piece may differ by ~1e-9 in
            # their constants: least squares meets both to half that, which the acceptance allows)
            if np.any(np.abs(slack[act]) > _ACCEPT * vtol):
                return None
            new = (slack < -vtol) & ~act
            if new.any():
                act |= new
                continue
            # rows held with a negative multiplier are not active at the KKT point: release them
            negative = self.local[on][z_raw < -vtol]
            if not negative.size:
                return d, z
            act[negative] = False
        return d, z  # the last point: its residuals decide

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
        self.S, self.ST, self.V = S, S.transpose(0, 2, 1), V
        b, _, s = S.shape
        self.b, self.s = b, s
        self.R = np.linalg.qr(S, mode="r")
        # the blocks' inverse triangular factors, once: applying them is a batched product, six
        # times faster than a batched solve per use; iterative refinement absorbs their rounding
        self.Ri = np.linalg.inv(self.R)
        self.RiT = self.Ri.transpose(0, 2, 1)
        if V.shape[1]:
            Y = self._block_solve(V)
            cap = np.eye(V.shape[1]) + V.T @ Y
            self.Y, self.cap = Y, scipy.linalg.cho_factor(cap)

    def _block_solve(self, R: np.ndarray) -> np.ndarray:
        b, s = self.b, self.s
        return (self.Ri @ (self.RiT @ R.reshape(b, s, -1))).reshape(R.shape)

    def _apply(self, x: np.ndarray) -> np.ndarray:
        b, s = self.b, self.s
        out = (self.ST @ (self.S @ x.reshape(b, s, 1))).reshape(-1)
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


def _root(blocks: np.ndarray) -> np.ndarray:
    r"""Per block a square root :math:`L_j^\top` with :math:`L_j L_j^\top = D_j`: Cholesky, or where a
    block is only semidefinite in rounding (a BFGS block with an eigenvalue of -6e-16 made
    ``cholesky`` raise at n = 500), :math:`\Lambda_+^{1/2} Q^\top` from its eigenvalues clipped at 0.
    The box rows keep every Newton matrix :math:`S_j^\top S_j` definite."""
    try:
        return np.linalg.cholesky(blocks).transpose(0, 2, 1)
    except np.linalg.LinAlgError:
        lam, q = np.linalg.eigh(blocks)
        return np.sqrt(np.maximum(lam, 0.0))[:, :, None] * q.transpose(0, 2, 1)


def _max_step(v: np.ndarray, dv: np.ndarray) -> float:
    """Largest :math:`\\alpha \\le 1` with :math:`v + \\alpha\\, dv \\ge 0` (``v > 0``)."""
    neg = dv < 0
    return float(min(1.0, np.min(-v[neg] / dv[neg], initial=np.inf)))


class BlockQPWorkspace:
    """Interior-point solver of a QP with a :class:`StructuredHessian` (module docstring)."""

    def __init__(self, n: int, eps_abs: float, max_iter: int):
        self.n, self.eps_abs, self.max_iter = n, eps_abs, max_iter

    def solve(self, sub: QPSubproblem, d0=None, lam0=None, nu0=None) -> QPStep:  # noqa: ARG002 (no primal start)
        r"""Solve ``sub`` (``sub.H`` a :class:`StructuredHessian`), first by the active set of the duals.

        With dual guesses ``lam0`` (rows, k) and ``nu0`` (box, n; positive on the lower side,
        negative on the upper, as :class:`~calib_oed.solver.qp.QPStep` gives them), the rows and box
        sides with a positive guess are polished as the active set (:meth:`_Rows.polish`, O(n), about
        one Newton step); if that point passes the same residual test as the interior point's
        (primal, dual, complementarity below ``eps_abs``, the dual scaled), it is the answer, with
        0 iterations: the KKT point of this convex QP, as the interior point would have polished it.
        Otherwise, or without guesses, the interior point method from its own start. ``d0`` is ignored.

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
        chol_t = _root(H.blocks)
        # start: inside the box, slacks and multipliers of order one
        width = np.where(np.isfinite(lo) & np.isfinite(hi), hi - lo, np.inf)
        d = np.clip(np.zeros(n), lo + np.minimum(0.1 * width, 1.0), hi - np.minimum(0.1 * width, 1.0))
        t = np.maximum(G @ d - h, 1.0)
        z = np.ones(m)
        tol_d = self.eps_abs * max(1.0, float(np.max(np.abs(g), initial=0.0)))
        box = (hi - lo)[np.isfinite(hi - lo)]
        vtol = min(self.eps_abs, 1e-3 * float(np.min(box))) if box.size else self.eps_abs

        def finish(d, t, z, status, it, polish=True, polish_only=None):
            """``(step, err)``: the better of the point and its polish on the active set
            :math:`z > t` (:meth:`_Rows.polish`), err its largest residual in tolerances;
            with ``polish_only``, the polish on that set alone (None if there is none)."""
            out, polished_dz = None, None
            if polish:
                try:
                    polished_dz = rows.polish(H, g, h, z > t if polish_only is None else polish_only, vtol, z)
                except (np.linalg.LinAlgError, RuntimeError, ValueError):  # a failed polish leaves the point
                    polished_dz = None
            candidates = (polished_dz,) if polish_only is not None else (polished_dz, (d, np.where(z > t, z, 0.0)))
            for dz in candidates:
                if dz is None:
                    continue
                nu = np.zeros(n)
                nu[i_lo] += dz[1][k:k + i_lo.size]
                nu[i_hi] -= dz[1][k + i_lo.size:]
                primal, dual, comp = sub.residuals(dz[0], dz[1][:k], nu)
                err = max(primal / self.eps_abs, dual / tol_d, comp / self.eps_abs)
                if out is None or err < out[1]:
                    out = QPStep(dz[0], dz[1][:k], nu, status, it, primal, dual, comp), err
                if err <= 1.0:
                    break
            return out

        if lam0 is not None or nu0 is not None:  # the guessed active set, verified like any polish
            z0 = np.zeros(m)
            if lam0 is not None and np.size(lam0) == k:
                z0[:k] = np.maximum(np.asarray(lam0, float), 0.0)
            if nu0 is not None and np.size(nu0) == n:
                nu0 = np.asarray(nu0, float)
                z0[k:k + i_lo.size] = np.maximum(nu0[i_lo], 0.0)
                z0[k + i_lo.size:] = np.maximum(-nu0[i_hi], 0.0)
            act = z0 > 0
            if act.any():
                warm = finish(d, np.ones(m), z0, "solved", 0, polish_only=act)
                if warm is not None and warm[1] <= 1.0:
                    return warm[0]._replace(status="solved")
        status, it, best, best_err, last_act, polished = "max_iter", 0, None, np.inf, None, False
        for it in range(1, self.max_iter + 1):
            rd = H @ d + g - GT @ z
            rp = G @ d - t - h
            viol = float(np.max(np.abs(rp), initial=0.0))
            gap = float(np.max(t * z, initial=0.0))
            if viol <= _POLISH_FROM * self.eps_abs and gap <= _POLISH_FROM * self.eps_abs:
                # polished once it stops changing (a polish costs about a Newton step), and at the end
                act = z > t
                polished = np.array_equal(act, last_act) or gap <= _GAP_FLOOR * self.eps_abs
                step, err = finish(d, t, z, status, it, polished)
                last_act = act
                if err <= 1.0:
                    return step._replace(status="solved")
                if err < best_err:
                    best, best_err = step, err
                if gap <= _GAP_FLOOR * self.eps_abs:  # complementarity beyond need: rounding only from here
                    break
            polished = False
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
        if not polished:  # the last point, polished, unless that was just done
            step, err = finish(d, t, z, status, it)
            if err < best_err:
                best, best_err = step, err
        # the SQP holds the step to 10 eps_abs (scaled): its own test decides
        solved = best_err <= _ACCEPT and status != "primal_infeasible"
        return best._replace(status="solved" if solved else status, iterations=it)
