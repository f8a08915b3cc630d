"""Distinct arm positions: reflector positions in the world frame more than a tolerance apart."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main
from calib_oed.exceptions import DesignError
from calib_oed.oed.design import evaluate_design
from calib_oed.oed.positions import (
    POSITION_TOL,
    distinct_positions,
    position_multiplicities,
    reflector_positions,
)
from calib_oed.oed.result import write_design
from calib_oed.oed.starts import multiplicities
from tests.conftest import make_space


@pytest.fixture(scope="module")
def kr16(kr16_setup, kr16_poses):
    """The session's fms_kr16 set-up and its 12 feasible poses (seed 3; tests/conftest.py)."""
    return kr16_setup, kr16_poses


def test_a_turn_of_the_last_joint_about_the_reflector_is_the_same_position(kr16):
    """fms_kr16's reflector sits on the A6 axis: turning A6 gives a new joint vector, the same point."""
    s, q = kr16
    turned = q[:3].copy()
    turned[:, 5] += np.array([0.7, -1.1, 2.0])
    design = np.vstack([q, turned])
    assert len(multiplicities(design)) == 15
    assert distinct_positions(s.problem.space, design) == [2, 2, 2] + [1] * 9
    record = evaluate_design(s, design)
    assert record.distinct_positions == 12 and len(record.multiplicity) == 15
    assert "15 distinct poses (joint vectors)" in record.summary()
    assert "12 distinct arm positions (reflectors more than 1 mm apart)" in record.summary()
    data = record.to_dict()
    assert data["distinct_positions"] == 12 and data["position_tolerance_mm"] == 1.0
    assert data["position_multiplicity"] == [2, 2, 2] + [1] * 9


def test_the_tolerance_decides_what_is_one_position(kr16):
    """Moving the reflector by 2 mm is a new position at 1 mm, the same at 5 mm."""
    s, q = kr16
    pts = reflector_positions(s.problem.space, q)  # (n, 1, 3)
    moved = pts[:2] + np.array([0.0, 0.002, 0.0])
    both = np.concatenate([pts, moved])
    assert len(position_multiplicities(both, POSITION_TOL)) == 14
    assert len(position_multiplicities(both, 5e-3)) == 12
    record = evaluate_design(s, q, position_tol=0.5)  # half a metre: everything is one position
    assert record.distinct_positions < 12 and record.position_tolerance == 0.5
    with pytest.raises(DesignError, match="position_tol"):
        evaluate_design(s, q, position_tol=-1.0)


def test_positions_are_the_reflectors_in_the_world_frame(kr16):
    s, q = kr16
    import pinocchio as pin

    robot = s.problem.robot
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q[0])
    tool = data.oMf[robot.tool_frame_id]
    expected = tool.act(s.problem.space.reflector_offsets(None)[0])
    np.testing.assert_allclose(reflector_positions(s.problem.space, q[:1])[0, 0], expected, atol=1e-12)


def test_several_reflectors_count_one_position_only_when_all_coincide():
    space = make_space(__import__("calib_oed").load_robot("ur5"))
    q = space.robot.random_configurations(4, 0)
    pts = reflector_positions(space, q)  # (4, 2, 3)
    one_moved = pts.copy()
    one_moved[:, 1] += 0.01  # only the second reflector is elsewhere
    assert len(position_multiplicities(np.concatenate([pts, pts]))) == 4
    assert len(position_multiplicities(np.concatenate([pts, one_moved]))) == 8


def test_design_yaml_and_cli_report_distinct_positions(kr16, tmp_path, capsys):
    s, q = kr16
    write_design(tmp_path, evaluate_design(s, q), s.problem.robot)
    assert main(["evaluate", "fms_kr16", str(tmp_path / "design.yaml"), "--no-mesh-check", "--json",
                 "--position-tol", "2"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["distinct_positions"] == 12 and data["position_tolerance_mm"] == 2.0
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "fms_kr16", str(tmp_path / "design.yaml"), "--position-tol", "-1"])
    assert exc.value.code == EXIT_BAD_INPUT
    assert "--position-tol" in capsys.readouterr().err
