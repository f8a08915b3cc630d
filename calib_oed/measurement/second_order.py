r"""Second configuration derivatives of the rows of :math:`F_1` (``docs/derivations.md`` §13).

**Joint columns.** Every model's joint columns have the form
:math:`\Lambda(q)\,K(q)\,J_r`, a :math:`d \times 6` matrix :math:`\Lambda` times the
LOCAL regressor (block :math:`K_b` for joint b) times the right Jacobians
:math:`J_r(\delta_b)` (constant in q). With :math:`A_k = \mathrm{ad}(J_k)`,
:math:`\partial_k K_b = -A_k K_b` for :math:`k \ge b` and
:math:`\partial_{kl}K_b = A_{\max(k,l)}A_{\min(k,l)}K_b` for :math:`\min(k,l) \ge b`
(``docs/derivations.md`` §13; its dense form is the tests' reference):

.. math::
    \partial_{kl}(\Lambda K_b) = \big(\Lambda_{kl} - [l \ge b]\,\Lambda_k A_l - [k \ge b]\,\Lambda_l A_k
      + [\min(k,l) \ge b]\,\Lambda A_{\max}A_{\min}\big)\,K_b,

four batched :math:`(d \times 6)(6 \times 6n_j)` products with column masks
(:func:`joint_rows_hessian`); :math:`\partial^2 K` is never formed.

**Tool point** :math:`x = t + Rc` (tracker position rows, :func:`tool_point_param_config_hessian`):
:math:`\Lambda = R\,E`, :math:`E = [\,I\;\;-[c]_\times]`; with :math:`\partial_k R = R\,\Omega_k`,
:math:`\Omega_k = [\omega_k]_\times`, :math:`\Omega_{kl} = [\partial_l\omega_k]_\times`:
:math:`\Lambda_k = R\,\Omega_k E`, :math:`\Lambda_{kl} = R\,(\Omega_l\Omega_k + \Omega_{kl})E`.
Reflector columns :math:`R\,(\Omega_l\Omega_k + \Omega_{kl})`; tracker columns
:math:`[\,0\;\;[\partial_{kl}y]_\times]\,J_r(\delta_T)` with
:math:`\partial_{kl}y = R_T^\top R\,[\Omega_l L(J_k) + L(\partial_l J_k)]`,
:math:`L(X) = X_v + X_\omega \times c`. In the tracker frame :math:`R` is
:math:`R_T^\top R`. Rigid kinematics only: with joint compliance the models
return None instead.

**Joint gains** (no compliance, :func:`with_joint_gains`): the kinematics run at
:math:`q_{eff} = Dq`, :math:`D = I + \sum_m\theta_m E_m` constant, so the geometric
rows' second derivative is the rigid one along :math:`q_{eff}` times :math:`D` on both
sides; a gain row :math:`\sum_i G_i(q_{eff})\,(E_m q)_i`, with
:math:`G_i = (\partial h/\partial\epsilon_i)S_i` (joint columns before :math:`J_r`), has

.. math::
    \partial_{kl} = \sum_{iab} G_{i,ab}D_{ak}D_{bl}(E_mq)_i
      + \sum_{ia} G_{i,a}\big(D_{ak}(E_m)_{il} + D_{al}(E_m)_{ik}\big),

both pieces from the rigid formulas at :math:`J_r = I` contracted with the axes :math:`S_i`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

from calib_oed.measurement.base import SetupState
from calib_oed.model.kinematics import ad_matrices, cross, skew


def lever(mat: np.ndarray, c: np.ndarray) -> np.ndarray:
    r""":math:`L(X) = X_v + X_\omega \times c` along axis 1 of ``mat`` (n, 6, ...) -> (n, 3, ...)."""
    shape = (1, 3) + (1,) * (mat.ndim - 2)
    return mat[:, :3] + cross(mat[:, 3:], np.reshape(c, shape), axis=1)


def rotation_products(state: SetupState) -> np.ndarray:
    r""":math:`\Omega_l\Omega_k + \Omega_{kl}` (n, nv_k, nv_l, 3, 3), symmetric in k, l, in the tool frame."""
    omega = np.moveaxis(state.kin.jacobian[:, 3:, :], 1, 2)  # (n, nv, 3)
    om = skew(omega)
    om_q = skew(np.moveaxis(state.jacobian_q[:, 3:], 1, 3))  # (n, k, l, 3, 3): [d_l w_k]x
    return om[:, None, :] @ om[:, :, None] + om_q


def joint_rows_hessian(state: SetupState, lam: np.ndarray, lam_k: np.ndarray,
                       lam_kl: np.ndarray) -> np.ndarray:
    r""":math:`\partial_{kl}(\Lambda K J_r)` on the joint columns, (n, d, 6 n_j, nv, nv) (module docstring).

    Args:
        state: Carries :math:`K`, :math:`J` and :math:`J_r(\delta_b)`.
        lam: :math:`\Lambda` (n, d, 6).
        lam_k: :math:`\partial_k\Lambda` (n, nv, d, 6).
        lam_kl: :math:`\partial_{kl}\Lambda` (n, nv, nv, d, 6), symmetric in k, l.
    """
    kin = state.kin
    reg = kin.regressor
    n, _, ncol = reg.shape
    nv = kin.jacobian.shape[2]
    if state.joint_jr is not None:  # K_b J_r(delta_b): constant in q, folded in once
        reg = np.einsum("nejf,jfg->nejg", reg.reshape(n, 6, -1, 6), state.joint_jr).reshape(n, 6, ncol)
    d = lam.shape[1]
    ad_cols = np.moveaxis(ad_matrices(kin.jacobian), 1, 2).reshape(n, 6, nv * 6)  # [A_1 .. A_nv]

    def times_ad(left):  # (n, m, d, 6) -> (n, m, nv, d, 6): left_i A_j, one product per pose
        m = left.shape[1]
        prod = left.reshape(n, m * d, 6) @ ad_cols
        return prod.reshape(n, m, d, nv, 6).transpose(0, 1, 3, 2, 4)

    idx = np.arange(nv)
    lever_kl = times_ad(lam_k)  # Lambda_k A_l
    both = times_ad(times_ad(lam[:, None])[:, 0])  # Lambda A_i A_j
    # the four left factors of the module docstring, then one product with K per pose
    left = np.stack([lam_kl, lever_kl, np.swapaxes(lever_kl, 1, 2),
                     both[:, np.maximum.outer(idx, idx), np.minimum.outer(idx, idx)]], axis=1)
    x = (left.reshape(n, -1, 6) @ reg).reshape(n, 4, nv, nv, d, ncol)
    # ge[l, c]: joint l is at or after the joint of column c (block b = c // 6)
    ge = np.broadcast_to((idx[:, None] >= np.arange(ncol) // 6)[None, :, None, :], (nv, nv, d, ncol))
    ge_k = np.swapaxes(ge, 0, 1)
    signs = np.stack([np.ones(ge.shape), -1.0 * ge, -1.0 * ge_k, 1.0 * (ge & ge_k)])
    return np.einsum("ngkldc,gkldc->ndckl", x, signs, optimize=False)


def tool_point_param_config_hessian(
    state: SetupState, offset: np.ndarray, frame: str, reflector: int | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    r""":math:`\partial^3 x/\partial p\,\partial q_k\,\partial q_l` of ``state.tool_point``, (n, 3, n_p, nv, nv).

    See the module docstring; ``frame`` and ``reflector`` as in
    :meth:`SetupState.tool_point_param_jacobian`; ``out``, if given, is a
    zeroed (n, 3, n_p, nv, nv) array written and returned. Rigid kinematics only
    (raises ``ValueError`` on a state with compliance or joint gains).
    """
    if not state.rigid:
        raise ValueError("second configuration derivatives are not available with joint compliance "
                         "or joint gains")
    space, kin = state.space, state.kin
    c = np.asarray(offset, dtype=float)
    n, nv = state.n, kin.jacobian.shape[2]
    rot = kin.rotation
    if frame == "tracker":
        rot = state.tracker.rotation.T @ rot
    prod = rot[:, None, None] @ rotation_products(state)  # R (Omega_l Omega_k + Omega_kl)
    lever_e = np.hstack([np.eye(3), -skew(c)])  # E = [I, -[c]x]
    om = skew(np.moveaxis(kin.jacobian[:, 3:, :], 1, 2))  # (n, nv, 3, 3)
    if out is None:
        out = np.zeros((n, 3, space.size, nv, nv))
    out[:, :, space.joints_slice] = joint_rows_hessian(
        state, rot @ lever_e, rot[:, None] @ om @ lever_e, prod @ lever_e)
    if reflector is not None:
        out[:, :, space.reflector_slice(reflector)] = np.moveaxis(prod, (1, 2), (3, 4))
    if frame == "tracker":
        lj = lever(kin.jacobian, c)  # (n, 3, nv)
        omega = kin.jacobian[:, 3:, :]
        y_kl = cross(omega[:, :, None, :], lj[:, :, :, None], axis=1) + lever(state.jacobian_q, c)
        y_kl = np.einsum("nab,nbkl->nkla", rot, y_kl)  # (n, k, l, 3)
        trk = np.zeros((n, nv, nv, 3, 6))
        trk[..., 3:] = skew(y_kl)
        delta = state.p[space.tracker_slice]
        if np.any(delta):
            trk = trk @ pin.Jexp6(delta)
        out[:, :, space.tracker_slice] = np.moveaxis(trk, (1, 2), (3, 4))
    return out


def _rigid_view(state: SetupState, eps: bool) -> SetupState:
    """The state without its gains (kinematics stay at q_eff); ``eps``: joint columns before J_r."""
    view = dataclasses.replace(state, gain_columns=None, **({"joint_jr": None} if eps else {}))
    for key in ("regressor_q", "jacobian_q"):  # the kinematics' derivatives are shared
        if key in state.__dict__:
            view.__dict__[key] = state.__dict__[key]
    return view


def with_joint_gains(model, state: SetupState) -> np.ndarray | None:
    r""":math:`\partial^3 h/\partial p\,\partial q_k\,\partial q_l` of ``model`` with joint gains, (n, d, n_p, nv, nv).

    From the model's rigid second derivative (module docstring); None with compliance too.
    """
    if state.torque is not None:
        return None
    space = state.space
    state.regressor_q, state.jacobian_q  # noqa: B018 -- computed once here, shared by both views
    out = model.compute_param_config_hessian(_rigid_view(state, eps=False))
    eps = _rigid_view(state, eps=True)
    d = state.config_chain[0]  # constant: I + sum theta_m E_m
    out = np.einsum("ndpab,ak,bl->ndpkl", out, d, d)
    joints = space.joints_slice
    n, dim = out.shape[:2]
    axes = space.joint_axes
    g_ab = np.einsum("ndjcab,jc->ndjab", model.compute_param_config_hessian(eps)[:, :, joints]
                     .reshape(n, dim, -1, 6, *out.shape[3:]), axes)
    g_a = np.einsum("ndjca,jc->ndja", model.compute_param_config_jacobian(eps)[:, :, joints]
                    .reshape(n, dim, -1, 6, out.shape[3]), axes)
    g_ab = np.einsum("ndiab,ak,bl->ndikl", g_ab, d, d)
    g_k = np.einsum("ndia,ak->ndik", g_a, d)
    lever = np.einsum("ndik,iml->ndmkl", g_k, space.gain_basis)
    out[:, :, space.gain_slice] = (np.einsum("ndikl,nim->ndmkl", g_ab, state.gain_columns)
                                   + lever + np.swapaxes(lever, 3, 4))
    return out
