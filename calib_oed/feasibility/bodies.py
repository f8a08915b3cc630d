r"""Placements and Jacobians of all joint bodies, batched over configurations.

Body :math:`k` is joint :math:`k`'s frame (``data.oMi[k]``); body 0 is the world
(the robot base), fixed. For a point :math:`x` fixed on body :math:`k` the
world-aligned point Jacobian is

.. math::
    J_x = J^{lin}_k - [x - t_k]_\times J^{ang}_k \in \mathbb{R}^{3\times n_v},

with :math:`J_k` Pinocchio's ``LOCAL_WORLD_ALIGNED`` joint Jacobian (linear
velocity of the joint origin :math:`t_k` and angular velocity, world axes).
For a unit direction :math:`u` the code only needs the row
:math:`u^\top J_x = u^\top J^{lin}_k + \big((x - t_k)\times u\big)^\top J^{ang}_k`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.model.kinematics import cross


@dataclass(frozen=True, eq=False)
class BodyStates:
    """World placements (and optionally Jacobians) of every body.

    Attributes:
        rotation: :math:`R_{W,k}`, (n, nb, 3, 3); body 0 is the identity.
        translation: :math:`t_{W,k}` [m], (n, nb, 3).
        jacobian: ``LOCAL_WORLD_ALIGNED`` joint Jacobians, (n, nb, 6, nv),
            rows (linear, angular); body 0 is zero. ``None`` if not computed.
    """

    rotation: np.ndarray
    translation: np.ndarray
    jacobian: np.ndarray | None

    def take(self, index: np.ndarray) -> BodyStates:
        """The states of a subset of the configurations."""
        jac = None if self.jacobian is None else self.jacobian[index]
        return BodyStates(self.rotation[index], self.translation[index], jac)

    def points(self, body: np.ndarray, local: np.ndarray) -> np.ndarray:
        """World points (n, s, 3) of points ``local`` (s, 3) fixed on bodies ``body`` (s,)."""
        return np.einsum("nsij,sj->nsi", self.rotation[:, body], local) + self.translation[:, body]

    def directional_jacobian(self, body: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        r""":math:`u^\top J_x` (n, s, nv) for points ``x`` (n, s, 3) on bodies ``body`` (s,)
        and directions ``u`` (n, s, 3)."""
        jac = self.jacobian[:, body]  # (n, s, 6, nv)
        lever = cross(x - self.translation[:, body], u)
        return np.einsum("nsi,nsiv->nsv", u, jac[:, :, :3]) + np.einsum(
            "nsi,nsiv->nsv", lever, jac[:, :, 3:]
        )


def compute_body_states(model: pin.Model, q: np.ndarray, jacobian: bool = True) -> BodyStates:
    """Forward kinematics (and joint Jacobians) at configurations ``q`` (n, nq)."""
    data = model.createData()
    n, nb = q.shape[0], model.njoints
    hom = np.empty((n, nb, 4, 4))
    jac = np.zeros((n, nb, 6, model.nv)) if jacobian else None
    placements, joint_jacobian, frame = data.oMi, pin.getJointJacobian, pin.LOCAL_WORLD_ALIGNED
    for k, qk in enumerate(q):  # the Python wrappers fetched once: this loop is per pose
        hom_k = hom[k]
        if jacobian:
            pin.computeJointJacobians(model, data, qk)
            jac_k = jac[k]
            for j in range(1, nb):
                jac_k[j] = joint_jacobian(model, data, j, frame)
        else:
            pin.forwardKinematics(model, data, qk)
        for j in range(nb):
            hom_k[j] = placements[j].homogeneous
    return BodyStates(hom[:, :, :3, :3], hom[:, :, :3, 3], jac)
