"""Shared fixtures: the three robots of the derivative tests and their set-ups."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.model.parameters import Group, ParameterSpace

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


def random_parameters(space: ParameterSpace, rng, sigma_length: float = 0.5e-3, sigma_angle: float = 0.5e-3,
                      sigma_compliance: float = 1e-6, sigma_gain: float = 1e-3) -> np.ndarray:
    """Random parameters of ``space``, normal with the given standard deviations [m], [rad],
    [rad/(N·m)], [1] (``rng`` a seed or a Generator)."""
    rng = np.random.default_rng(rng)
    table = {"m": sigma_length, "rad": sigma_angle}
    sd = np.array([sigma_gain if p.group in (Group.GAIN, Group.COUPLING)
                   else table.get(p.unit, sigma_compliance) for p in space.parameters])
    return rng.normal(size=space.size) * sd


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


def smooth_difference(fun, x, eps=1e-6, agree=1e-6):
    """Central differences of ``fun`` (values (m,)) at ``x`` with steps ``eps`` and ``2 eps``, and the
    rows (m,) where the two agree to ``agree`` relative to the row's largest entry (at least 1e-3):
    rows with no kink (a switch of coal's witness features) within the step. A kink between
    ``x - 2 eps`` and ``x + 2 eps`` changes the two differences by different amounts."""
    num = central_difference(fun, x, eps)
    second = central_difference(fun, x, 2 * eps)
    scale = np.maximum(np.abs(num).max(axis=-1), 1e-3)
    return num, np.abs(num - second).max(axis=-1) <= agree * scale


def relative_error(analytic, numeric):
    """Largest absolute difference relative to the largest entry."""
    return float(np.abs(analytic - numeric).max() / max(np.abs(numeric).max(), 1e-300))


@pytest.fixture(scope="session", autouse=True)
def _fresh_geometry_cache(tmp_path_factory):
    """The on-disk cache of link fits and mesh pairs (``feasibility/fit_cache.py``) in a
    fresh folder: tests never read a stale entry nor write to the user's cache."""
    patch = pytest.MonkeyPatch()
    patch.setenv("CALIB_OED_CACHE_DIR", str(tmp_path_factory.mktemp("geometry_cache")))
    yield
    patch.undo()


# ---- fms_kr16: its scene, set-up, continuous check (tests/program) and feasible poses


@pytest.fixture(scope="session")
def kr16_scene():
    from calib_oed.scene.reader import load_scene

    return load_scene("fms_kr16")


@pytest.fixture(scope="session")
def kr16_checker(kr16_scene):
    from calib_oed.program.build import move_checker
    from calib_oed.program.settings import ProgramSettings

    return move_checker(kr16_scene, ProgramSettings())


@pytest.fixture(scope="session")
def kr16_setup(kr16_scene):
    """fms_kr16's set-up (calibration problem and feasibility model), built once per session
    (per xdist worker). Read-only: a test that changes it builds its own with ``setup``."""
    from calib_oed.calibration.workflow import setup

    return setup(kr16_scene)


@pytest.fixture(scope="session")
def kr16(kr16_setup):
    """``kr16_setup`` by its short name; a test module may define its own ``kr16`` (a robot, or the
    set-up with poses) from ``kr16_setup``, which keeps its name everywhere."""
    return kr16_setup


@pytest.fixture(scope="session")
def kr16_poses(kr16_setup) -> np.ndarray:
    """12 poses that keep every constraint of the scene (the design's model), seed 3; read-only."""
    from calib_oed.feasibility.sampling import sample_feasible

    poses = sample_feasible(kr16_setup.feasibility, 12, 3)
    poses.setflags(write=False)
    return poses


@pytest.fixture(scope="session")
def ur5_checker():
    """ur5_table's continuous check (rows on convex pieces of the link geometry, a UR's
    joints of two turns in the design joint window), built once per session."""
    from calib_oed.program.build import move_checker
    from calib_oed.program.settings import ProgramSettings
    from calib_oed.scene.reader import load_scene

    return move_checker(load_scene("ur5_table"), ProgramSettings())
