r"""Infeasible QP subproblems: rows no step can reach, and the elastic restoration QP.

At an infeasible iterate the linearised rows :math:`C d \ge \ell` may have
no solution in the box :math:`[\underline{b}, \overline{b}]`; ProxQP does not
detect this (:mod:`calib_oed.solver.qp`). :func:`unreachable_rows` finds the
obvious cases in :math:`O(\text{nnz})`, and :func:`solve_elastic_qp` gives the
feasibility-restoration step of the SQP (:mod:`calib_oed.solver.sqp`, item 5).
"""

from __future__ import annotations

import numpy as np
import proxsuite
import scipy.sparse as sp

from calib_oed.solver.qp import QPStep, QPSubproblem, _configure, _finish


def unreachable_rows(C, lower, box_lower, box_upper, tol: float) -> np.ndarray:
    r"""Rows that no :math:`d` in the box can satisfy: :math:`\max_{d \in \text{box}} C_i d < \ell_i - \text{tol}`.

    :math:`\max_{d} C_i d = \sum_j \max(C_{ij} \underline{b}_j, C_{ij} \overline{b}_j)`,
    one pass over the nonzeros. Any such row makes the QP infeasible; finding
    it here spares ProxQP, which does not detect infeasibility and would run
    to its iteration limit.
    """
    def best(a, cols):
        with np.errstate(invalid="ignore"):
            return np.where(a > 0, a * box_upper[cols], np.where(a < 0, a * box_lower[cols], 0.0))

    if sp.issparse(C):
        C = sp.csr_matrix(C)
        vals = best(C.data, C.indices)
        reach = np.asarray(sp.csr_matrix((vals, C.indices, C.indptr), shape=C.shape).sum(axis=1)).ravel()
    else:
        C = np.asarray(C, dtype=float)
        reach = best(C, np.arange(C.shape[1])[None, :]).sum(axis=1) if C.size else np.zeros(C.shape[0])
    return np.flatnonzero(reach < lower - tol)


def solve_elastic_qp(C, lower, violated, box_lower, box_upper, penalty: float,
                     eps_abs: float, max_iter: int) -> QPStep:
    r"""Feasibility-restoration step: the elastic QP.

    .. math::
        \min_{d, s} \tfrac12 \|d\|_2^2 + \rho \sum_{i \in V} s_i
        \quad \text{s.t.} \quad C_i d + s_i \ge \ell_i \;(i \in V), \quad
        C_i d \ge \ell_i \;(i \notin V), \quad s \ge 0, \quad
        \underline{b} \le d \le \overline{b},

    with :math:`V` the rows violated at the current point
    (:math:`\ell_i > 0`, i.e. :math:`c_i < 0`). It is always feasible
    (:math:`d = 0`, :math:`s_i = \ell_i`), and for large :math:`\rho` its
    :math:`d` is the shortest step minimising the linearised :math:`\ell_1`
    violation inside the box (the elastic mode of Nocedal & Wright,
    *Numerical Optimization*, 2nd ed., §18.3, with the proximal term
    :math:`\tfrac12\|d\|^2` in place of the Hessian model). A term
    :math:`10^{-8} \|s\|^2` keeps the Hessian definite. Its Hessian is
    diagonal and its rows sparse, so it goes to ProxQP's sparse backend (the
    box as identity rows). Returns :math:`d` (slacks dropped) and the
    multipliers of the rows.
    """
    C = sp.csr_matrix(C)
    k, n = C.shape
    idx = np.flatnonzero(violated)
    nv = idx.size
    E = sp.csr_matrix((np.ones(nv), (idx, np.arange(nv))), shape=(k, nv))
    H = sp.diags(np.concatenate([np.ones(n), np.full(nv, 1e-8)])).tocsc()
    g = np.concatenate([np.zeros(n), np.full(nv, penalty)])
    CC = sp.hstack([C, E], format="csr")
    bl = np.concatenate([box_lower, np.zeros(nv)])
    bu = np.concatenate([box_upper, np.full(nv, np.inf)])
    stacked = sp.vstack([CC, sp.identity(n + nv, format="csr")], format="csc")
    qp = proxsuite.proxqp.sparse.QP(n + nv, 0, k + n + nv)
    _configure(qp, eps_abs, max_iter)
    qp.init(H, g, None, None, stacked, np.concatenate([lower, bl]),
            np.concatenate([np.full(k, np.inf), bu]))
    qp.solve()
    r = qp.results
    sub = QPSubproblem(H, g, CC, np.asarray(lower, dtype=float), bl, bu)
    full = _finish(sub, r.x, r.z[:k], r.z[k:], r.info)
    return full._replace(d=full.d[:n], lam=full.lam[:k], nu=full.nu[:n])
