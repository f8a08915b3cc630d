r"""The exact Hessian of ``kpi_model`` (the fit predictor under the joint-space prior) in the
configurations, for the design SQP.

**Setting** (:mod:`calib_oed.oed.model_error`). :math:`\phi = \Psi(\tilde F, S, k_w)
= \mathrm{tr}(\Omega K_{ww}) + \mathrm{tr}(\Omega V^\top S V) - 2\,\mathrm{tr}(\Omega V^\top k_w)`,
:math:`V = \tilde F Y`, :math:`Y = M^{-1}\tilde G^\top`, :math:`M = \tilde F^\top\tilde F`. A
direction :math:`a = (j, m)` (joint m of pose j) moves pose j's rows
:math:`\partial\tilde F = E_j A_a`, :math:`A_a = \partial_m\tilde F_j`; the measurement
covariance :math:`\partial S = E_j X_a + X_a^\top E_j^\top` with
:math:`X_a[\alpha, (i,\beta)] = \sum_\kappa (\partial_m k_\kappa(q_j, q_i)\,B_{j\alpha\kappa}
+ k_\kappa(q_j, q_i)\,\partial_m B_{j\alpha\kappa})\,B_{i\beta\kappa}` (first argument only:
the diagonal block follows from the kernel's symmetry); and pose j's rows of :math:`k_w` by
:math:`X^w_a`. The gradient is :math:`g_a = \langle D_F, \partial\tilde F\rangle
+ 2\langle U_{j\cdot}, X_a\rangle + \langle x_w, X^w_a\rangle`, :math:`D_F = \partial\Psi/\partial\tilde F`,
:math:`U = V\Omega V^\top`, :math:`x_w = -2V\Omega`. Its derivative along :math:`b = (l, p)`:

.. math::
    H_{ab} = \underbrace{\Psi_{FF}[A_a, A_b] + \Psi_{FS}[A_a, \partial_b S] + \Psi_{FS}[A_b, \partial_a S]
      + \Psi_{Fk}[A_a, \partial_b k_w] + \Psi_{Fk}[A_b, \partial_a k_w]}_{\text{through the adjoints}}
      + \underbrace{\langle D_F, \partial_{ab}\tilde F\rangle + 2\langle U_{j\cdot}, \partial_b X_a\rangle
      + \langle x_w, \partial_b X^w_a\rangle}_{\text{second derivatives of the pieces}},

with :math:`dV = dF\,Y + \tilde F\,dY`, :math:`dY = -M^{-1}dM\,Y`,
:math:`\Psi_{FF}[A_a, A_b] = 2\,\mathrm{tr}(\Omega\,dV_a^\top S\,dV_b) + 2\langle d^2V_{ab}, R\Omega\rangle`
(:math:`R = SV - k_w`, :math:`d^2V_{ab} = dF_a dY_b + dF_b dY_a + \tilde F d^2Y_{ab}`,
:math:`d^2Y_{ab} = M^{-1}(dM_b M^{-1}dM_a + dM_a M^{-1}dM_b - d^2M_{ab})Y`),
:math:`\Psi_{FS}[A, \partial S] = 2\langle\partial S, dV\,\Omega V^\top\rangle`,
:math:`\Psi_{Fk}[A, \partial k_w] = -2\langle\partial k_w, dV\,\Omega\rangle`. The kernel's second
derivatives in both arguments (own angle: :math:`\pm k''(\Delta)`; gain :math:`\nu^2`; compliance
:math:`\gamma^2\,\partial\tau\,\partial\tau^\top` and :math:`\gamma^2\,\partial^2\tau\,\tau`), the
points' second Jacobian derivatives (:func:`point_derivatives`) and the gravity torques' second
derivatives (:func:`gravity_hessians`) are closed form. Checked against central differences of the
exact gradient in ``tests/oed/test_model_error_hessian.py``.

The Hessian couples every pair of poses (the kernel) and is indefinite; the SQP takes it made
positive definite by the absolute value of its eigenvalues (the rule of
:mod:`calib_oed.solver.hessian`, applied to the whole matrix), in the form of the solver's
lifted QP (:func:`structured_hessian`): the :math:`n/3` largest :math:`|\theta|` as a low-rank
factor, the rest by its pose blocks (a dense factor would make every QP dense). Not covered (None: the SQP's damped BFGS): ``kpi_kriging``, the
isotropic prior, a full noise model (whitening that moves with the pose), joint compliance modelled
(no second row derivatives), prismatic joints.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.model.kinematics import compute_tool_kinematics, cross
from calib_oed.solver.hessian import LIFTED_MAX_RANK_RATIO
from calib_oed.solver.result import StructuredHessian

_MM = 1e3
#: Eigenvalues of the Hessian below this times the largest are raised to it (:func:`structured_hessian`).
EIGENVALUE_FLOOR = 1e-8
#: Largest size of the Hessian (poses times joints) given to the SQP whole, :math:`|H|` with every
#: eigenpair (:func:`design_hessian`); above it, the lifted QP's form (the largest :math:`|\theta|`,
#: :data:`~calib_oed.solver.hessian.LIFTED_MAX_RANK_RATIO` of the size, as a factor, the rest by
#: pose blocks). The truncation leaves out the remainder's coupling between poses (along late SQP
#: steps 0.36-0.57 of the true curvature on fms_kr16), and the QP overshoots. Up to this size (60
#: poses of 6 joints, where the default design was measured on the realistic simulator with it) the
#: whole |H| costs 1.3x the lifted form's SQP CPU per iteration, at 120 poses 2.1x (``docs/benchmarks.md``,
#: "kpi_model's iteration budget").
FULL_COUPLING_MAX_SIZE = 360


def point_derivatives(axes: np.ndarray, jac: np.ndarray):
    r""":math:`\partial_l J_k` and :math:`\partial_m\partial_l J_k` of point Jacobian columns of a serial
    revolute chain: ``axes`` :math:`a_k` (n, K, 3), ``jac`` :math:`J_k` (n, P, 3, K) (zero for joints
    that do not move the point). :math:`\partial_l J_k = a_{\min} \times J_{\max}`;
    :math:`\partial_m(a_p \times J_r) = [m < p]\,(a_m \times a_p) \times J_r + a_p \times \partial_m J_r`.
    Returns (n, P, 3, K, K) and (n, P, 3, K, K, K), symmetric in the joint indices."""
    nk = jac.shape[-1]
    a = axes[:, None, :, None, :]  # (n, 1, K, 1, 3): a_k
    jt = np.moveaxis(jac, 2, 3)  # (n, P, K, 3): J_l
    lo, hi = np.minimum.outer(np.arange(nk), np.arange(nk)), np.maximum.outer(np.arange(nk), np.arange(nk))
    ax = cross(a, jt[:, :, None, :, :])  # [.., k, l] = a_k x J_l
    d = ax[:, :, lo, hi]  # (n, P, K, K, 3)
    # T[p, m, r] = a_p x dJ_r/dq_m + [m < p] (a_m x a_p) x J_r
    t = cross(axes[:, None, :, None, None, :], d[:, :, None, :, :, :])
    aa = cross(axes[:, None, :, :], axes[:, :, None, :])  # [p, m] = a_m x a_p
    aa = aa * (np.arange(nk)[None, :] < np.arange(nk)[:, None])[None, :, :, None]  # m < p
    t += cross(aa[:, None, :, :, None, :], jt[:, :, None, None, :, :])
    m = np.arange(nk)
    dd = t[:, :, lo[:, :, None], m[None, None, :], hi[:, :, None]]  # (n, P, K, K, K, 3)
    return np.moveaxis(d, 4, 2), np.moveaxis(dd, 5, 2)


def gravity_hessians(load, q: np.ndarray) -> np.ndarray:
    r""":math:`\partial^2\tau_{g,k}/\partial q_m\partial q_p` (n, nv, nv, nv) [N·m/rad²] of a
    :class:`~calib_oed.model.compliance.GravityLoad` (revolute joints):
    :math:`\tau_{g,k} = \sum_i m_i\,g\cdot J_k(c_i) = g\cdot J_k^m`, :math:`c_i` the centre of mass of
    body i, with the mass-weighted column :math:`J_k^m = \sum_{i \ge k} m_i\,a_k\times(c_i - o_k)
    = a_k\times(\sum_{i\ge k} m_i c_i - M_k o_k)`, :math:`M_k = \sum_{i\ge k} m_i`: the derivatives
    of :func:`point_derivatives` are linear in the columns, so one weighted point carries them all."""
    model = load.model
    nv = model.nv
    g = np.asarray(model.gravity.linear)
    inertias = [model.inertias[i] for i in range(1, nv + 1)]
    mass = np.array([m.mass for m in inertias])
    lever = np.array([m.lever for m in inertias])  # (nv, 3), body frames
    states = compute_body_states(model, np.asarray(q, dtype=float), jacobian=False)
    rot, orig = states.rotation[:, 1:], states.translation[:, 1:]  # joint frames 1..nv
    axes = rot @ load.axes[:, 3:, None]  # (n, nv, 3, 1)
    com = (rot @ lever[:, :, None])[..., 0] + orig  # (n, nv, 3)
    moment = np.cumsum((mass[:, None] * com)[:, ::-1], axis=1)[:, ::-1]  # sum_{i >= k} m_i c_i
    total = np.cumsum(mass[::-1])[::-1]  # M_k
    jac = cross(axes[..., 0], moment - total[:, None] * orig)  # (n, nv, 3): J_k^m
    dd = point_derivatives(axes[..., 0], np.moveaxis(jac, 2, 1)[:, None])[1][:, 0]  # (n, 3, K, K, K)
    return np.einsum("x,sxkmp->skmp", g, dd)


def kernel_second_own(prior, q1, q2, e, grav=None):
    r""":math:`\sum_{\kappa, i} e_{\kappa j i}\,\partial^2 k_\kappa(x, y)/\partial x_m\partial x_p` at
    :math:`(x, y) = (q_{1j}, q_{2i})`, (n1, nv, nv), for weights ``e`` (K, n1, n2); the second
    derivatives never formed (K, n1, n2, nv, nv): the own angle's :math:`k''` sits on
    :math:`m = p = \kappa`, the compliance part is :math:`\gamma_\kappa^2\,\partial^2\tau_\kappa(x)\,\tau_\kappa(y)`.
    ``grav``: (torques at q2, second derivatives of the torques at q1), or None without a compliance part."""
    nk = prior.nq
    own = np.moveaxis(prior.compute_own_second(q1, q2), 2, 0)  # (K, n1, n2)
    out = np.zeros((len(q1), nk, nk))
    idx = np.arange(nk)
    out[:, idx, idx] = np.einsum("kji,kji->jk", own, e)
    if grav is not None:
        t2, ddt1 = grav
        out += np.einsum("jkmp,jk->jmp", ddt1, (prior.compliance**2) * np.einsum("ik,kji->jk", t2, e))
    return out


def kernel_second_mixed(prior, q, e, grav):
    r""":math:`e_{\kappa jl}\,\partial^2 k_\kappa(x, y)/\partial x_m\partial y_p` at
    :math:`(x, y) = (q_j, q_l)` summed over :math:`\kappa`, (n, nv, n, nv), for weights ``e``
    (K, n, n): own angle :math:`-k'' + \nu^2` on :math:`m = p = \kappa`, compliance
    :math:`\gamma^2\,\partial\tau(x)\,\partial\tau(y)^\top`. ``grav``: the torques' derivatives at q, or None."""
    nk = prior.nq
    own = np.moveaxis(prior.compute_own_second(q, q), 2, 0)
    out = np.zeros((len(q), nk, len(q), nk))
    idx = np.arange(nk)
    out[:, idx, :, idx] = (prior.gain**2)[:, None, None] * e - own * e  # [k, j, l]
    if grav is not None:
        out += np.einsum("kjl,jkm,lkp->jmlp", (prior.compliance**2)[:, None, None] * e, grav, grav, optimize=True)
    return out


def covers(criterion) -> bool:
    """Whether :func:`design_hessian` applies to ``criterion`` (``kpi_model`` with the joint-space prior)."""
    return (getattr(criterion, "needs_design", False) and getattr(criterion, "predictor", None) == "fit"
            and getattr(criterion, "joint_space", False))


def design_hessian(objective, q: np.ndarray) -> StructuredHessian | None:
    """The exact Hessian of ``objective`` (a :class:`~calib_oed.oed.objective.DesignObjective` of a
    criterion :func:`covers`) at ``q``, made positive definite (:func:`structured_hessian`); None
    where a second derivative is missing (joint compliance or gains modelled, prismatic joints)."""
    crit = objective.criterion
    if not covers(crit):
        return None
    grav = crit.prior.gravity
    if grav is not None and np.any(grav.axes[:, :3] != 0):  # a prismatic joint
        return None
    rows, d_rows, _, state = objective._evaluated(q)
    dd_rows = objective._row_hessians(state)
    if dd_rows is None:
        return None
    z, d_z, dd_z = [], [], []
    nv = d_rows.shape[-1]
    for mdl in objective.problem.models:
        if getattr(mdl, "noise", None) is None:
            z.append(np.broadcast_to(np.diag(1.0 / mdl.sigma), (len(q), 3, 3)))
            d_z.append(np.zeros((len(q), 3, 3, nv)))
            dd_z.append(np.zeros((len(q), 3, 3, nv, nv)))
            continue
        pieces = objective._whitening(mdl, state, 2)
        if pieces.dd_w is None:
            return None
        z.append(pieces.w)
        d_z.append(pieces.d_w)
        dd_z.append(pieces.dd_w)
    h = compute_hessian(crit, rows, np.asarray(q, dtype=float), np.concatenate(z, axis=1), d_rows, dd_rows,
                        np.concatenate(d_z, axis=1), np.concatenate(dd_z, axis=1))
    full = h.shape[0] <= FULL_COUPLING_MAX_SIZE
    return structured_hessian(h, nv, None if full else int(LIFTED_MAX_RANK_RATIO * h.shape[0]))


def compute_hessian(crit, rows, q, z, d_rows, dd_rows, d_z=None, dd_z=None) -> np.ndarray:
    r""":math:`\nabla^2_x\phi` (n nv, n nv), :math:`x = \mathrm{vec}(q)` pose-major (module docstring).

    Args: as :meth:`~calib_oed.oed.model_error.ModelErrorCriterion.compute_design`, with
    ``dd_rows`` :math:`\partial^2\tilde F_j/\partial q_j^2` (n, d, n_f, nv, nv) and the whitening's
    second derivative ``dd_z`` (n, d, 3, nv, nv) (both None: a constant whitening).
    """
    n, d, nf = rows.shape
    nv = d_rows.shape[-1]
    big = n * nv
    prior, om = crit.prior, crit.omega
    flat = rows.reshape(-1, nf)
    s, k_w, _, (kk, kwk, b, jac, _, tau) = crit._covariances(rows, q, z, False)
    t3 = k_w.shape[1]
    factor = scipy.linalg.cho_factor(flat.T @ flat, lower=True, check_finite=False)
    y = scipy.linalg.cho_solve(factor, crit.kpi_jacobian.T, check_finite=False)  # (nf, T3)
    v = flat @ y
    r = s @ v - k_w
    qq = scipy.linalg.cho_solve(factor, flat.T @ r, check_finite=False)
    d_f = 2.0 * (r * om) @ y.T - 2.0 * flat @ ((qq * om) @ y.T + (y * om) @ qq.T)
    vo = v * om
    u4 = (vo @ v.T).reshape(n, d, n, d)
    x_w = -2.0 * vo

    # the points' Jacobian derivatives, whitened: B, dB, ddB (n, d, K[, nv[, nv]])
    pts = crit.points
    kin = compute_tool_kinematics(pts.model, pts.frame_id, q, regressor=False, jacobian=True)
    axes = np.swapaxes(pts.rotation.T @ kin.rotation @ kin.jacobian[:, 3:, :], 1, 2)  # (n, K, 3)
    d_jac, dd_jac = point_derivatives(axes, jac)
    zr = z.reshape(n, -1, 3, 3)
    db = np.einsum("jrxy,jrykm->jrxkm", zr, d_jac)
    ddb = np.einsum("jrxy,jrykmp->jrxkmp", zr, dd_jac)
    if d_z is not None:  # B = Z J with Z moving with the pose
        dzr = d_z.reshape(n, -1, 3, 3, nv)
        db += np.einsum("jrxym,jryk->jrxkm", dzr, jac)
        dzj = np.einsum("jrxym,jrykp->jrxkmp", dzr, d_jac)
        ddb += dzj + np.swapaxes(dzj, 4, 5)
        ddb += np.einsum("jrxymp,jryk->jrxkmp", dd_z.reshape(n, -1, 3, 3, nv, nv), jac)
    db = db.reshape(n, d, nv, nv)
    ddb = ddb.reshape(n, d, nv, nv, nv)

    # kernels and their derivatives
    jw, tau_w, _ = crit._joint_work
    grav = prior.gravity if prior.gravity is not None and np.any(prior.compliance > 0) else None
    dt, dk1, dkw1 = crit._kernel_gradients(q, tau)
    if grav is not None:
        ddt = gravity_hessians(grav, q)

    # first derivatives of F, M, Y along every direction a = (j, m). dV_a = F dY_a + E_j A_a Y is
    # not formed ((n nv, n d, T3), and S dV an O(n^3) product): each product with it splits into
    # the part through F (nf columns) and the part in pose j's rows
    a_rows = np.moveaxis(d_rows, 3, 1)  # (n, nv, d, nf)
    atf = np.einsum("jmdf,jdg->jmfg", a_rows, rows)
    dm = (atf + np.swapaxes(atf, 2, 3)).reshape(big, nf, nf)
    dy = -scipy.linalg.cho_solve(factor, np.moveaxis(dm @ y, 0, 1).reshape(nf, -1),
                                 check_finite=False).reshape(nf, big, t3).transpose(1, 0, 2)
    ay = a_rows @ y  # (n, nv, d, T3): A_a Y
    dyf = dy.reshape(big, -1)
    dyw = (dy * om).reshape(big, -1)
    flat3 = flat.reshape(n, d, nf)

    # through the adjoints: Psi_FF, Psi_FS, Psi_Fk. 2 tr(Omega dV_a^T S dV_b) =
    # 2 [<dY_a, F^T S F dY_b> + <dY_a, (SF)_l^T A_b Y> + <(SF)_j^T A_a Y, dY_b> + <A_a Y, S_jl A_b Y>]_Omega
    sf = s @ flat  # (n d, nf)
    p_s = np.einsum("lbf,lpbc->lpfc", sf.reshape(n, d, nf), ay).reshape(big, -1)
    t2 = dyw @ p_s.T
    h = dyw @ np.einsum("fg,Ngc->Nfc", flat.T @ sf, dy).reshape(big, -1).T + t2 + t2.T
    del p_s, t2
    # <A_a Y, S_jl A_b Y>_Omega: pose j's rows of S first, then pose l's columns
    t1 = ((ay * om).transpose(0, 1, 3, 2).reshape(n, nv * t3, d) @ s.reshape(n, d, n * d))
    t1 = t1.reshape(n, nv, t3, n, d).transpose(3, 0, 1, 4, 2).reshape(n, big, d * t3)  # [l, (j, m), (b, c)]
    h += (t1 @ ay.transpose(0, 2, 3, 1).reshape(n, d * t3, nv)).transpose(1, 0, 2).reshape(big, big)
    h *= 2.0
    del t1
    rw = (r * om).reshape(n, d, t3)
    p_a = np.einsum("jmdf,jdc->jmfc", a_rows, rw).reshape(big, -1)
    cross = p_a @ dyf.T
    lam = scipy.linalg.cho_solve(factor, flat.T @ (r * om), check_finite=False)  # M^-1 F^T R Omega
    gm = np.einsum("Nfg,fc->Ngc", dm, lam).reshape(big, -1) @ dyf.T
    h += 2.0 * (cross + cross.T) - 2.0 * (gm + gm.T)
    blocks = -2.0 * np.einsum("jmdc,jpdc->jmp", a_rows @ lam, ay)
    blocks = blocks + np.swapaxes(blocks, 1, 2)
    # X_b = E_l (pose l's rows) of dS along b, never formed ((n, nv, d, n d)): every product with it
    # goes through the kernels' joint index k, X_b[a, (i, b')] = sum_k B_ik b' (dk_k B_lak + k_k dB_lak)
    xk = _MM * (np.einsum("kjim,jak,ick->jmaic", dkw1, b, jw, optimize=True)
                + np.einsum("kji,jakm,ick->jmaic", kwk, db, jw, optimize=True)).reshape(n, nv, d, t3)
    vo3 = vo.reshape(n, d, t3)
    bt = np.swapaxes(b, 1, 2)  # (n, K, d)
    bv = bt @ vo3  # (n, K, T3): B_i^T (V Omega)_i
    bf = bt @ flat3  # (n, K, nf): B_i^T F_i
    dbv = np.einsum("lakp,lac->lkpc", db, vo3)  # (n, K, nv, T3)
    dk_t = dk1.transpose(0, 1, 3, 2).reshape(nv, big, n)  # [k, (l, p), i]
    d1 = (dk_t @ bv.transpose(1, 0, 2)).reshape(nv, n, nv, t3)  # sum_i dk_k(l, i)/dq_lp B_i^T V Omega_i
    d2 = kk @ bv.transpose(1, 0, 2)  # (K, n, T3)
    # W_b = X_b V Omega - X^w_b Omega (pose l's rows of dV Omega's partner), (n, nv, d, T3)
    w_l = (b[:, None] @ d1.transpose(1, 2, 0, 3) + db.transpose(0, 3, 1, 2) @ d2.transpose(1, 0, 2)[:, None]
           - xk * om)
    # F^T (X_b^T V Omega), (n, nv, T3, nf)
    q1 = (dk_t @ bf.transpose(1, 0, 2)).reshape(nv, n, nv, nf)
    q2 = kk @ bf.transpose(1, 0, 2)  # (K, n, nf)
    f_xtv = (bv.transpose(0, 2, 1)[:, None] @ q1.transpose(1, 2, 0, 3)
             + dbv.transpose(0, 2, 3, 1) @ q2.transpose(1, 0, 2)[:, None])
    hfs = dyf @ (np.swapaxes(flat3, 1, 2)[:, None] @ w_l + np.swapaxes(f_xtv, 2, 3)).reshape(big, -1).T
    # <A_a Y, X_b^T V Omega> on pose j's rows: through B_j^T (A_a Y) per joint k
    ayb = (bt[:, None] @ ay).transpose(2, 0, 1, 3).reshape(nv, big, t3)  # [k, (j, m), c]
    p1 = (ayb @ bv.transpose(1, 2, 0)).reshape(nv, n, nv, n)  # [k, j, m, l]
    hfs4 = hfs.reshape(n, nv, n, nv)
    hfs4 += np.einsum("kjml,kljp->jmlp", p1, dk1)
    dbv_k = dbv.transpose(1, 0, 2, 3).reshape(nv, big, t3)  # [k, (l, p), c]
    for k in range(nv):
        hfs4 += (ayb[k] @ dbv_k[k].T).reshape(n, nv, n, nv) * kk[k].T[:, None, :, None]
    hfs4[np.arange(n), :, np.arange(n)] += np.einsum("jmac,jpac->jmp", ay, w_l)
    h += 2.0 * (hfs + hfs.T)
    del xk, w_l, f_xtv, hfs, hfs4, p1

    # second derivatives of the pieces: rows, S (all pairs of poses), k_w (per pose); the kernels'
    # second derivatives contracted in factored form (kernel_second_own, kernel_second_mixed)
    blocks += np.einsum("jdf,jdfmp->jmp", d_f.reshape(n, d, nf), dd_rows)
    ub = np.einsum("jalb,jak,lbk->kjl", u4, b, b, optimize=True)
    w1 = np.einsum("jalb,lbkp->jalkp", u4, db, optimize=True)
    udb_r = np.einsum("jak,jalkp->kjlp", b, w1, optimize=True)  # U with B left, dB right
    udb_l = np.swapaxes(udb_r, 1, 2)
    # the 2nd term with (j, m) and (l, p) exchanged is the 3rd (the same products, summed alike)
    dk_udb = np.einsum("kjlm,kjlp->jmlp", dk1, udb_r)
    pair_h = kernel_second_mixed(prior, q, ub, None if grav is None else dt)
    pair_h += dk_udb + dk_udb.transpose(2, 3, 0, 1)
    w1 *= np.moveaxis(kk, 0, 2)[:, None, :, :, None]  # k_kappa(q_j, q_l) U_jl dB_l
    pair_h += np.einsum("jakm,jalkp->jmlp", db, w1, optimize=True)
    del w1, dk_udb
    h += 2.0 * pair_h.reshape(big, big)
    del pair_h
    g_dd = np.einsum("jaib,ibk,kji->jak", u4, b, kk, optimize=True)  # U with B right, weighted by k
    dk_udb = np.einsum("kjim,kjip->jmp", dk1, udb_l)  # its transpose in (m, p) is the 3rd term
    own = (kernel_second_own(prior, q, q, ub, None if grav is None else (tau, ddt)) + dk_udb
           + np.swapaxes(dk_udb, 1, 2) + np.einsum("jakmp,jak->jmp", ddb, g_dd))
    blocks += 2.0 * own
    xwj = np.einsum("jaic,ick->jaik", x_w.reshape(n, d, -1, 3), jw) * _MM
    blocks += (kernel_second_own(prior, q, crit.working, np.einsum("jaik,jak->kji", xwj, b),
                                 None if grav is None else (tau_w[0], ddt))
               + np.einsum("jaik,kjim,jakp->jmp", xwj, dkw1, db, optimize=True)
               + np.einsum("jaik,kjip,jakm->jmp", xwj, dkw1, db, optimize=True)
               + np.einsum("jaik,kji,jakmp->jmp", xwj, kwk, ddb, optimize=True))
    h4 = h.reshape(n, nv, n, nv).copy()
    h4[np.arange(n), :, np.arange(n)] += blocks
    h = h4.reshape(big, big)
    return 0.5 * (h + h.T)


def structured_hessian(h: np.ndarray, nv: int, rank: int | None = None) -> StructuredHessian:
    r""":math:`|H|` of :math:`H = Q\Theta Q^\top`, :math:`|H| = Q\max(|\Theta|, \epsilon)Q^\top`,
    :math:`\epsilon` = :data:`EIGENVALUE_FLOOR` times the largest :math:`|\theta|`, as a
    :class:`StructuredHessian`. ``rank`` None: zero pose blocks and the dense factor
    :math:`U = Q\max(|\Theta|, \epsilon)^{1/2}`. ``rank`` r: U keeps the r largest
    :math:`|\theta|`, the rest of :math:`|H|` enters by its pose blocks (principal blocks of a
    positive semidefinite matrix, so positive semidefinite)."""
    theta, vec = np.linalg.eigh(h)
    mag = np.abs(theta)
    mag = np.maximum(mag, EIGENVALUE_FLOOR * max(mag.max(initial=0.0), 1e-300))
    b = h.shape[0] // nv
    if rank is None or rank >= len(mag):
        return StructuredHessian(np.zeros((b, nv, nv)), vec * np.sqrt(mag))
    order = np.argsort(mag)
    keep, rest = order[len(mag) - rank:], order[:len(mag) - rank]
    vr = (vec[:, rest] * np.sqrt(mag[rest])).reshape(b, nv, -1)
    blocks = np.einsum("jar,jbr->jab", vr, vr)
    return StructuredHessian(blocks, vec[:, keep] * np.sqrt(mag[keep]))
