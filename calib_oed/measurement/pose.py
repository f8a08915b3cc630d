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
        :math:`H_k = d J_{\log}/dq_k` = ``pin.Hlog3(R_{T,P}, w_k)``, and
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
        hlog = np.array([[pin.Hlog3(rot[i], w[i, :, k]) for k in range(nv)] for i in range(n)])
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
