"""Shared fixtures: the three robots of the derivative tests and their set-ups."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.model.parameters import ParameterSpace

ROBOTS = ("ur5", "panda", "kr16")


@pytest.fixture(scope="session", params=ROBOTS)
def robot(request):
    return load_robot(request.param)


def make_space(robot, reflectors=((0.03, -0.01, 0.05), (0.0, 0.04, 0.02))):
    """A tracker about 2.5 m away, looking back at the robot, and two reflectors."""
    tracker = pin.SE3(pin.rpy.rpyToMatrix(0.02, -0.03, 2.4), np.array([1.8, 1.6, 0.4]))
    return ParameterSpace(robot, tracker, np.array(reflectors))


@pytest.fixture(scope="session")
def space(robot):
    return make_space(robot)


def central_difference(fun, x, eps=1e-6):
    """Central finite differences of ``fun`` (array-valued) at ``x``: shape fun.shape + (n,)."""
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(fun(x))
    out = np.zeros(f0.shape + (x.size,))
    for k in range(x.size):
        dx = np.zeros_like(x)
        dx.flat[k] = eps
        out[..., k] = (np.asarray(fun(x + dx)) - np.asarray(fun(x - dx))) / (2 * eps)
    return out


def relative_error(analytic, numeric):
    """Largest absolute difference relative to the largest entry."""
    return float(np.abs(analytic - numeric).max() / max(np.abs(numeric).max(), 1e-300))
