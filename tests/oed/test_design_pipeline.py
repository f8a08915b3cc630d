"""The default design pipeline: exchange start on a pool, SQP refinement, certificate; pools
given by the user, pure selection, replicates, the memory check, and the CLI flags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from calib_oed.calibration.workflow import setup
from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main
from calib_oed.exceptions import DesignError, DesignMemoryError
from calib_oed.io.design_file import write_design_csv
from calib_oed.oed import memory
from calib_oed.oed.certificate import SEARCH_COMPLETE
from calib_oed.oed.design import design, exchange_baseline
from calib_oed.oed.starts import multiplicities
from calib_oed.solver.sqp import SQPSettings

N = 12
FEW = SQPSettings(max_iterations=15)


@pytest.fixture(scope="module")
def default(kr16):
    """The default call (small pool and few iterations to keep the test short)."""
    return design(kr16, N, "kpi", pool=400, settings=FEW)


def test_default_is_exchange_refined_and_certified(kr16, default):
    ex = exchange_baseline(kr16, N, "kpi", pool=400, seed=0)
    assert default.method == "exchange+sqp" and default.feasible
    # the start: the exchange on the pool enriched by the approximate design's local maxima
    approx = default.solver["approximate"]
    assert approx["candidates"] == 400 + approx["local_maxima_added"] and approx["cpu_seconds"] > 0
    assert default.value <= default.start_value * (1 + 1e-9)
    cert = default.certificate
    # the bound holds for every n-pose design, this one included: efficiency = bound / value <= 1
    assert 0 < cert["lower_bound"] <= default.value
    assert default.efficiency == pytest.approx(cert["lower_bound"] / default.value, rel=1e-12)
    # the enriched pool, reused (plus the design's poses and further maxima)
    assert cert["pool_size"] >= approx["candidates"] + N
    assert ex.value >= cert["lower_bound"]  # the exchange design cannot beat it either
    # complete only when the last round found no better pose and its maximisation converged
    assert cert["search_complete"] == (cert["search_end"] == SEARCH_COMPLETE)
    assert cert["search_complete"] <= (cert["local_status"] == "converged")
    assert "efficiency:" in default.summary() and f"{N}-pose" in default.summary()
    data = default.to_dict()
    assert data["efficiency"] == default.efficiency and data["distinct_poses"] == N
    assert data["solver"]["pool"] == {"size": 400, "source": "random", "seed": 0, "rejected": 0}


def test_no_refine_is_pure_selection(kr16):
    ex = exchange_baseline(kr16, N, "kpi", pool=400, seed=0)
    sel = design(kr16, N, "kpi", pool=400, refine=False, certificate=False)
    assert sel.method == "exchange" and np.array_equal(sel.q, ex.q) and sel.value == ex.value


def test_given_pool_drops_infeasible_candidates(kr16):
    good = exchange_baseline(kr16, 30, "kpi", pool=200, seed=1).q
    bad = np.tile(kr16.problem.robot.upper, (3, 1))  # at the joint limits: violates the 1 deg margin
    assert not kr16.feasibility.compute(bad, jacobian=False).feasible.any()
    d = design(kr16, N, "kpi", pool=np.vstack([bad, good]), refine=False, certificate=False)
    assert d.solver["pool"] == {"size": 30, "source": "given", "seed": None, "rejected": 3}
    assert all(any(np.array_equal(row, g) for g in good) for row in d.q)  # selected from the pool
    with pytest.raises(DesignError, match="none is feasible"):
        design(kr16, N, "kpi", pool=bad, certificate=False)
    with pytest.raises(DesignError, match="at most 30 poses"):
        design(kr16, 31, "kpi", pool=good, refine=False, certificate=False)


def test_replicates_use_fewer_distinct_poses(kr16):
    """12 measurements from a pool of 9: only possible by measuring poses again."""
    pool = exchange_baseline(kr16, 9, "kpi", pool=200, seed=2).q
    d = design(kr16, N, "kpi", pool=pool, replicates=3, refine=False, certificate=False)
    counts = multiplicities(d.q)
    assert sum(counts) == N and len(counts) <= 9 and max(counts) <= 3
    assert d.to_dict()["multiplicity"] == counts and "distinct poses" in d.summary()
    # refinement moves copies together (the problem is symmetric under swapping them)
    r = design(kr16, N, "kpi", pool=pool, replicates=3, settings=SQPSettings(max_iterations=5),
               certificate=False)
    assert len(multiplicities(r.q)) <= 9 and r.value <= d.value * (1 + 1e-9)
    with pytest.raises(DesignError, match="replicates"):
        design(kr16, N, "kpi", replicates=0)


def test_multiplicities_group_equal_poses():
    q = np.random.default_rng(0).random((5, 6))
    assert multiplicities(np.vstack([q, q[[0, 0, 3]]])) == [3, 1, 1, 2, 1]
    assert multiplicities(np.vstack([q, q[:1] + 1e-3])) == [1] * 6


def test_memory_check_names_the_largest_n(kr16, monkeypatch):
    monkeypatch.setattr(memory, "_available_memory", lambda: 0.1 * 2**30)
    with pytest.raises(DesignMemoryError) as info:
        design(kr16, 4000, "kpi")
    err = info.value
    assert 0 < err.largest_n < 4000 and "GiB" in str(err) and str(err.largest_n) in str(err)
    rows = len(kr16.feasibility.labels)
    memory.check_memory(err.largest_n, 6, rows, dense=False)  # that one fits
    with pytest.raises(DesignMemoryError):
        memory.check_memory(err.largest_n + 1, 6, rows, dense=False)
    # a dense (BFGS) Hessian needs far more: the largest n that fits is smaller
    with pytest.raises(DesignMemoryError) as dense:
        design(kr16, 4000, "kpi", hessian="bfgs")
    assert dense.value.largest_n < err.largest_n


def test_memory_check_counts_the_coupled_criterion(kr16, monkeypatch):
    """kpi_model's exact Hessian holds dense (n nv)² arrays (every pose pair): the estimate covers the
    growth of peak RSS measured on fms_kr16 above the 60-pose process (docs/benchmarks.md, "The memory
    of a coupled criterion") and refuses a size whose kpi estimate fits."""
    rows = len(kr16.feasibility.labels)
    base = 217 * 2**20
    for n, peak_mib in ((250, 531), (500, 1497), (1000, 4862)):
        est = memory.estimate_memory(n, 6, rows, dense=False, coupled=True)
        assert peak_mib * 2**20 - base <= est <= 1.5 * (peak_mib * 2**20 - base)
        assert est > 10 * memory.estimate_memory(n, 6, rows, dense=False)  # kpi's structured Hessian
    monkeypatch.setattr(memory, "_available_memory", lambda: 8 * 2**30)
    memory.check_memory(2000, 6, rows, dense=False)  # the kpi design of 2000 poses fits
    with pytest.raises(DesignMemoryError) as info:
        design(kr16, 2000, "kpi_model")
    err = info.value
    assert 0 < err.largest_n < 2000 and str(err.largest_n) in str(err)
    memory.check_memory(err.largest_n, 6, rows, dense=False, coupled=True)
    with pytest.raises(DesignMemoryError):
        memory.check_memory(err.largest_n + 1, 6, rows, dense=False, coupled=True)


def test_cli_pool_file_replicates_and_no_certificate(tmp_path, kr16, capsys):
    pool = exchange_baseline(kr16, 10, "kpi", pool=200, seed=2).q
    write_design_csv(tmp_path / "pool.csv", kr16.problem.robot, pool)
    out = tmp_path / "d"
    assert main(["design", "fms_kr16", "-n", "14", "--pool", str(tmp_path / "pool.csv"),
                 "--replicates", "2", "--no-refine", "--no-certificate", "-o", str(out),
                 "--quiet"]) == EXIT_OK
    data = yaml.safe_load((out / "design.yaml").read_text())
    assert data["method"] == "exchange" and data["distinct_poses"] <= 10
    assert sum(data["multiplicity"]) == 14 and data["certificate"]["skipped"].startswith("not asked")
    capsys.readouterr()
    assert main(["design", "fms_kr16", "--pool", str(tmp_path / "missing.csv")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "--pool" in err and len(err.strip().splitlines()) == 1


def _crowded_ur5_cell():
    """ur5_table with 120 small obstacles on a shell around the arm: thousands of rows per design."""
    import yaml as _yaml

    from calib_oed.scene.reader import scene_from_dict

    path = Path(__file__).parents[2] / "calib_oed" / "scene" / "shipped" / "ur5_table.yaml"
    data = _yaml.safe_load(path.read_text())
    rng = np.random.default_rng(3)
    capsules = []
    for k in range(120):
        az, el = rng.uniform(-np.pi, np.pi), rng.uniform(0.05, 1.2)
        c = 1050.0 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        if c[0] > 600 and abs(c[1] + 300) < 700:  # keep the line of sight to the tracker clear
            continue
        capsules.append({"name": f"post{k}", "a": c.tolist(), "b": (c + [0, 0, 60]).tolist(),
                         "radius": 20})
    data["cell"]["capsules"] = capsules
    return setup(scene_from_dict(data, source=str(path)))


def test_a_crowded_cell_with_failing_qps_ends_with_a_status(monkeypatch):
    """The cell kind that used to abort the process (many obstacle rows, a QP failure that
    widened the trust region to 1 rad): the QP rows stay bounded, and a QP solver that
    fails ends the design with a status and a feasible record, never an exception."""
    from calib_oed.solver.lifted import LiftedQPWorkspace
    from calib_oed.solver.qp import DenseQPWorkspace, SparseQPWorkspace

    s = _crowded_ur5_cell()
    n = 12
    rows = []
    d = design(s, n, "kpi", pool=300, certificate=False, callback=rows.append, enrich=False,
               settings=SQPSettings(max_iterations=12, step_bound=1.0))
    assert len(s.feasibility.labels) * n > 1000 and d.feasible
    assert rows and max(r.n_rows_kept for r in rows) <= max(200, 4 * n * 6)
    assert max(r.n_rows_dropped for r in rows) > 1000  # the bound is what kept the QP small

    def fail(*args, **kwargs):
        raise MemoryError()

    for workspace in (DenseQPWorkspace, SparseQPWorkspace, LiftedQPWorkspace):
        monkeypatch.setattr(workspace, "solve", fail)
    broken = design(s, n, "kpi", pool=300, certificate=False, enrich=False,
                    settings=SQPSettings(max_iterations=12))
    assert broken.solver["status"] == "qp_failed" and "MemoryError" in broken.solver["message"]
    assert broken.feasible and broken.value <= broken.start_value * (1 + 1e-12)


def test_ctrl_c_keeps_the_best_feasible_design_so_far(kr16):
    """Ctrl-C in the SQP (a KeyboardInterrupt, here from the progress callback) returns the
    design so far, feasible, marked interrupted, without the certificate."""
    def callback(record):
        if record.iteration == 2:
            raise KeyboardInterrupt

    d = design(kr16, N, "kpi", pool=400, settings=FEW, callback=callback, enrich=False)
    assert d.interrupted and d.solver["status"] == "interrupted"
    assert d.feasible and d.value <= d.start_value * (1 + 1e-9)
    assert d.solver["iterations"] == 3
    assert d.efficiency is None and "interrupted" in d.certificate["skipped"]
    assert not design(kr16, N, "kpi", pool=400, refine=False, certificate=False).interrupted


def test_ctrl_c_in_the_certificate_keeps_the_design(kr16, monkeypatch):
    """A KeyboardInterrupt inside the certificate's local SQP (which the SQP turns into its
    status ``interrupted``) ends the certificate, not just that search: the refined design
    is kept, marked interrupted, without an efficiency."""
    from calib_oed.oed import sensitivity_maxima

    real, calls, refined = sensitivity_maxima.sensitivity_field, [], []

    def interrupted_field(*args, **kwargs):
        if refined:  # after the design's SQP (the start's column generation also calls it)
            calls.append(1)
            if len(calls) == 3:
                raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(sensitivity_maxima, "sensitivity_field", interrupted_field)
    d = design(kr16, N, "kpi", pool=400, settings=FEW, callback=refined.append)
    assert refined and len(calls) == 3  # the certificate stopped at the interrupt
    assert d.interrupted and d.feasible and d.efficiency is None
    assert d.solver["status"] != "interrupted"  # the design's own SQP ran to its end
    assert "certificate" in d.certificate["skipped"]
