r"""Active-set polish of a ProxQP step: the exact KKT point on the identified active set.

Near convergence the SQP step is small and ProxQP's ~1e-9 error matters
(:mod:`calib_oed.solver.qp` for the subproblem and sign conventions);
:func:`polish` re-solves the equality-constrained KKT system on the active
rows and fixed box components, as OSQP's solution polishing does.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from calib_oed.solver.qp import QPStep, QPSubproblem, as_dense, matvec


def _solve_kkt(kkt, rhs, singular_ok: bool = True):
    """Solve the symmetric KKT system; least squares if it is singular (degenerate active set).

    With more active constraints than free variables (a tiny trust region
    fixes most components while many rows stay active) the system is singular
    but consistent; the minimum-norm solution is then a valid one, and the
    caller's residual check decides. ``None`` if nothing finite comes out.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
        try:
            sol = scipy.linalg.solve(kkt, rhs, assume_a="sym", check_finite=False)
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgWarning, ValueError):
            if not singular_ok:
                return None
            try:
                sol = scipy.linalg.lstsq(kkt, rhs, check_finite=False, lapack_driver="gelsy")[0]
            except (np.linalg.LinAlgError, ValueError):
                return None
    return sol if np.all(np.isfinite(sol)) else None


def polish(sub: QPSubproblem, step: QPStep, tol: float = 1e-9, rounds: int = 3,
           release: bool = False) -> QPStep | None:
    r"""Exact solution on the active set ProxQP identified, or ``None``.

    ProxQP's solution is accurate to ``eps_abs`` (~1e-9). Near convergence
    the SQP step is ~1e-6 and the merit decrease :math:`\sim\|d\|^2` drowns
    in that error. Like the solution polishing of OSQP (Stellato et al.,
    *Math. Prog. Comp.* 12, 2020, §5), we take the active set
    :math:`\mathcal{A} = \{i : \lambda_i > 0\}` and the box components
    with :math:`\nu_j \ne 0` (fixed at their bound, set :math:`\mathcal{F}`
    free) and solve the equality-constrained KKT system

    .. math::
        \begin{bmatrix} H_{\mathcal{F}\mathcal{F}} & -C_{\mathcal{A}\mathcal{F}}^\top \\
        -C_{\mathcal{A}\mathcal{F}} & 0 \end{bmatrix}
        \begin{bmatrix} d_\mathcal{F} \\ \lambda_\mathcal{A} \end{bmatrix} =
        \begin{bmatrix} -g_\mathcal{F} - H_{\mathcal{F}\bar{\mathcal{F}}} d_{\bar{\mathcal{F}}} \\
        -\ell_\mathcal{A} + C_{\mathcal{A}\bar{\mathcal{F}}} d_{\bar{\mathcal{F}}} \end{bmatrix},
        \qquad \nu = H d + g - C^\top \lambda \text{ on } \bar{\mathcal{F}}.

    Rows or box components the result violates join the active set (up to
    ``rounds`` rounds). With ``release`` (a guessed active set,
    :func:`from_active_set`), rows and box components with a wrong-signed
    multiplier leave it first; violated ones join only in a round where none
    leaves. A singular system
    (degenerate active set) is solved in the least-squares sense; with
    ``release`` it ends the attempt instead (its multipliers are not unique,
    and their signs then send the sets in a cycle). The result is returned only if it is a KKT point of
    the QP to ``tol`` (signs of :math:`\lambda, \nu` included). A structured
    :math:`H` is made dense (the caller skips the polish for large :math:`n`).
    """
    H, g, lower, bl, bu = as_dense(sub.H), sub.g, sub.lower, sub.box_lower, sub.box_upper
    C = sub.C.toarray() if sp.issparse(sub.C) else np.asarray(sub.C)
    scale = tol * max(1.0, float(np.max(np.abs(step.lam), initial=0.0)),
                      float(np.max(np.abs(step.nu), initial=0.0)))
    # violations are judged against the box's size too: with a tiny trust region an absolute
    # ``tol`` would accept a step several times outside it
    width = (bu - bl)[np.isfinite(bu - bl)]
    vtol = min(tol, 1e-3 * float(np.min(width))) if width.size else tol
    act = step.lam > scale
    lo = (step.nu > scale) & np.isfinite(bl)
    up = (step.nu < -scale) & np.isfinite(bu) & ~lo
    for _ in range(rounds):
        fixed = lo | up
        free = ~fixed
        d = np.where(lo, bl, np.where(up, bu, 0.0))
        ca = C[act]
        nf, na = int(free.sum()), int(act.sum())
        kkt = np.zeros((nf + na, nf + na))
        kkt[:nf, :nf] = H[np.ix_(free, free)]
        kkt[:nf, nf:] = -ca[:, free].T
        kkt[nf:, :nf] = -ca[:, free]
        rhs = np.concatenate([-g[free] - H[np.ix_(free, fixed)] @ d[fixed],
                              -lower[act] + ca[:, fixed] @ d[fixed]])
        sol = _solve_kkt(kkt, rhs, singular_ok=not release)
        if sol is None:
            return None
        d[free] = sol[:nf]
        lam = np.zeros(lower.size)
        lam[act] = sol[nf:]
        nu = np.where(fixed, matvec(H, d) + g - matvec(C.T, lam), 0.0)
        new_rows = (matvec(C, d) - lower < -vtol) & ~act
        new_lo, new_up = (d < bl - vtol) & free, (d > bu + vtol) & free
        if release:  # wrong-signed multipliers leave the active set before anything joins it
            out_rows, out_lo, out_up = act & (lam < -tol), lo & (nu < -tol), up & (nu > tol)
            if out_rows.any() or out_lo.any() or out_up.any():
                act &= ~out_rows
                lo &= ~out_lo
                up &= ~out_up
                continue
        if not (new_rows.any() or new_lo.any() or new_up.any()):
            break
        act |= new_rows
        lo |= new_lo
        up |= new_up
    else:
        return None
    if np.any(lam < -tol) or np.any(nu[lo] < -tol) or np.any(nu[up] > tol):
        return None
    lam = np.maximum(lam, 0.0)
    primal, dual, comp = sub.residuals(d, lam, nu)
    if max(primal, dual, comp) > tol:
        return None
    return step._replace(d=d, lam=lam, nu=nu, primal_residual=primal, dual_residual=dual,
                         complementarity=comp, polished=True)


def from_active_set(sub: QPSubproblem, lam0, nu0, tol: float = 1e-9, rounds: int = 5) -> QPStep | None:
    r"""The QP's solution on the active set that warm-start multipliers name, or ``None``.

    Between SQP iterations the active set of the QP changes little: the rows
    with :math:`\lambda_0 > 0` and the bounds with :math:`\nu_0 \ne 0` of the
    last iteration are usually the active set of this one. Solving the KKT
    system on that set (:func:`polish` with ``release``: rows it violates join,
    wrong-signed multipliers leave, ``rounds`` times) costs one symmetric
    factorisation; ProxQP's proximal iterations cost several (its own
    factorisation and updates for every change of its active set). The result
    is returned only if it is a KKT point of the QP to ``tol``, signs
    included, exactly as a polished ProxQP step is; :math:`H` positive
    definite makes that point the QP's unique solution. ``None`` when the guess
    does not lead there: the caller solves the QP with ProxQP.
    """
    n = sub.g.size
    nu = np.zeros(n) if nu0 is None else np.asarray(nu0, dtype=float)
    guess = QPStep(np.zeros(n), np.asarray(lam0, dtype=float), nu, "solved", 0, np.inf, np.inf, np.inf)
    return polish(sub, guess, tol, rounds=rounds, release=True)
