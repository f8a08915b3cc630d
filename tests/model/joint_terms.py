"""What the joint-term tests share (test_compliance.py, test_joint_gains.py): the measurement
models, a tracker and two reflectors, and central differences along unit-scaled parameters."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from conftest import central_difference, relative_error

from calib_oed.measurement import PoseMeasurement, TrackerPosition

MODELS = {
    "position": lambda: TrackerPosition(1, sigma=1e-5),
    "pose": lambda: PoseMeasurement(0, sigma=1e-5, sigma_angle=2e-5),
}
REFLECTORS = np.array(((0.03, -0.01, 0.05), (0.0, 0.04, 0.02)))
#: Relative error allowed against central differences.
TOL = 1e-6


def tracker() -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(0.02, -0.03, 2.4), np.array([1.8, 1.6, 0.4]))


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
