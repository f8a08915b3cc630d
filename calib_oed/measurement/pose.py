r"""6-D pose measurement: a tracker with a 6-DoF probe, or an optical CMM.

The probe frame :math:`P` sits on the tool at the reflector offset
:math:`c_j` with a fixed nominal orientation :math:`R_{F,P}`. The sensor
reports its position and orientation in the sensor (tracker) frame:

.. math::
    h(p, q) = \big({}^{T}t_P,\; \log_3 R_{T,P}\big) \in \mathbb{R}^6,\qquad
    R_{T,P} = R_T^\top\, R_{W,F}(q)\, R_{F,P}

(position [m], rotation vector [rad]). The position rows are those of
:class:`~calib_oed.measurement.position.TrackerPosition`; the rotation rows,
with :math:`\omega` the LOCAL angular part of the tool-frame regressor or
Jacobian and :math:`J_{\log}` = ``pin.Jlog3``:

.. math::
    \frac{\partial \log R_{T,P}}{\partial \delta_i} = J_{\log}\,R_{F,P}^\top\,\omega_{K,i}\,J_r(\delta_i),
    \qquad
    \frac{\partial \log R_{T,P}}{\partial \delta_T} = J_{\log}\,[\,0\;\; -R_{T,P}^\top\,]\,J_r(\delta_T),
    \qquad
    \frac{\partial \log R_{T,P}}{\partial q} = J_{\log}\,R_{F,P}^\top\,\omega_J .

The orientation of the probe on the tool is not a parameter (the binding
layout has a 3-vector per reflector). Its rotation about the last joint axis
is redundant with that joint's placement; its two tilts are not representable,
so they are taken as known: with this model the identifiable count is
4R + 2P + 6 - 2 (docs/conventions.md).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from calib_oed.measurement.base import MeasurementModel, SetupState, skew
from calib_oed.measurement.position import DEFAULT_SIGMA, TrackerPosition
from calib_oed.measurement.second_order import joint_rows_hessian, with_joint_gains
from calib_oed.model.kinematics import log_jacobian_derivative, log_jacobian_second_derivative

#: Default rotation noise per axis [rad] (0.01 mrad).
DEFAULT_SIGMA_ANGLE = 1e-5


class PoseMeasurement(MeasurementModel):
    """Probe pose (position and rotation vector) in the sensor frame.

    Args:
        reflector: Index j of the reflector/probe offset parameter.
        sigma: Position noise per axis [m], scalar or (3,).
        sigma_angle: Rotation noise per axis [rad], scalar or (3,).
        probe_rotation: Nominal :math:`R_{F,P}` (3, 3); identity by default.
    """

    dim = 6
    labels = ("x", "y", "z", "rx", "ry", "rz")
    units = ("m", "m", "m", "rad", "rad", "rad")

    def __init__(
        self,
        reflector: int = 0,
        sigma: float | np.ndarray = DEFAULT_SIGMA,
        sigma_angle: float | np.ndarray = DEFAULT_SIGMA_ANGLE,
        probe_rotation: np.ndarray | None = None,
    ):
        s = np.broadcast_to(np.asarray(sigma, dtype=float), (3,))
        a = np.broadcast_to(np.asarray(sigma_angle, dtype=float), (3,))
        super().__init__(np.concatenate([s, a]))
        self._position = TrackerPosition(reflector, s)
        self.reflector = int(reflector)
        rot = np.eye(3) if probe_rotation is None else np.asarray(probe_rotation, dtype=float)
        if rot.shape != (3, 3) or not np.allclose(rot.T @ rot, np.eye(3), atol=1e-9):
            raise ValueError("probe_rotation must be a 3x3 rotation matrix")
        self.probe_rotation = rot

    @property
    def name(self) -> str:
        return f"probe{self.reflector}"

    def _rotations(self, state: SetupState) -> np.ndarray:
        return state.tracker.rotation.T @ state.kin.rotation @ self.probe_rotation

    def compute_values(self, state: SetupState) -> np.ndarray:
        rot = self._rotations(state)
        logs = np.array([pin.log3(r) for r in rot])
        return np.concatenate([self._position.compute_values(state), logs], axis=1)

    @staticmethod
    def _jlog(rotations: np.ndarray) -> np.ndarray:
        return np.array([pin.Jlog3(r) for r in rotations])

    def compute_param_jacobian(self, state: SetupState) -> np.ndarray:
        space = state.space
        out = np.zeros((state.n, 6, space.size))
        out[:, :3, :] = self._position.compute_param_jacobian(state)
        rot = self._rotations(state)
        jlog = self._jlog(rot)
        tracker = np.zeros((state.n, 3, 6))
        tracker[:, :, 3:] = -np.transpose(rot, (0, 2, 1))
        delta_t = state.p[space.tracker_slice]
        if np.any(delta_t):
            tracker = tracker @ pin.Jexp6(delta_t)
        out[:, 3:, space.tracker_slice] = jlog @ tracker
        omega = self.probe_rotation.T @ state.kin.regressor[:, 3:, :]
        rows = out[:, 3:]  # a view: the state writes the joint and compliance columns into it
        state.fill_joint_columns(rows, jlog @ omega)
        return out

    def compute_config_jacobian(self, state: SetupState) -> np.ndarray:
        out = np.empty((state.n, 6, state.kin.jacobian.shape[2]))
        out[:, :3, :] = self._position.compute_config_jacobian(state)
        jlog = self._jlog(self._rotations(state))
        out[:, 3:, :] = state.chain_config(jlog @ (self.probe_rotation.T @ state.kin.jacobian[:, 3:, :]))
        return out

    def compute_param_config_jacobian(self, state: SetupState) -> np.ndarray:
        r"""Position rows as :class:`TrackerPosition`; rotation rows below.

        With :math:`w_k = R_{F,P}^\top \omega_{J,k}` the probe-frame rotation
        rate of joint ``k`` (:math:`R_{T,P}(q + dq_k) = R_{T,P}\exp(w_k\,dq_k)`),
        :math:`H_k = d J_{\log}/dq_k` = ``pin.Hlog3(R_{T,P}, w_k)`` (computed as
        :math:`DJ_{\log}(\theta)[J_{\log}w_k]`, :func:`~calib_oed.model.kinematics.log_jacobian_derivative`,
        exact also near :math:`R_{T,P} = I` where ``Hlog3`` is not), and
        :math:`\partial\omega_K/\partial q_k` the angular rows of
        :func:`~calib_oed.model.kinematics.regressor_config_derivative`:

        .. math::
            \partial_k\big(J_{\log} R_{F,P}^\top \omega_K\big)
                &= H_k R_{F,P}^\top \omega_K + J_{\log} R_{F,P}^\top\,\partial_k\omega_K,\\
            \partial_k\big(J_{\log} [\,0\;\; -R_{T,P}^\top]\big)
                &= H_k [\,0\;\; -R_{T,P}^\top] + J_{\log} [\,0\;\; [w_k]_\times R_{T,P}^\top],

        each times the right Jacobians :math:`J_r` of the perturbations (all
        along :math:`q_{eff}`; with compliance the state adds :math:`D` and the
        compliance columns, :meth:`SetupState.finish_param_config`).
        """
        space = state.space
        n = state.n
        nv = state.kin.jacobian.shape[2]
        out = np.zeros((n, 6, space.size, nv))
        out[:, :3] = self._position.compute_param_config_jacobian(state)
        rot = self._rotations(state)
        jlog = self._jlog(rot)
        w = self.probe_rotation.T @ state.kin.jacobian[:, 3:, :]  # (n, 3, nv)
        _, _, hlog = self._log_rates(rot, jlog, np.moveaxis(w, 1, 2))
        omega = self.probe_rotation.T @ state.kin.regressor[:, 3:, :]  # (n, 3, 6nj)
        omega_q = np.einsum("ab,nbcq->nacq", self.probe_rotation.T,
                            state.regressor_q[:, 3:])
        joints = np.einsum("nqab,nbc->nacq", hlog, omega) + np.einsum("nab,nbcq->nacq", jlog, omega_q)
        rows = np.zeros((n, 3, space.size, nv))
        rows[:, :, space.joints_slice] = state.joint_param_config_sensitivity(joints)
        rot_t = np.transpose(rot, (0, 2, 1))
        trk = np.zeros((n, nv, 3, 6))
        trk[:, :, :, 3:] = (-np.einsum("nqab,nbc->nqac", hlog, rot_t)
                            + jlog[:, None] @ skew(np.moveaxis(w, 1, 2)) @ rot_t[:, None])
        delta_t = state.p[space.tracker_slice]
        if np.any(delta_t):
            trk = trk @ pin.Jexp6(delta_t)
        rows[:, :, space.tracker_slice] = np.moveaxis(trk, 1, 3)
        out[:, 3:] = state.finish_param_config(rows, jlog @ omega, joints)
        return out

    @staticmethod
    def _log_rates(rot: np.ndarray, jlog: np.ndarray, w: np.ndarray):
        r""":math:`\theta = \log_3 R_{T,P}` (n, 3), which moves by :math:`\theta_k = J_{\log}w_k`
        (n, nv, 3) along :math:`q_k`, and :math:`H_k = DJ_{\log}[\theta_k]` (n, nv, 3, 3)."""
        theta = np.array([pin.log3(r) for r in rot])
        th_k = np.einsum("nab,nkb->nka", jlog, w)
        return theta, th_k, log_jacobian_derivative(theta[:, None], th_k)

    def compute_param_config_hessian(self, state: SetupState) -> np.ndarray | None:
        r"""Second configuration derivative of the rows, (n, 6, n_p, nv, nv); None with compliance.

        Position rows as :class:`TrackerPosition`. Rotation rows: with
        :math:`\theta_k = J_{\log}w_k`, :math:`H_k = DJ_{\log}[\theta_k]`,
        :math:`\theta_{kl} = H_l w_k + J_{\log}\,\partial_l w_k` and
        :math:`H_{kl} = D^2J_{\log}[\theta_k, \theta_l] + DJ_{\log}[\theta_{kl}]`
        (:mod:`calib_oed.model.kinematics`), differentiating the terms of
        :meth:`compute_param_config_jacobian` along :math:`q_l`:

        .. math::
            \partial_{kl}\big(J_{\log}\tilde\omega_K\big)
              &= H_{kl}\tilde\omega_K + H_k\,\partial_l\tilde\omega_K
                 + H_l\,\partial_k\tilde\omega_K + J_{\log}\,\partial_{kl}\tilde\omega_K,
              \qquad \tilde\omega_K = R_{F,P}^\top\omega_K,\\
            \partial_{kl}\big(J_{\log}[\,0\;\;-R_{T,P}^\top]\big)
              &= \big[\,0\;\; \big(-H_{kl} + H_k[w_l]_\times + H_l[w_k]_\times
                 + J_{\log}([\partial_l w_k]_\times - [w_k]_\times[w_l]_\times)\big)R_{T,P}^\top\big]

        (``docs/derivations.md`` §13), times the right Jacobians :math:`J_r`.
        """
        if not state.rigid:  # joint gains from the rigid rows; None with compliance
            return with_joint_gains(self, state)
        space, kin = state.space, state.kin
        n, nv = state.n, kin.jacobian.shape[2]
        out = np.zeros((n, 6, space.size, nv, nv))
        self._position.compute_param_config_hessian(state, out=out[:, :3])
        rot = self._rotations(state)
        jlog = self._jlog(rot)
        rfp = self.probe_rotation.T
        w = np.moveaxis(rfp @ kin.jacobian[:, 3:, :], 1, 2)  # (n, nv, 3): w_k
        w_q = np.einsum("ab,nbkl->nkla", rfp, state.jacobian_q[:, 3:])  # d_l w_k, (n, k, l, 3)
        theta, th_k, hk = self._log_rates(rot, jlog, w)
        theta = theta[:, None, None]
        th_kl = np.einsum("nlab,nkb->nkla", hk, w) + np.einsum("nab,nklb->nkla", jlog, w_q)
        hkl = (log_jacobian_second_derivative(theta, th_k[:, :, None], th_k[:, None, :])
               + log_jacobian_derivative(theta, th_kl))  # (n, k, l, 3, 3)
        rows = out[:, 3:]  # a view
        lams = [np.zeros(a.shape[:-1] + (6,)) for a in (jlog, hk, hkl)]  # Lambda = [0, J_log R_FP^T]
        for lam, a in zip(lams, (jlog, hk, hkl), strict=True):
            lam[..., 3:] = a @ rfp
        rows[:, :, space.joints_slice] = joint_rows_hessian(state, *lams)
        sw = skew(w)  # (n, nv, 3, 3)
        mixed = hk[:, :, None] @ sw[:, None, :]  # H_k [w_l]x
        inner = (-hkl + mixed + np.swapaxes(mixed, 1, 2)
                 + jlog[:, None, None] @ (skew(w_q) - sw[:, :, None] @ sw[:, None, :]))
        trk = np.zeros((n, nv, nv, 3, 6))
        trk[..., 3:] = inner @ np.transpose(rot, (0, 2, 1))[:, None, None]
        delta_t = state.p[space.tracker_slice]
        if np.any(delta_t):
            trk = trk @ pin.Jexp6(delta_t)
        rows[:, :, space.tracker_slice] = np.moveaxis(trk, (1, 2), (3, 4))
        return out
