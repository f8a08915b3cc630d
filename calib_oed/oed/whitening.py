r"""Rows of a measurement model with a full error model, whitened, and their q-derivatives.

For a model with ``mdl.noise`` (:class:`~calib_oed.measurement.noise.TrackerNoise`)
the rows of pose :math:`j` are :math:`\tilde F_j = W(y_j)\,J_j` (before the unit
scaling :math:`D`), with :math:`J_j = \partial h/\partial p_f(p, q_j)`,
:math:`y_j = h(p, q_j)` the reflector in the TRACKER frame [m] and
:math:`W = \Sigma(y)^{-1/2}`, symmetric, in closed form
(:meth:`~calib_oed.measurement.noise.TrackerNoise.symmetric_whitening`; the
identification's inverse Cholesky factor differs from it by a rotation per
pose, so :math:`\tilde F^\top\tilde F`, the criterion and the certificate are
the same). :math:`\Sigma` depends on :math:`q_j` through :math:`y_j` (range and
direction), so

.. math::
    \partial_k\tilde F_j = W\,\partial_k J_j + \partial_k W\,J_j, \qquad
    \partial_k W = \sum_a \frac{\partial W}{\partial y_a}\,\frac{\partial y_a}{\partial q_k},

    \partial_{kl}\tilde F_j = W\,\partial_{kl}J_j + \partial_k W\,\partial_l J_j
      + \partial_l W\,\partial_k J_j + \partial_{kl}W\,J_j, \qquad
    \partial_{kl} W = \sum_{ab} \frac{\partial^2 W}{\partial y_a\partial y_b}
      \frac{\partial y_a}{\partial q_k}\frac{\partial y_b}{\partial q_l}
      + \sum_a \frac{\partial W}{\partial y_a}\frac{\partial^2 y_a}{\partial q_k\partial q_l},

with :math:`\partial^2 y/\partial q_k\partial q_l = \omega_{\min(k,l)} \times
\partial y/\partial q_{\max(k,l)}` for a serial chain (:func:`point_config_hessian`;
:math:`\omega_k` the axis of joint k in the tracker frame, 0 for a prismatic
joint; None, and the term left out, with compliance or joint gains).
``docs/uncertainty.md``, "The design objective".
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from calib_oed.measurement.base import MeasurementModel, SetupState


class NoisePieces(NamedTuple):
    r"""Whitening of one model at one state and what its derivatives need.

    Attributes:
        w: :math:`W` (n, d, d) [1/m].
        jac: :math:`J` on the free parameters (n, d, n_f) [m per parameter unit, SI].
        d_w: :math:`\partial W/\partial q_k` (n, d, d, nv), or None (order 0).
        d_jac: :math:`\partial J/\partial q_k` (n, d, n_f, nv), or None (order 0).
        dd_w: :math:`\partial^2 W/\partial q_k\partial q_l` (n, d, d, nv, nv), or None
            (order < 2, or a state with compliance or joint gains).
    """

    w: np.ndarray
    jac: np.ndarray
    d_w: np.ndarray | None = None
    d_jac: np.ndarray | None = None
    dd_w: np.ndarray | None = None


def point_config_hessian(mdl: MeasurementModel, state: SetupState) -> np.ndarray | None:
    r""":math:`\partial^2 y/\partial q_k\partial q_l` of the model's position (n, 3, nv, nv) [m/rad²].

    For a serial chain, joint k before joint l moves joint l's axis and the
    point rigidly: :math:`\partial_k(\partial_l y) = \omega_k \times \partial_l y`
    (:math:`k \le l`), symmetric. None for a state with compliance or joint gains
    (:math:`q_{eff} \ne q`).
    """
    if not state.rigid:
        return None
    kin = state.kin
    axes = state.tracker.rotation.T @ kin.rotation @ kin.jacobian[:, 3:, :]  # (n, 3, nv)
    dy = mdl.compute_config_jacobian(state)  # (n, 3, nv)
    cross = np.cross(axes[:, :, :, None], dy[:, :, None, :], axis=1)  # [i, :, k, l]
    upper = np.triu(cross)
    return upper + np.swapaxes(np.triu(cross, 1), 2, 3)


def whitening_pieces(mdl: MeasurementModel, state: SetupState, free: np.ndarray, order: int,
                     known: NoisePieces | None = None) -> NoisePieces:
    r""":class:`NoisePieces` of ``mdl`` at ``state`` up to derivative ``order`` (0, 1 or 2) in q.

    ``known``: pieces of a lower order at the same state, reused (not recomputed).
    """
    if known is None:
        known = NoisePieces(mdl.noise.symmetric_whitening(mdl.compute_values(state))[0],
                            mdl.compute_param_jacobian(state)[:, :, free])
    if order == 0 or (order == 1 and known.d_w is not None):
        return known
    dd_y = point_config_hessian(mdl, state) if order >= 2 else None
    if known.d_w is not None and dd_y is None:
        return known
    y = mdl.compute_values(state)
    dy = mdl.compute_config_jacobian(state)  # (n, 3, nv)
    _, d_wy, dd_wy = mdl.noise.symmetric_whitening(y, 1 if dd_y is None else 2)  # [i, a, b, c(, e)]
    if known.d_w is None:
        known = known._replace(d_w=d_wy @ dy[:, None],
                               d_jac=mdl.compute_param_config_jacobian(state)[:, :, free, :])
    if dd_y is None:
        return known
    n, d, nv = dy.shape
    dy_t = np.swapaxes(dy, 1, 2)[:, None]  # (n, 1, nv, 3)
    dd_w = dy_t @ dd_wy.reshape(n, d * d, 3, 3) @ dy[:, None]  # (n, d*d, nv, nv)
    dd_w += (d_wy.reshape(n, d * d, 3) @ dd_y.reshape(n, 3, nv * nv)).reshape(n, d * d, nv, nv)
    return known._replace(dd_w=dd_w.reshape(n, d, d, nv, nv))


def whitened_rows(pc: NoisePieces) -> np.ndarray:
    r""":math:`W J`, (n, d, n_f)."""
    return pc.w @ pc.jac


def whitened_row_derivatives(pc: NoisePieces) -> np.ndarray:
    r""":math:`W\,\partial_k J + \partial_k W\,J`, (n, d, n_f, nv)."""
    n, d, nf, nv = pc.d_jac.shape
    out = (pc.w @ pc.d_jac.reshape(n, d, nf * nv)).reshape(n, d, nf, nv)
    out += np.moveaxis(np.moveaxis(pc.d_w, 3, 1) @ pc.jac[:, None], 1, 3)
    return out


def whitened_row_hessians(pc: NoisePieces, dd_jac: np.ndarray) -> np.ndarray:
    r""":math:`\partial_{kl}(W J)` (n, d, n_f, nv, nv) from ``dd_jac`` :math:`\partial_{kl}J`
    on the free parameters; without ``pc.dd_w`` the term :math:`\partial_{kl}W\,J` is left out."""
    n, d, nf, nv = pc.d_jac.shape
    out = (pc.w @ dd_jac.reshape(n, d, -1)).reshape(n, d, nf, nv, nv)
    # dW_k dJ_l as [j, a, k, f, l]: one (d nv, d) @ (d, nf nv) product per pose
    cross = (np.swapaxes(pc.d_w, 2, 3).reshape(n, d * nv, d) @ pc.d_jac.reshape(n, d, nf * nv))
    cross = cross.reshape(n, d, nv, nf, nv).transpose(0, 1, 3, 2, 4)  # [j, a, f, k, l]
    out += cross
    out += np.swapaxes(cross, 3, 4)
    if pc.dd_w is not None:  # ddW_kl J as [j, a, k, l, f]: one (d nv nv, d) @ (d, nf) per pose
        second = np.moveaxis(pc.dd_w, 2, 4).reshape(n, d * nv * nv, d) @ pc.jac
        out += second.reshape(n, d, nv, nv, nf).transpose(0, 1, 4, 2, 3)
    return out
