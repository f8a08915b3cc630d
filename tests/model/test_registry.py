"""Every robot the registry lists (``calib-oed robots``) works out of the box.

Each gets the same simple cell, scaled by its reach R (the largest distance of
the tool frame from the base over 200 seeded random configurations): the
robot on a pedestal (floor z >= -0.1 R), a box "car" in front of it, the
tracker at (0.6 R, -2.5 R, 0.6 R) facing the robot, one reflector 40 mm out
along tool z, the working configuration in the middle of the joint ranges, and
every other setting at its default: no per-robot exclusions or tweaks. The
test loads the scene (so it passes its own check), samples a feasible pool and
designs a few poses (few SQP iterations, no certificate), then checks the
design on the URDF collision geometry.

The meshed arms take seconds each to set up (collision fit and mesh pair
decisions), so only one of them is in the fast subset; ``pytest -m slow`` runs all.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.calibration.workflow import setup
from calib_oed.feasibility.mesh_check import check_design_meshes
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.model.registry import EXAMPLE_ROBOTS, OWN_ROBOTS, robot_names
from calib_oed.oed.design import design
from calib_oed.scene.reader import scene_from_dict
from calib_oed.solver.settings import SQPSettings

NOTIONAL = "notional_l650_m600"  # the paper's arm stands for the pattern
FAST = ("kr16", "kr300", "kr500", NOTIONAL, "ur3")


def listed() -> list[str]:
    return [NOTIONAL if n.startswith("notional_") else n for n in robot_names()]


def reach(robot) -> float:
    data = robot.model.createData()
    out = 0.0
    for q in robot.random_configurations(200, 0):
        pin.framesForwardKinematics(robot.model, data, q)
        out = max(out, float(np.linalg.norm(data.oMf[robot.tool_frame_id].translation)))
    return out


def simple_cell(name: str) -> dict:
    """The scene file (as a mapping, mm and deg) of ``name`` in the simple cell."""
    robot = load_robot(name)
    r = round(reach(robot) * 1e3)
    mid = np.rad2deg(0.5 * (robot.lower + robot.upper)).round(3)
    return {
        "version": 1, "name": f"simple_{name}", "units": {"length": "mm", "angle": "deg"},
        "robot": {"name": name},
        "tracker": {"position": [0.6 * r, -2.5 * r, 0.6 * r], "rpy": [0, 0, 90], "sigma": 0.01},
        "reflectors": [{"name": "smr0", "offset": [0, 0, 40]}],
        "kpi": {"working_configurations": [{"name": "middle", "q": mid.tolist()}]},
        "cell": {
            "halfspaces": [{"name": "floor", "z_min": -0.1 * r}],
            "boxes": [{"name": "car", "center": [1.6 * r, 0, 0.25 * r],
                       "size": [0.8 * r, 2.0 * r, 0.7 * r]}],
        },
    }


def test_the_cases_cover_every_listed_robot():
    assert set(OWN_ROBOTS) | set(EXAMPLE_ROBOTS) | {NOTIONAL} == set(listed())


def _case(name: str, fit: str = "default"):
    fast = name in FAST and fit == "default" or (name, fit) == ("kr16", "single")
    marks = [] if fast else [pytest.mark.slow]
    return pytest.param(name, fit, marks=marks, id=name if fit == "default" else f"{name}-{fit}")


@pytest.mark.parametrize(("name", "fit"), [_case(n) for n in listed()] + [_case(n, "single") for n in listed()])
def test_every_listed_robot_designs_in_a_simple_cell(name, fit):
    """With the default link geometry (``link_fit: hulls``) and with an explicit
    ``feasibility: {link_fit: single}``, one capsule per link (kr16 fast, the others slow)."""
    spec = simple_cell(name)
    if fit != "default":
        spec["feasibility"] = {"link_fit": fit}
    scene = scene_from_dict(spec)
    s = setup(scene)
    pool = sample_feasible(s.feasibility, 60, 0)
    d = design(s, n=10, pool=pool, seed=0, certificate=False,
               settings=SQPSettings(max_iterations=5))
    assert d.q.shape == (10, scene.robot.nq)
    assert d.feasible and s.feasibility.compute(d.q, jacobian=False).feasible.all()
    assert np.isfinite(d.value) and d.value <= d.start_value * (1 + 1e-9)
    assert np.all(np.isfinite(d.kpi_sigma_mm)) and np.all(d.kpi_sigma_mm > 0)
    meshes = check_design_meshes(
        scene.robot, d.q, scene.cell, tracker_position=scene.tracker.position,
        reflector_offsets=np.array([r.offset for r in scene.reflectors]),
        excluded_pairs=scene.feasibility.excluded_pairs)
    assert meshes.all_feasible(), meshes.summary()
