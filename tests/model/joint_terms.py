"""What the joint-term tests share (test_joint_terms.py, test_compliance.py, test_joint_gains.py):
the measurement models, a tracker and two reflectors, the joint terms (compliance, gains and
couplings, both) with parameters large enough for every term to show, and central differences
along unit-scaled parameters."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from conftest import central_difference, random_parameters, relative_error

from calib_oed.measurement import PoseMeasurement, TrackerPosition
from calib_oed.model.compliance import Compliance
from calib_oed.model.joint_map import JointGains
from calib_oed.model.parameters import ParameterSpace

MODELS = {
    "position": lambda: TrackerPosition(1, sigma=1e-5),
    "pose": lambda: PoseMeasurement(0, sigma=1e-5, sigma_angle=2e-5),
}
REFLECTORS = np.array(((0.03, -0.01, 0.05), (0.0, 0.04, 0.02)))
#: Relative error allowed against central differences.
TOL = 1e-6
PAYLOAD = Compliance(12.0, [0.02, -0.03, 0.15])
GAINS = JointGains((1, 2, 3, 5), ((3, 2), (1, 4)))
#: The joint terms a parameter space may add to the geometric parameters.
TERMS = ("compliance", "gains", "gains+compliance")


def tracker() -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(0.02, -0.03, 2.4), np.array([1.8, 1.6, 0.4]))


@dataclass(frozen=True)
class JointTerm:
    """A space with joint terms, parameters at which every term shows, and the terms' columns."""

    space: ParameterSpace
    p: np.ndarray
    added: slice


def joint_term(robot, kind: str) -> JointTerm:
    """Geometric errors of 5 mm / 5 mrad; gains and couplings of 2 %; compliances scaled so that
    the largest deflection is tens of mrad (every term of D = I + diag(c) dtau/dq shows)."""
    gains = GAINS if "gains" in kind else None
    comp = (PAYLOAD if kind == "compliance" else Compliance(8.0, [0.0, 0.02, 0.1])) if "compliance" in kind else None
    space = ParameterSpace(robot, tracker(), REFLECTORS, compliance=comp, joint_gains=gains)
    p = random_parameters(space, 4, 5e-3, 5e-3, sigma_gain=2e-2)
    if comp is not None:
        tau = np.abs(space.gravity.torques(robot.random_configurations(50, 0))).max(axis=0)
        scale = 0.01 if gains else np.random.default_rng(5).uniform(0.5, 1.0, space.n_joints) * 0.02
        p[space.compliance_slice] = scale / np.maximum(tau, 1.0)
    plain = ParameterSpace(robot, tracker(), REFLECTORS).size
    return JointTerm(space, p, slice(plain, space.size))


def scaled_difference(fun, space, p):
    """Central differences along unit-scaled parameters (1 mm, 1 mrad, ...), unscaled back."""
    scale = space.unit_scale
    return central_difference(lambda x: fun(p + scale * x), np.zeros(space.size), eps=1e-3) / scale


def compare_scaled(analytic, numeric, scale, axis=-1):
    """Relative error of two derivatives along parameters, both in unit-scaled parameters."""
    shape = [1] * analytic.ndim
    shape[axis] = -1
    s = scale.reshape(shape)
    return relative_error(analytic * s, numeric * s)
