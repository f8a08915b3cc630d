"""The gauge rule and KPI estimability: known answers and the classical count."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_space
from hypothesis import given, settings
from hypothesis import strategies as st

from calib_oed import load_robot
from calib_oed.calibration.kpi import TcpKpi
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.measurement import PoseMeasurement, TrackerPosition
from calib_oed.model.identifiability import check_estimability, select_gauge


def test_greedy_selection_on_a_known_matrix():
    """Columns: a, b, a+2b, 0, c  ->  free a, b, c; 'ab' redundant with a and b; 'z' no effect."""
    rng = np.random.default_rng(0)
    a, b, c = rng.normal(size=(3, 20))
    mat = np.column_stack([a, b, a + 2 * b, np.zeros(20), c])
    rep = select_gauge(mat, ["a", "b", "ab", "z", "c"])
    assert rep.free_names == ("a", "b", "c") and rep.rank == 3
    fixed = {f.name: f for f in rep.fixed}
    assert dict(fixed["ab"].redundant_with) == pytest.approx({"a": 1.0, "b": 2.0})
    assert fixed["z"].redundant_with == () and "no effect" in fixed["z"].reason
    # Gauge directions span the null space.
    assert np.allclose(mat @ rep.null_space, 0.0, atol=1e-12)
    # The sensor-first order matters: reversing the columns frees the later ones.
    rev = select_gauge(mat[:, ::-1], ["c", "z", "ab", "b", "a"])
    assert rev.free_names == ("c", "ab", "b")


def _rank(robot_name, reflectors, model_cls=TrackerPosition):
    robot = load_robot(robot_name)
    space = make_space(robot, reflectors)
    models = [model_cls(j) for j in range(len(reflectors))]
    kpi = TcpKpi(robot.random_configurations(1, 1))
    return CalibrationProblem(space, models, kpi).identifiability


@pytest.mark.parametrize("robot_name, n_revolute", [("kr16", 6), ("ur5", 6), ("panda", 7)])
def test_classical_count_for_one_point_off_the_last_axis(robot_name, n_revolute):
    """Position of one general point, unknown base and tool: 4R + 2P + 6 - 3."""
    report = _rank(robot_name, [(0.03, 0.01, 0.05)])
    assert report.rank == 4 * n_revolute + 3
    assert report.condition_number < 1e4
    # The tracker absorbs the base: all of joint 1 is fixed, the sensor is free.
    assert all(f"joint1.{c}" in report.fixed_names for c in ("tx", "ty", "tz", "rx", "ry", "rz"))
    assert all(f"tracker.{c}" in report.free_names for c in ("tx", "ty", "tz", "rx", "ry", "rz"))


def test_reflector_on_the_last_axis_loses_two():
    """kr16's A6 axis is tool z: a reflector on it traces no circle about A6."""
    assert _rank("kr16", [(0.0, 0.0, 0.05)]).rank == 4 * 6 + 3 - 2


def test_pose_measurement_and_three_reflectors():
    assert _rank("kr16", [(0.03, 0.01, 0.05)], PoseMeasurement).rank == 4 * 6 + 6 - 2
    three = [(0.05, 0.0, 0.05), (0.0, 0.05, 0.05), (-0.05, -0.05, 0.02)]
    assert _rank("kr16", three).rank == 4 * 6 + 6 + 3


def test_estimability():
    robot = load_robot("kr16")
    space = make_space(robot, [(0.03, 0.01, 0.05)])
    q_work = robot.random_configurations(1, 4)
    problem = CalibrationProblem(space, [TrackerPosition(0)], TcpKpi(q_work))
    rep = problem.identifiability
    a = problem.weighted_jacobian(problem.generic_configurations()) * space.unit_scale
    # A predicted measurement is estimable by construction.
    row = problem.weighted_jacobian(q_work)[:3] * space.unit_scale
    est = check_estimability(a, row, rep, "measurement")
    assert est.estimable and est.residual < 1e-9 and est.gauge == ()
    # A fixed parameter alone is not, and its gauge names it.
    e = np.zeros((1, space.size))
    e[0, space.index("joint1.tz")] = 1.0
    est = check_estimability(a, e, rep, "joint1.tz")
    assert not est.estimable and "joint1.tz" in est.gauge
    # The world-frame TCP depends on the base gauge (tracker pose unknown).
    (tcp,) = problem.kpi_estimability()
    assert not tcp.estimable and {"joint1.tx", "joint1.rz"} <= set(tcp.gauge)
    # A fixed tool point in the tracker frame still depends on the tool gauge ...
    problem.kpi = TcpKpi(q_work, point=np.array([0.0, 0.0, 0.1]), frame="tracker")
    (tool_point,) = problem.kpi_estimability()
    assert not tool_point.estimable and tool_point.gauge
    assert not any(name.startswith("joint1.") for name in tool_point.gauge)
    # ... while the reflector centre in the tracker frame is a predicted measurement.
    problem.kpi = TcpKpi(q_work, frame="tracker", reflector=0)
    (refl,) = problem.kpi_estimability()
    assert refl.estimable and refl.residual < 1e-9


@settings(max_examples=40, deadline=None)
@given(
    n_independent=st.integers(1, 8),
    n_dependent=st.integers(0, 6),
    seed=st.integers(0, 2**32 - 1),
)
def test_gauge_rank_and_null_space_on_planted_dependencies(n_independent, n_dependent, seed):
    """Random columns plus random combinations of them: rank and gauge are recovered."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(30, n_independent))
    mix = rng.normal(size=(n_independent, n_dependent))
    mat = np.hstack([base, base @ mix])[:, rng.permutation(n_independent + n_dependent)]
    names = [f"c{k}" for k in range(mat.shape[1])]
    rep = select_gauge(mat, names)
    assert rep.rank == n_independent
    assert rep.null_space.shape == (mat.shape[1], n_dependent)
    assert np.allclose(mat @ rep.null_space, 0.0, atol=1e-9 * np.abs(mat).max())
    # The free columns are independent and, in order, the first ones that are.
    assert np.linalg.matrix_rank(mat[:, rep.free]) == n_independent


def test_report_explains_the_on_axis_reflector():
    from calib_oed.calibration.report import reflectors_on_last_axis

    robot = load_robot("kr16")
    kpi = TcpKpi(robot.random_configurations(1, 1))
    on = CalibrationProblem(make_space(robot, [(0.0, 0.0, 0.05), (0.03, 0.0, 0.05)]),
                            [TrackerPosition(0)], kpi)
    assert reflectors_on_last_axis(on) == [0]
