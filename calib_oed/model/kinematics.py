r"""Batched forward kinematics of the tool frame, with its sensitivities.

For configurations :math:`q_1..q_n` this computes, in one pass of Pinocchio
per configuration, everything the measurement models and KPIs need:

- the tool placement :math:`T_{W,F}(q) = (R, t)` in the world (= robot base);
- the LOCAL kinematic regressor :math:`K(q) \in \mathbb{R}^{6 \times 6n_j}`:
  a right perturbation :math:`\epsilon_i` of joint ``i``'s placement
  (:math:`M_i \leftarrow M_i \exp_6(\epsilon_i)`) moves the tool frame by the
  local twist :math:`K_{:, 6(i-1):6i}\, \epsilon_i`
  (``pin.computeFrameKinematicRegressor``, block ``i-1`` for joint ``i``);
- the LOCAL frame Jacobian :math:`J(q) \in \mathbb{R}^{6 \times n_v}`.

A point :math:`c` fixed in the tool frame, :math:`x = t + R c`, then has

.. math::
    \frac{\partial x}{\partial \epsilon} = R\,[\,I \;\; -[c]_\times\,]\,K, \qquad
    \frac{\partial x}{\partial q} = R\,[\,I \;\; -[c]_\times\,]\,J .

Second order (design optimisation, ``docs/derivations.md`` §11 and §13): the
configuration derivatives of :math:`K` and :math:`J`
(:func:`regressor_config_derivative`, :func:`jacobian_config_derivative`,
all through :math:`\mathrm{ad}(J_k)`, :func:`ad_matrices`; the second derivative of
:math:`K` is applied in factored form by :mod:`calib_oed.measurement.second_order`), and :math:`J_{\log}` (``pin.Jlog3``) with its first and
second derivatives in :math:`\theta = \log_3 R` (:func:`log_jacobian`,
:func:`log_jacobian_derivative`, :func:`log_jacobian_second_derivative`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import scipy.special


@dataclass(frozen=True, eq=False)
class ToolKinematics:
    """Tool-frame kinematics at n configurations (arrays read-only).

    Attributes:
        q: Configurations, (n, nq) [rad].
        rotation: :math:`R_{W,F}`, (n, 3, 3).
        translation: :math:`t_{W,F}`, (n, 3) [m].
        regressor: LOCAL kinematic regressor, (n, 6, 6 n_j), or None.
        jacobian: LOCAL frame Jacobian, (n, 6, nv), or None.
    """

    q: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    regressor: np.ndarray | None
    jacobian: np.ndarray | None

    @property
    def n(self) -> int:
        return self.q.shape[0]

    def points(self, offset: np.ndarray) -> np.ndarray:
        """World position of a point fixed in the tool frame, (n, 3) [m]."""
        return self.translation + self.rotation @ np.asarray(offset, dtype=float)

    def point_sensitivity(self, offset: np.ndarray, of: str) -> np.ndarray:
        r"""World-frame derivative of the tool point ``offset``.

        Args:
            offset: :math:`c` in the tool frame [m].
            of: ``"regressor"`` for :math:`\partial x/\partial\epsilon`
                (n, 3, 6 n_j) or ``"jacobian"`` for :math:`\partial x/\partial q`
                (n, 3, nv).
        """
        mat = self.regressor if of == "regressor" else self.jacobian
        if mat is None:
            raise ValueError(f"ToolKinematics was computed without the {of}")
        # [I, -[c]x] M = M_v - c x M_w = M_v + M_w x c  (column-wise cross product)
        c = np.asarray(offset, dtype=float)
        local = mat[:, :3, :] - cross(c[None, :, None], mat[:, 3:, :], axis=1)
        return self.rotation @ local


def compute_tool_kinematics(
    model: pin.Model,
    frame_id: int,
    q: np.ndarray,
    *,
    regressor: bool = True,
    jacobian: bool = True,
    data: pin.Data | None = None,
) -> ToolKinematics:
    """Tool kinematics at every row of ``q`` (n, nq), see :class:`ToolKinematics`.

    ``q`` is assumed validated (see :meth:`calib_oed.model.robot.Robot.check_configurations`).
    """
    data = data if data is not None else model.createData()
    q = np.array(q, dtype=float)
    n = q.shape[0]
    rot = np.empty((n, 3, 3))
    trans = np.empty((n, 3))
    reg = np.empty((n, 6, 6 * (model.njoints - 1))) if regressor else None
    jac = np.empty((n, 6, model.nv)) if jacobian else None
    local = pin.ReferenceFrame.LOCAL
    for k in range(n):
        qk = q[k]
        if jacobian:
            # computeJointJacobians also runs the forward kinematics (data.oMi).
            pin.computeJointJacobians(model, data, qk)
        else:
            pin.forwardKinematics(model, data, qk)
        placement = pin.updateFramePlacement(model, data, frame_id)
        if jacobian:
            jac[k] = pin.getFrameJacobian(model, data, frame_id, local)
        rot[k] = placement.rotation
        trans[k] = placement.translation
        if regressor:
            reg[k] = pin.computeFrameKinematicRegressor(model, data, frame_id, local)
    for arr in (q, rot, trans, reg, jac):
        if arr is not None:
            arr.setflags(write=False)
    return ToolKinematics(q=q, rotation=rot, translation=trans, regressor=reg, jacobian=jac)


# ------------------------------------------------------- second order
def _ad_apply(twist: np.ndarray, mat: np.ndarray) -> np.ndarray:
    r""":math:`\mathrm{ad}(\xi)\,X` column-wise, :math:`\xi = (v, \omega)` (n, 6), X (n, 6, c).

    :math:`\mathrm{ad}(\xi) \begin{bmatrix} a \\ b \end{bmatrix}
    = \begin{bmatrix} \omega \times a + v \times b \\ \omega \times b \end{bmatrix}`
    (Pinocchio's order, linear part first), as skew-matrix products.
    """
    sv = skew(twist[:, :3])
    sw = skew(twist[:, 3:])
    out = np.empty_like(mat)
    out[:, :3] = sw @ mat[:, :3] + sv @ mat[:, 3:]
    out[:, 3:] = sw @ mat[:, 3:]
    return out


def skew(v: np.ndarray) -> np.ndarray:
    r"""Batched :math:`[v]_\times`: (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def cross(a: np.ndarray, b: np.ndarray, axis: int = -1) -> np.ndarray:
    r"""Batched :math:`a \times b` along ``axis`` of float arrays that broadcast: ``np.cross(a, b,
    axis=axis)`` bit for bit and in its memory layout, without its checks and copies.

    The same products and differences in the same order as NumPy's (:math:`c_0 = a_1 b_2 - a_2 b_1`,
    ...), in an array with the components last, returned as the view with them at ``axis``.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if axis != -1:
        a, b = np.moveaxis(a, axis, -1), np.moveaxis(b, axis, -1)
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a0.shape, b0.shape) + (3,))
    c0, c1, c2 = out[..., 0], out[..., 1], out[..., 2]
    tmp = np.multiply(a2, b1, out=...)
    np.multiply(a1, b2, out=c0)
    c0 -= tmp
    np.multiply(a2, b0, out=c1)
    np.multiply(a0, b2, out=tmp)
    c1 -= tmp
    np.multiply(a0, b1, out=c2)
    np.multiply(a1, b0, out=tmp)
    c2 -= tmp
    return out if axis == -1 else np.moveaxis(out, -1, axis)


def regressor_config_derivative(kin: ToolKinematics) -> np.ndarray:
    r""":math:`\partial K/\partial q`, (n, 6, 6 n_j, nv), of the LOCAL regressor.

    Block :math:`K_i` maps a right perturbation of joint ``i``'s placement,
    applied *before* the motion of joint ``i``, to the tool's local twist:
    :math:`K_i = \mathrm{Ad}(T_{W,F}^{-1} T_{W,K_i})`. Joint ``k`` with
    :math:`k \ge i` moves the tool relative to :math:`K_i`
    (:math:`dT_{W,F} = T_{W,F}\,\hat{J}_k\,dq_k`), joints before ``i`` move
    both rigidly, so

    .. math::
        \frac{\partial K_i}{\partial q_k} =
        \begin{cases} -\mathrm{ad}(J_k)\,K_i & k \ge i \\ 0 & k < i \end{cases}

    with :math:`J_k` column ``k`` of the LOCAL frame Jacobian
    (``docs/derivations.md`` §11). Valid for chains of 1-DoF joints whose
    velocity index is the joint index minus one (every robot calib_oed loads).
    """
    reg, jac = _need_both(kin)
    n, _, ncol = reg.shape
    nv = jac.shape[2]
    out = np.zeros((n, 6, ncol, nv))
    for k in range(nv):
        cols = slice(0, 6 * (k + 1))  # blocks of joints 1..k+1 (i <= k)
        out[:, :, cols, k] = -_ad_apply(jac[:, :, k], reg[:, :, cols])
    return out


def jacobian_config_derivative(kin: ToolKinematics) -> np.ndarray:
    r""":math:`\partial J/\partial q`, (n, 6, nv, nv), of the LOCAL frame Jacobian.

    :math:`J_l = \mathrm{Ad}(T_{W,F}^{-1} T_{W,l})\,S_l` with joint ``l``'s
    frame after its own motion, so only joints *after* ``l`` change it:

    .. math::
        \frac{\partial J_l}{\partial q_k} =
        \begin{cases} -\mathrm{ad}(J_k)\,J_l & k > l \\ 0 & k \le l \end{cases}

    (column ``l`` of the result's third axis, derivative along the fourth).
    """
    _, jac = _need_both(kin)
    n, _, nv = jac.shape
    out = np.zeros((n, 6, nv, nv))
    for k in range(1, nv):
        out[:, :, :k, k] = -_ad_apply(jac[:, :, k], jac[:, :, :k])
    return out


def ad_matrices(jacobian: np.ndarray) -> np.ndarray:
    r""":math:`\mathrm{ad}(J_k)` as 6x6 matrices, (n, nv, 6, 6), from the LOCAL Jacobian (n, 6, nv).

    :math:`\mathrm{ad}(v, \omega) = \begin{bmatrix} [\omega]_\times & [v]_\times \\
    0 & [\omega]_\times \end{bmatrix}` (see :func:`regressor_config_derivative`).
    """
    cols = np.moveaxis(np.asarray(jacobian, dtype=float), 1, 2)  # (n, nv, 6)
    out = np.zeros(cols.shape[:2] + (6, 6))
    sw = skew(cols[..., 3:])
    out[..., :3, :3] = sw
    out[..., 3:, 3:] = sw
    out[..., :3, 3:] = skew(cols[..., :3])
    return out


def _need_both(kin: ToolKinematics) -> tuple[np.ndarray, np.ndarray]:
    if kin.regressor is None or kin.jacobian is None:
        raise ValueError("second-order kinematics need both the regressor and the Jacobian; "
                         "compute the kinematics with regressor=True, jacobian=True")
    return kin.regressor, kin.jacobian


# ------------------------------------------- SO(3) logarithm: J_log and its derivatives
#: Terms of the series of b(s) below; at |θ| = π the m-th term is at most 4^-m / 12.
_LOG_TERMS = 48
_M = np.arange(_LOG_TERMS)
#: :math:`b(s) = \sum_m c_m s^m`, :math:`c_m = 2\zeta(2m+2)/(2\pi)^{2m+2}` (all positive).
_LOG_COEFFS = 2.0 * scipy.special.zeta(2 * _M + 2) / (2 * np.pi) ** (2 * _M + 2)


def _log_series(theta: np.ndarray):
    r""":math:`b, b', b''` at :math:`s = |\theta|^2`, each shaped like ``theta[..., 0]``."""
    s = np.sum(theta**2, axis=-1)
    poly = np.polynomial.polynomial.polyval
    b = poly(s, _LOG_COEFFS)
    b1 = poly(s, _LOG_COEFFS[1:] * _M[1:])
    b2 = poly(s, _LOG_COEFFS[2:] * _M[2:] * _M[1:-1])
    return b[..., None, None], b1[..., None, None], b2[..., None, None]


def log_jacobian(theta: np.ndarray) -> np.ndarray:
    r""":math:`J_{\log}` (``pin.Jlog3``) as a function of :math:`\theta = \log_3 R`, (..., 3, 3).

    .. math::
        J_{\log}(\theta) = J_r(\theta)^{-1} = I + \tfrac12[\theta]_\times + b(|\theta|^2)\,[\theta]_\times^2,
        \qquad b(\theta^2) = \frac{1}{\theta^2} - \frac{1 + \cos\theta}{2\theta\sin\theta}
        = \sum_{m \ge 0} \frac{2\zeta(2m+2)}{(2\pi)^{2m+2}}\,\theta^{2m},

    the series (from :math:`x\cot x`, Bernoulli numbers) summed for every
    :math:`|\theta| \le \pi` (the range of ``log3``): no cancellation near 0.
    """
    theta = np.asarray(theta, dtype=float)
    sk = skew(theta)
    b, _, _ = _log_series(theta)
    return np.eye(3) + 0.5 * sk + b * (sk @ sk)


def log_jacobian_derivative(theta: np.ndarray, u: np.ndarray) -> np.ndarray:
    r"""Directional derivative :math:`DJ_{\log}(\theta)[u]`, (..., 3, 3) (shapes broadcast).

    .. math::
        DJ_{\log}[u] = \tfrac12[u]_\times + 2b'\,(\theta\cdot u)\,S^2 + b\,([u]_\times S + S[u]_\times),
        \qquad S = [\theta]_\times .

    Along the right perturbation :math:`R \leftarrow R\exp_3(w\,t)`,
    :math:`\dot\theta = J_{\log}w` and ``pin.Hlog3(R, w)`` = :math:`DJ_{\log}[J_{\log}w]`.
    """
    theta, u = np.asarray(theta, dtype=float), np.asarray(u, dtype=float)
    sk, su = skew(theta), skew(u)
    b, b1, _ = _log_series(theta)  # on theta's own shape: the series once per rotation
    tu = np.sum(theta * u, axis=-1)[..., None, None]
    return 0.5 * su + 2.0 * b1 * tu * (sk @ sk) + b * (su @ sk + sk @ su)


def log_jacobian_second_derivative(theta: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    r"""Second directional derivative :math:`D^2J_{\log}(\theta)[u, v]`, (..., 3, 3), symmetric in u, v.

    .. math::
        D^2J_{\log}[u, v] = \big(4b''(\theta\cdot u)(\theta\cdot v) + 2b'(u\cdot v)\big)S^2
          + 2b'(\theta\cdot u)\{[v]_\times, S\} + 2b'(\theta\cdot v)\{[u]_\times, S\}
          + b\,\{[u]_\times, [v]_\times\}

    with :math:`\{X, Y\} = XY + YX`.
    """
    theta, u, v = (np.asarray(a, dtype=float) for a in (theta, u, v))
    sk, su, sv = skew(theta), skew(u), skew(v)
    b, b1, b2 = _log_series(theta)
    tu = np.sum(theta * u, axis=-1)[..., None, None]
    tv = np.sum(theta * v, axis=-1)[..., None, None]
    uv = np.sum(u * v, axis=-1)[..., None, None]
    return ((4.0 * b2 * tu * tv + 2.0 * b1 * uv) * (sk @ sk)
            + 2.0 * b1 * tu * (sv @ sk + sk @ sv) + 2.0 * b1 * tv * (su @ sk + sk @ su)
            + b * (su @ sv + sv @ su))
