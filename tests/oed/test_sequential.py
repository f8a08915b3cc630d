"""Sequential (online) design: stopping at the target, feasible batches, monotone σ, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib_oed.calibration.workflow import heuristic_design, simulated_measurements
from calib_oed.exceptions import SequentialError
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed.sequential import NEIGHBOURHOOD_RAD, SequentialDesigner
from calib_oed.oed.sequential_run import measurements_needed, run_sequential
from calib_oed.solver.sqp import SQPSettings

#: The heuristic 60-pose design of fms_kr16 (seed 0) predicts 0.0062 mm under the shipped
#: tracker error model and repeatability (0.0036 mm with the old isotropic 0.01 mm); 0.007 is reachable.
TARGET = 0.007
FAST = SQPSettings(max_iterations=10)


@pytest.fixture(scope="module")
def run(kr16):
    return run_sequential(kr16, TARGET, batch=5, initial=15, truth_seed=0, max_measurements=60,
                          settings=FAST, compare=True, grid=range(10, 65, 5),
                          compare_settings=SQPSettings(max_iterations=5))


def test_run_stops_at_the_target(run):
    sig = [s.sigma_mm.max() for s in run.steps]
    assert run.reached
    assert sig[-1] <= TARGET < sig[-2]
    assert all(x > TARGET for x in sig[:-1])
    assert len(run.steps) >= 2
    assert run.n_measurements == len(run.q) == 15 + 5 * (len(run.steps) - 1)
    assert run.check() == []


def test_sigma_never_increases(run):
    sig = np.array([s.sigma_mm.max() for s in run.steps])
    assert np.all(np.diff(sig) <= 0)


def test_batches_feasible(run, kr16):
    start = 0
    for step in run.steps:
        q = run.q[start:start + step.n_added]
        assert kr16.feasibility.compute(q, jacobian=False).feasible.all()
        assert step.feasible
        start += step.n_added
    assert start == len(run.q)


def test_truth_is_the_workflow_truth_and_estimate_improves(run, kr16):
    _, p_true = simulated_measurements(kr16, run.q[:15], run.truth_seed)
    np.testing.assert_array_equal(run.p_true, p_true)
    # actual error of the final estimate is of the order the prediction says (3-D norm ~ sqrt(3) sigma)
    assert run.steps[-1].tcp_error_mm.max() < 5 * np.sqrt(3) * TARGET
    assert run.steps[-1].tcp_error_mm.max() < run.steps[0].tcp_error_mm.max()


def test_comparison_consistent(run, kr16):
    by = {c.method: c for c in run.comparison}
    heur = by["heuristic"]
    assert heur.n is not None and heur.sigma_mm[heur.n] <= TARGET
    assert all(v > TARGET for n, v in heur.sigma_mm.items() if n < heur.n)
    # measured: sequential 25, heuristic 50 poses for 0.007 mm (tracker model + repeatability)
    assert run.n_measurements < heur.n
    opt = by["fixed KPI-optimal"]
    if opt.n is not None:
        assert opt.sigma_mm[opt.n] <= TARGET
    d = json.loads(json.dumps(run.to_dict()))
    assert d["measurements_needed"]["sequential"] == run.n_measurements
    assert d["measurements_needed"]["heuristic"] == heur.n
    text = run.summary()
    assert "sequential" in text and "heuristic" in text and "CHECK FAILED" not in text
    # the fixed 60-pose references at the final estimate: the heuristic one is the seed-0 design
    assert run.reference_n == 60 and d["reference"]["n"] == 60
    heur60 = float(kr16.problem.kpi_sigma(heuristic_design(kr16, 60, 0), run.p_estimate).max() * 1e3)
    assert run.reference["heuristic"] == pytest.approx(heur60, rel=1e-9)
    assert run.reference["fixed KPI-optimal"] < run.reference["heuristic"]
    assert "fixed 60-pose designs at the final estimate" in text


def test_propose_beats_random_batch(kr16):
    des = SequentialDesigner(kr16, TARGET, batch=5, settings=FAST, seed=3)
    q_meas = heuristic_design(kr16, 15, 0)
    rng = np.random.default_rng(7)
    p = np.zeros(kr16.problem.space.size)
    p[kr16.problem.identifiability.free_indices] = rng.normal(size=25) * 3e-4
    obj = des.objective(q_meas, p)
    prop = des.plan(q_meas, p)
    assert prop.q.shape == (5, kr16.problem.robot.nq)
    assert kr16.feasibility.compute(prop.q, jacobian=False).feasible.all()
    assert prop.value == pytest.approx(obj.compute_value(prop.q), rel=1e-12)
    assert prop.value <= prop.start_value
    for seed in (11, 12, 13):
        random_batch = sample_feasible(kr16.feasibility, 5, seed)
        assert prop.value < obj.compute_value(random_batch)
    # the criterion is the mean predicted variance: adding the batch lowers sigma
    before = des.predicted_sigma_mm(q_meas, p)
    after = des.predicted_sigma_mm(np.vstack([q_meas, prop.q]), p)
    assert after.max() < before.max()
    assert np.mean(after ** 2) == pytest.approx(prop.value, rel=1e-6)


def test_propose_near_current_pose(kr16):
    des = SequentialDesigner(kr16, TARGET, batch=3, settings=FAST)
    q_meas = heuristic_design(kr16, 15, 0)
    pose = q_meas[-1]
    near = des.near_candidates(pose, 50, np.random.default_rng(0))
    assert len(near) > 0
    assert np.all(np.abs(near - pose) <= NEIGHBOURHOOD_RAD + 1e-12)
    assert kr16.feasibility.compute(near, jacobian=False).feasible.all()
    q = des.propose(q_meas, None, current_pose=pose)
    assert q.shape == (3, kr16.problem.robot.nq)
    assert kr16.feasibility.compute(q, jacobian=False).feasible.all()
    assert des.done(q_meas) is False  # 15 heuristic poses: 0.0161 mm > 0.007 mm


@pytest.mark.parametrize("kwargs", [
    {"target_sigma_mm": 0.0}, {"target_sigma_mm": -1.0}, {"target_sigma_mm": float("nan")},
    {"batch": 0}, {"batch": 2.5}, {"batch": 301}, {"criterion": "nope"},
])
def test_bad_designer_inputs(kr16, kwargs):
    args = {"target_sigma_mm": TARGET, **kwargs}
    target = args.pop("target_sigma_mm")
    with pytest.raises(SequentialError):
        SequentialDesigner(kr16, target, **args)


def test_bad_run_and_proposal_inputs(kr16):
    with pytest.raises(SequentialError, match="initial"):
        run_sequential(kr16, TARGET, initial=4, compare=False)
    with pytest.raises(SequentialError, match="max_measurements"):
        run_sequential(kr16, TARGET, initial=15, max_measurements=10, compare=False)
    with pytest.raises(SequentialError, match="batch"):
        run_sequential(kr16, TARGET, batch=0, compare=False)
    des = SequentialDesigner(kr16, TARGET, batch=2)
    with pytest.raises(SequentialError, match="free parameters"):
        des.propose(np.zeros((0, 6)))  # no prior: 2 poses cannot determine 25 parameters
    with pytest.raises(SequentialError, match="k"):
        des.propose(heuristic_design(kr16, 15, 0), k=0)
    with pytest.raises(SequentialError, match="method"):
        measurements_needed(kr16, TARGET, "random")
    with pytest.raises(SequentialError, match="grid"):
        measurements_needed(kr16, TARGET, "heuristic", grid=[])


def test_measurements_needed_heuristic_is_nested(kr16):
    """The heuristic designs of the grid are the first n poses of one draw: the search stops at
    the first n whose design reaches the target (a target between the 15- and 20-pose sigmas)."""
    q = heuristic_design(kr16, 25, 0)
    s15, s20 = (kr16.problem.kpi_sigma(q[:n]).max() for n in (15, 20))
    assert s20 < s15
    res = measurements_needed(kr16, np.sqrt(s15 * s20) * 1e3, "heuristic", grid=[10, 15, 20, 25])  # [mm]
    assert res.n == 20
    assert res.sigma_mm[15] == pytest.approx(s15 * 1e3)
    assert res.sigma_mm[20] == pytest.approx(s20 * 1e3)
    assert set(res.sigma_mm) == {10, 15, 20}
    never = measurements_needed(kr16, 1e-6, "heuristic", grid=[10, 15])
    assert never.n is None and set(never.sigma_mm) == {10, 15}


# ------------------------------------------------------------------ the CLI
def test_cli_sequential_stops_at_the_target_and_writes_its_files(capsys, tmp_path, kr16):
    from calib_oed.cli import EXIT_OK, main
    from calib_oed.io.design_file import read_design_csv

    argv = ["sequential", "fms_kr16", "--target-sigma", "5um", "--initial", "9", "--batch", "2",
            "--no-compare", "--iterations", "10", "-o", str(tmp_path), "--json"]
    assert main(argv) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    sig = [s["sigma_max_mm"] for s in data["steps"]]
    assert data["target_sigma_mm"] == pytest.approx(0.005)
    assert data["reached"] and sig[-1] <= 0.005 < min(sig[:-1])
    assert data["check"] == []
    assert data["n_measurements"] == 9 + 2 * (len(sig) - 1)
    q = read_design_csv(tmp_path / "measured.csv", kr16.problem.robot)
    np.testing.assert_allclose(q, np.array(data["q_rad"]), rtol=0, atol=1e-15)
    assert json.loads((tmp_path / "sequential.json").read_text())["n_measurements"] == len(q)


def test_cli_sequential_reports_the_fixed_designs(capsys):
    from calib_oed.cli import EXIT_OK, main

    assert main(["sequential", "fms_kr16", "--target-sigma", "0.02mm", "--iterations", "3",
                 "--quiet"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "measurements to reach sigma <= 0.02 mm" in out
    lines = {ln.split()[0]: ln.split()[-1] for ln in out.splitlines() if ln.startswith("  ")}
    # the initial heuristic design (15 poses) and then batches of 5, until the target or 3 iterations
    assert lines["sequential"].isdigit() and lines["fixed"].isdigit() and lines["heuristic"].isdigit()
    assert int(lines["sequential"]) in (15, 20, 25, 30)


def test_cli_sequential_bad_reference_is_one_clear_line(capsys):
    from calib_oed.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["sequential", "fms_kr16", "--target-sigma", "0.02mm", "--reference", "-5"])
    assert exc.value.code == 2 and "--reference" in capsys.readouterr().err


@pytest.mark.parametrize("target", ["0.02 furlong", "-1mm", "abc", "0"])
def test_cli_sequential_bad_target_is_one_clear_line(capsys, target):
    from calib_oed.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["sequential", "fms_kr16", "--target-sigma", target])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--target-sigma" in err and "Traceback" not in err


def test_optimal_initial_design_starts_lower(kr16):
    kw = dict(batch=3, initial=9, truth_seed=1, max_measurements=9, settings=FAST, compare=False,
              compare_settings=SQPSettings(max_iterations=10))
    heur = run_sequential(kr16, 1e-6, **kw)
    opt = run_sequential(kr16, 1e-6, initial_design="optimal", **kw)
    assert opt.initial_design == "optimal" and opt.to_dict()["initial_design"] == "optimal"
    assert len(opt.q) == len(heur.q) == 9
    assert opt.steps[0].sigma_mm.max() < 0.5 * heur.steps[0].sigma_mm.max()
    with pytest.raises(SequentialError, match="initial_design.*heuristic, optimal"):
        run_sequential(kr16, 0.01, initial_design="best", **kw)


def test_cli_sequential_step_on_measured_data(capsys, tmp_path, kr16):
    """--measured: identify from a real (here simulated) file, then propose the next batch or stop."""
    from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main
    from calib_oed.io.design_file import read_design_csv

    meas = tmp_path / "m.csv"
    assert main(["simulate", "fms_kr16", "-n", "12", "--seed", "0", "--truth-seed", "2", "-o", str(meas),
                 "--quiet"]) == EXIT_OK
    out = tmp_path / "step"
    assert main(["sequential", "fms_kr16", "--target-sigma", "0.005mm", "--measured", str(meas),
                 "--batch", "4", "--iterations", "10", "-o", str(out), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["configurations"] == 12 and not data["done"]
    assert max(data["sigma_mm"]) > 0.005
    q_next = read_design_csv(out / "next.csv", kr16.problem.robot)
    np.testing.assert_allclose(q_next, np.array(data["next_q_rad"]), rtol=0, atol=1e-15)
    assert q_next.shape == (4, 6)
    assert kr16.feasibility.compute(q_next, jacobian=False).feasible.all()
    assert max(data["sigma_after_mm"]) < max(data["sigma_mm"])
    assert json.loads((out / "sequential_step.json").read_text())["done"] is False
    # a target already met: stop, no next batch
    assert main(["sequential", "fms_kr16", "--target-sigma", "1mm", "--measured", str(meas),
                 "-o", str(tmp_path / "done")]) == EXIT_OK
    assert "reached: stop measuring" in capsys.readouterr().out
    assert not (tmp_path / "done" / "next.csv").exists()
    # data that do not fit the scene (y and z swapped) stop before the fit, as identify does
    swapped = tmp_path / "swapped.csv"
    swapped.write_text(meas.read_text().replace(",reflector,x,y,z", ",reflector,x,z,y"))
    assert main(["sequential", "fms_kr16", "--target-sigma", "1mm", "--measured", str(swapped),
                 "-o", str(tmp_path / "swapped_step")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "swapped or mirrored position columns" in err
    assert not (tmp_path / "swapped_step").exists()
    assert main(["sequential", "fms_kr16", "--target-sigma", "1mm", "--max-registration-rms", "5"]) == EXIT_BAD_INPUT
    assert "--max-registration-rms acts only with --measured" in capsys.readouterr().err
