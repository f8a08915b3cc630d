"""Parameter tables: classic DH, modified DH and Hayati rows reproduce the model; the residual is named."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from conftest import random_parameters

from calib_oed import load_robot
from calib_oed.exceptions import ParameterTableError
from calib_oed.model.dh import CONVENTIONS, compute_table
from calib_oed.model.parameters import ParameterSpace

TOL = 1e-9


def _calibrated(name: str, seed: int):
    robot = load_robot(name)
    space = ParameterSpace(robot, pin.SE3.Identity(), np.zeros((1, 3)))
    return replace(robot, model=space.perturbed_model(random_parameters(space, seed)))


@pytest.mark.parametrize("convention", CONVENTIONS)
@pytest.mark.parametrize("name", ["kr16", "ur5", "panda"])
def test_nominal_tables_are_exact(name, convention):
    robot = load_robot(name)
    table = compute_table(robot, convention)
    assert table.residual_m < TOL and table.residual_rad < TOL
    dp, dr = table.compute_difference(robot, robot.random_configurations(30, 7))   # fresh poses
    assert dp < TOL and dr < TOL


def test_kuka_modified_dh_is_the_textbook_table():
    """kr16 at q = 0 (model/kuka.py): a1 = 0.26, a2 = 0.68, a3 = -0.035, d4 = 0.67 [m]."""
    table = compute_table(load_robot("kr16"), "modified_dh")
    a = [abs(r.a) for r in table.rows]
    d = [abs(r.d) for r in table.rows]
    alpha = [abs(r.alpha) for r in table.rows]
    assert np.allclose(a, [0.0, 0.26, 0.68, 0.035, 0.0, 0.0], atol=1e-12)
    assert np.allclose(d, [0.0, 0.0, 0.0, 0.67, 0.0, 0.0], atol=1e-12)
    assert np.allclose(alpha, [0.0, np.pi / 2, 0.0, np.pi / 2, np.pi / 2, np.pi / 2], atol=1e-12)


@pytest.mark.parametrize("name", ["kr16", "ur5", "panda"])
def test_hayati_is_exact_on_calibrated_arms(name):
    robot = _calibrated(name, 1)
    table = compute_table(robot, "hayati")
    assert table.residual_m < TOL and table.residual_rad < TOL
    if name != "panda":                                   # A2 || A3 (KUKA), shoulder-elbow-wrist (UR)
        assert any(r.kind == "hayati" for r in table.rows)


def test_dh_on_nearly_parallel_axes_names_its_residual():
    """Calibrated ur5: axes 2, 3, 4 nearly parallel, d of the common normals runs to hundreds of m."""
    robot = _calibrated("ur5", 1)
    table = compute_table(robot, "classic_dh")
    assert max(abs(r.d) for r in table.rows) > 10.0
    dp, dr = table.compute_difference(robot, robot.random_configurations(50, 0))
    assert dp <= table.residual_m * 10 and table.residual_m > dp / 10    # the residual is what it says
    assert compute_table(robot, "hayati").residual_m < table.residual_m


def test_prismatic_joints_and_unknown_conventions_are_refused():
    with pytest.raises(ParameterTableError, match="valid: classic_dh"):
        compute_table(load_robot("kr16"), "dh")
