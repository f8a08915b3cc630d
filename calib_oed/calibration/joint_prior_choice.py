r"""The joint-space model-error prior of a design: the defaults for the robot's size class, with
what the scene (``robot.model_error: {kind: joint, ...}``) or an earlier identification
(``calib-oed design --prior-from``) sets (:class:`~calib_oed.scene.records.JointErrorSpec`).

**Amplitudes given at the points** (an identification's fitted kernel: an RMS :math:`s` per
Cartesian axis [m]) become joint angles through each joint's lever arm
:math:`\ell_k = \big(\mathrm{mean}_{j,r}\,\lVert J_k(q_j; c_r)\rVert^2\big)^{1/2}` [m/rad], the RMS
of the point Jacobian column of joint k over the problem's generic configurations and the
reflectors: a joint-angle error of RMS :math:`a_k` moves the points by the trace
:math:`a_k^2\ell_k^2` where the isotropic fit has :math:`3 s^2`. A harmonic amplitude of joint k is
its own, :math:`a_k = \sqrt3\,s_k/\ell_k`; the smooth part is shared by the joints it varies
with (finite length scale, set :math:`\mathcal K`), equally:
:math:`a = s\,\sqrt{3/\sum_{k\in\mathcal K}\ell_k^2}`. A joint that moves no point
(:math:`\ell_k \le 10^{-9}\max_l \ell_l`) gets zero.
"""

from __future__ import annotations

import numpy as np

from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.joint_prior import AMPLITUDES, PARTS, JointErrorPrior, point_jacobians
from calib_oed.measurement.pose_scale import PoseScale

#: Relative lever arm [1] below which a joint moves no point (as :data:`calib_oed.oed.model_error.STILL_TOL`).
STILL_TOL = 1e-9
#: Configurations of the generic design the lever arms are averaged over.
LEVER_CONFIGURATIONS = 20
#: Joint deflection under gravity [rad] from which :func:`deflection_note` warns: the prior is
#: linear in the deflections. On ``fms_kr300`` (up to 3.2 mrad, a 300 kg payload, compliance not
#: identified) the design's promise was 2.4x optimistic on the realistic simulator, on
#: ``fms_kr500`` (6.0 mrad, 500 kg) 12x; the other shipped scenes' arms deflect by at most
#: 0.4 mrad, the UR10 and Panda cells of ``bench/scenes`` by 0.8, and their promises hold
#: (``docs/oed.md``).
DEFLECTION_NOTE = 1e-3


def lever_arms(problem) -> np.ndarray:
    r""":math:`\ell_k` per joint [m/rad] (module docstring), (nv,)."""
    offsets = problem.space.reflector_offsets(None)
    q = problem.generic_configurations()[:LEVER_CONFIGURATIONS]
    jac = point_jacobians(problem, offsets).compute(q)[0]  # (n, r, 3, nv)
    return np.sqrt(np.mean(np.sum(jac**2, axis=2), axis=(0, 1)))


def joint_prior(problem, spec=None) -> JointErrorPrior:
    """The joint-space prior of ``problem``: the size-class default, the arm loaded by the
    problem's payload (modelled or not) and the reflector nest at the reflectors, with what
    ``spec`` (a :class:`~calib_oed.scene.records.JointErrorSpec` or None) sets."""
    base = JointErrorPrior.default_for(problem.robot, getattr(problem, "payload", None),
                                       problem.space.reflector_offsets(None))
    if spec is None:
        return base
    parts = {name: np.array(getattr(base, name), dtype=float) for name in PARTS}
    for name, values in spec.values.items():
        given = np.asarray(values, dtype=float)
        parts[name] = np.where(np.isnan(given), parts[name], given)
    if spec.at_point:
        lever = lever_arms(problem)
        moves = lever > STILL_TOL * lever.max()
        for name in ("once", "twice"):
            if name in spec.at_point:
                s = np.asarray(spec.at_point[name], dtype=float)
                parts[name] = np.where(moves, np.sqrt(3.0) * s / np.where(moves, lever, 1.0), 0.0)
        if "smooth" in spec.at_point:
            s = np.asarray(spec.at_point["smooth"], dtype=float)
            shared = (s > 0) & moves
            total = float(np.sum(lever[shared] ** 2))
            parts["smooth"] = np.where(shared, s * np.sqrt(3.0 / total) if total > 0 else 0.0, 0.0)
    f = spec.scale
    for name in AMPLITUDES:
        parts[name] = parts[name] * f
    return JointErrorPrior(**parts, gravity=base.gravity, source=f"{spec.source} ({base.source})")


def pose_scale(problem, spec=None) -> PoseScale:
    """The pose scale of a fitted model error (:mod:`calib_oed.measurement.pose_scale`): the shape
    of :func:`joint_prior` at the centre of ``problem``'s nominal reflectors, weight 1 and mean
    variance 1 until the fit normalises and weighs it."""
    centre = np.mean(problem.space.reflector_offsets(None), axis=0)
    return PoseScale(joint_prior(problem, spec), point_jacobians(problem, centre[None]))


def fitted_model_error(data, space, source: str = "identification") -> DiscrepancyPrior:
    """The fitted model error of an ``identification.json`` (``model_error.fitted``) with its pose
    scale restored for ``space`` (the scene's parameter space: its robot and payload;
    :meth:`PoseScale.from_dict`); :meth:`DiscrepancyPrior.from_dict` alone gives the stationary part.

    Raises:
        ParameterError: the record is malformed.
    """
    prior = DiscrepancyPrior.from_dict(data, space.robot.nq, source)
    recorded = data.get("pose_scale")
    return prior if not recorded else prior.with_scale(PoseScale.from_dict(recorded, space))


def deflection_note(problem, prior) -> str | None:
    """A note when ``prior``'s compliance part deflects a joint by :data:`DEFLECTION_NOTE` or more over
    ``problem``'s generic configurations and the model does not identify compliance; else None."""
    if not isinstance(prior, JointErrorPrior) or getattr(problem.space, "compliance", None) is not None:
        return None
    d = np.abs(prior.compute_deflections(problem.generic_configurations()))
    if d.max(initial=0.0) < DEFLECTION_NOTE:
        return None
    joint = problem.robot.joint_names[int(np.argmax(d.max(axis=0)))]
    return (f"the arm's joints deflect under gravity by up to {d.max() * 1e3:.2g} mrad ({joint}, "
            f"{prior.source}) and compliance is not identified: the design criterion is linear in the "
            "deflection, so its predicted KPI error can be far too optimistic (2.4x at 3.2 mrad on "
            "fms_kr300, 12x at 6 mrad on fms_kr500; docs/oed.md); --compliance identifies it")
