r"""Forward kinematics of many configurations at once, for the sampling of feasible poses.

:func:`~calib_oed.feasibility.bodies.compute_body_states` calls Pinocchio once
per configuration; the rejection sampling of the pool
(:mod:`calib_oed.feasibility.sampling`) evaluates some 200,000 uniform draws
to keep 3000 (``fms_kr16``), and the per-configuration Python loop was most
of its time. For a chain of one-degree-of-freedom joints the placements are
products that vectorise over the draws:

.. math::
    T_{W,i}(q) = T_{W,\lambda(i)}(q)\;M_i\;X_i(q_i),\qquad
    X_i(q_i) = \begin{cases}
      (\exp_3(q_i\,a_i),\ 0) & \text{revolute about the unit axis } a_i\\
      (I,\ q_i\,a_i\ [\mathrm{m}]) & \text{prismatic along } a_i
    \end{cases}

with :math:`\lambda(i)` the parent joint, :math:`M_i` = ``model.jointPlacements[i]``
and the rotation :math:`\exp_3(\theta a) = \cos\theta\,I + \sin\theta\,[a]_\times +
(1 - \cos\theta)\,a a^\top` (Rodrigues, as Pinocchio computes it), all in the world (robot base)
frame :math:`W`, lengths in m, angles in rad. The joint axes :math:`a_i` and
placements are read from the Pinocchio model; a model with any other joint
type (spherical, free flyer, continuous joints with two coordinates, mimic
joints) falls back to Pinocchio per configuration, so the result is always
that of :func:`~calib_oed.feasibility.bodies.compute_body_states` (tested to
1e-12 against it).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from calib_oed.feasibility.bodies import BodyStates, compute_body_states

#: Pinocchio joint types with a fixed unit axis: (revolute?, axis).
_AXES = {
    "JointModelRX": (True, (1.0, 0.0, 0.0)), "JointModelRY": (True, (0.0, 1.0, 0.0)),
    "JointModelRZ": (True, (0.0, 0.0, 1.0)), "JointModelPX": (False, (1.0, 0.0, 0.0)),
    "JointModelPY": (False, (0.0, 1.0, 0.0)), "JointModelPZ": (False, (0.0, 0.0, 1.0)),
}


def _joint_axes(model: pin.Model) -> list[tuple[bool, np.ndarray, int]] | None:
    """Per joint 1..njoints-1: (revolute?, axis in the joint frame, index in q), or None
    when a joint is not a one-coordinate revolute or prismatic joint."""
    out = []
    for i in range(1, model.njoints):
        joint = model.joints[i]
        if joint.nq != 1 or joint.nv != 1:
            return None
        name = joint.shortname()
        if name in _AXES:
            revolute, axis = _AXES[name]
            out.append((revolute, np.array(axis), joint.idx_q))
        elif name in ("JointModelRevoluteUnaligned", "JointModelPrismaticUnaligned"):
            # as Pinocchio, the axis as stored (unit for a URDF's joints)
            axis = np.asarray(joint.extract().axis, dtype=float)
            out.append((name == "JointModelRevoluteUnaligned", axis, joint.idx_q))
        else:
            return None
    return out


def batch_body_states(model: pin.Model, q: np.ndarray) -> BodyStates:
    r"""World placements of every body at configurations ``q`` (n, nq) [rad, m], no Jacobians.

    The same :class:`~calib_oed.feasibility.bodies.BodyStates` as
    ``compute_body_states(model, q, jacobian=False)``, vectorised over the
    configurations (module docstring).
    """
    q = np.asarray(q, dtype=float)
    axes = _joint_axes(model)
    if axes is None:
        return compute_body_states(model, q, jacobian=False)
    n, nb = q.shape[0], model.njoints
    rot = np.empty((n, nb, 3, 3))
    trans = np.empty((n, nb, 3))
    rot[:, 0] = np.eye(3)
    trans[:, 0] = 0.0
    for i, (revolute, a, iq) in enumerate(axes, start=1):
        parent = model.parents[i]
        placement = model.jointPlacements[i]
        r_p = rot[:, parent] @ placement.rotation  # R_{W,λ(i)} M_i.R, (n, 3, 3)
        t_i = trans[:, parent] + rot[:, parent] @ placement.translation
        theta = q[:, iq]
        if revolute:
            s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
            motion = c * np.eye(3) + s * pin.skew(a) + (1.0 - c) * np.outer(a, a)  # exp3(θ a)
            rot[:, i] = r_p @ motion
        else:
            rot[:, i] = r_p
            t_i = t_i + theta[:, None] * (r_p @ a)
        trans[:, i] = t_i
    return BodyStates(rot, trans, None)
