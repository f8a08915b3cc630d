"""Tests of the study runner, its configuration and its report (calib_oed.study)."""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import calib_oed.study.runner as study_module
from calib_oed.calibration.workflow import setup
from calib_oed.exceptions import (
    OptionalDependencyError,
    StudyConfigError,
    StudyLockError,
    StudyResumeError,
)
from calib_oed.model.kuka import notional_grid
from calib_oed.scene.reader import load_scene
from calib_oed.study.case import colliding_poses
from calib_oed.study.loader import load_study_config, study_config_from_dict, study_names
from calib_oed.study.report import study_tables, write_report
from calib_oed.study.results import CaseFailure, DesignRow, improvement_pct
from calib_oed.study.runner import read_study, run_study

# CI's study: the shipped 2-arm smoke configuration (20 poses, 3 heuristic
# seeds, 10 SQP iterations; about 1 s a case), as a dict to vary.
SMOKE = load_study_config("smoke").to_dict()
ITERATIONS = SMOKE["sqp"]["max_iterations"]
# Columns that depend on the machine, not on the results.
TIMING = {"seconds"}


def smoke(**changes) -> dict:
    data = copy.deepcopy(SMOKE)
    data.update(changes)
    return data


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def without_timing(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


@pytest.fixture(scope="module")
def smoke_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("smoke")
    return run_study(study_config_from_dict(smoke()), out, n_jobs=1, progress=False)


# ---------------------------------------------------------------- configuration

@pytest.mark.parametrize(("change", "key", "text"), [
    ({"colour": 1}, "colour", "valid keys of the top level are: version, name, cases"),
    ({"version": 2}, "version", "supported: 1"),
    ({"criteria": ["kpi", "G"]}, "criteria[1]", "valid criteria are: kpi, params, D, E"),
    ({"criteria": []}, "criteria", "non-empty list"),
    ({"collisions": ["yes"]}, "collisions[0]", "true (with collision constraints) or false"),
    ({"collisions": [True, True]}, "collisions", "repeated"),
    ({"start": "random"}, "start", "expected one of heuristic, exchange"),
    ({"enrich": "yes"}, "enrich", "expected true or false"),
    ({"n": 0}, "n", "integer >= 1"),
    ({"heuristic_seeds": [0, -1]}, "heuristic_seeds[1]", "integer >= 0"),
    ({"sqp": {"iterations": 5}}, "sqp.iterations", "valid keys of 'sqp' are: max_iterations, "
                                                   "time_limit"),
    ({"sqp": {"time_limit": 0}}, "sqp.time_limit", "seconds > 0 or null"),
    ({"certificate": {"pool": 0}}, "certificate.pool", "integer >= 1"),
    ({"certificate": {"size": 3}}, "certificate.size", "valid keys of 'certificate' are: pool, seed"),
    ({"cases": {}}, "cases", "'robots'"),
    ({"cases": {"notional": "all"}}, "cases.notional", "expected 'grid'"),
    ({"cases": {"notional": {"lambdas": [650.5], "mus": [600]}}}, "cases.notional.lambdas[0]",
     "whole number of millimetres"),
    ({"cases": {"notional": "grid", "scene_template": "nowhere"}}, "cases.scene_template",
     "shipped scenes are: fms_kr16"),
    ({"cases": {"robots": [{"robot": "kr300", "scene": "fms_kr16"}]}}, "cases.robots[0].robot",
     "has robot 'kr16', not 'kr300'; use scene_template"),
    ({"cases": {"robots": [{"robot": "kr16", "scene": "fms_kr16", "scene_template": "fms_kr16"}]}},
     "cases.robots[0]", "exactly one of 'scene'"),
    ({"cases": {"robots": [{"robot": "ur5", "scene_template": "fms_kr16"}]}},
     "cases.robots[0].robot", "notional_l<lambda_mm>_m<mu_mm>"),
    ({"cases": {"robots": [{"robot": "kr16", "scene": "fms_kr16"}] * 2}}, "cases",
     "the same case appears twice: kr16-fms_kr16"),
])
def test_config_errors_name_the_key_and_the_choices(change, key, text):
    with pytest.raises(StudyConfigError) as info:
        study_config_from_dict(smoke(**change), source="study.yaml")
    assert info.value.key == key
    assert text in str(info.value)
    assert str(info.value).startswith(f"study.yaml: {key}: ")


def test_config_defaults_and_round_trip():
    data = {"version": 1, "name": "d", "cases": {"robots": [{"robot": "kr16",
                                                            "scene": "fms_kr16"}]}}
    config = study_config_from_dict(data)
    plan = config.plan
    assert (plan.n, plan.criteria, plan.collisions, plan.start, plan.seed) == (
        60, ("params", "kpi"), (True, False), "heuristic", 0)
    assert plan.heuristic_seeds == tuple(range(10))
    again = study_config_from_dict(config.to_dict())
    assert again.cases()[0].config_hash == config.cases()[0].config_hash
    assert again.to_dict() == config.to_dict()


def test_enrich_round_trips_and_changes_the_hash():
    off = study_config_from_dict(smoke(enrich=False))
    assert off.plan.enrich is False and study_config_from_dict(smoke()).plan.enrich is True
    assert study_config_from_dict(off.to_dict()).plan.enrich is False
    assert off.cases()[0].config_hash != study_config_from_dict(smoke()).cases()[0].config_hash


def test_hash_changes_with_the_plan_not_with_the_name():
    a = study_config_from_dict(smoke()).cases()[0].config_hash
    assert study_config_from_dict(smoke(name="other", description="x")).cases()[0].config_hash == a
    assert study_config_from_dict(smoke(n=21)).cases()[0].config_hash != a
    assert study_config_from_dict(smoke(sqp={"max_iterations": 9})).cases()[0].config_hash != a


def test_unknown_study_lists_the_shipped_ones():
    with pytest.raises(StudyConfigError, match="shipped studies are: kuka, notional90, smoke"):
        load_study_config("nonesuch")


def test_shipped_studies():
    assert {"kuka", "notional90", "smoke"} <= set(study_names())
    kuka = load_study_config("kuka")
    # the studies run on copies of the cells with the paper's isotropic noise
    assert [(s.robot, Path(s.scene).name) for s in kuka.specs] == [
        ("kr16", "fms_kr16_paper.yaml"), ("kr300", "fms_kr300_paper.yaml"),
        ("kr500", "fms_kr500_paper.yaml")]
    for s in kuka.specs:
        scene = load_scene(s.scene)
        assert scene.tracker.noise is None and scene.repeatability == 0
    grid = load_study_config("notional90")
    assert [s.robot for s in grid.specs] == [d.name for d in notional_grid()]
    assert all(Path(s.template).name == "fms_kr16_paper.yaml" and s.lambda_mm and s.mu_mm
               for s in grid.specs)
    for config in (kuka, grid):
        plan = config.plan
        assert (plan.n, plan.criteria, plan.collisions) == (60, ("params", "kpi"), (True, False))
    smoke = load_study_config("smoke")
    assert len(smoke.specs) == 2 and smoke.plan.max_iterations <= 20
    # same seed, same results under any load: the iteration limit bounds every design, no clock
    assert [c.plan.time_limit for c in (kuka, grid, smoke)] == [None, None, None]


# ---------------------------------------------------------------- the smoke study

def test_results_table(smoke_study):
    rows = read_csv(smoke_study.out_dir / "results.csv")
    assert list(rows[0]) == DesignRow.columns()
    assert len(rows) == 2 * (3 + 1 + 2 * 2)  # heuristics, their median, criteria x collisions
    for case in smoke_study.cases:
        mine = [r for r in rows if r["case_id"] == case.case_id]
        heur = [float(r["kpi_avg_variance_mm2"]) for r in mine if r["kind"] == "heuristic"]
        (median,) = [r for r in mine if r["kind"] == "heuristic_median"]
        assert float(median["kpi_avg_variance_mm2"]) == pytest.approx(np.median(heur), rel=1e-9)
        assert {r["seed"] for r in mine if r["kind"] == "heuristic"} == {"0", "1", "2"}
        optimal = {(r["criterion"], r["collisions"]): r for r in mine if r["kind"] == "optimal"}
        assert set(optimal) == {(c, f) for c in ("params", "kpi") for f in ("True", "False")}
        for r in optimal.values():
            # the SQP lowers its own criterion from the shared start (heuristic seed 0)
            assert float(r["criterion_value"]) <= float(r["criterion_start_value"])
            assert r["lambda_mm"] in ("650", "1100") and r["iterations"] == str(ITERATIONS)
            assert r["seed"] == "0"
        (seed0,) = [r for r in mine if r["kind"] == "heuristic" and r["seed"] == "0"]
        for flag in ("True", "False"):
            assert optimal[("kpi", flag)]["criterion_start_value"] == seed0["kpi_avg_variance_mm2"]
            assert optimal[("params", flag)]["criterion_start_value"] == seed0[
                "params_avg_variance"]
        for flag in ("True", "False"):
            kpi = float(optimal[("kpi", flag)]["kpi_avg_variance_mm2"])
            assert kpi <= float(median["kpi_avg_variance_mm2"])
            assert kpi <= float(optimal[("params", flag)]["kpi_avg_variance_mm2"])
        # with collision constraints: feasible, nothing collides; heuristics never collide
        for r in mine:
            if r["kind"] != "optimal" or r["collisions"] == "True":
                assert r["feasible"] == "True" and float(r["colliding_fraction"]) == 0.0


def test_colliding_fraction_of_stored_designs(smoke_study):
    """The stored no-collision designs collide where the table says, and are flagged infeasible."""
    fractions = []
    for case in smoke_study.cases:
        fm = setup(case.case.spec.load_scene()).feasibility
        for crit in ("params", "kpi"):
            stored = case.designs[f"{crit}-no_collisions"]
            assert stored.q.shape == (20, 6)
            row = case.row("optimal", crit, False)
            assert colliding_poses(fm, stored.q).mean() == pytest.approx(row.colliding_fraction)
            assert not (row.feasible and row.colliding_fraction > 0)
            assert stored.solver["iterations"] == ITERATIONS and "history" in stored.solver
            fractions.append(row.colliding_fraction)
            # with collision constraints: the stored design collides nowhere
            assert not colliding_poses(fm, case.designs[f"{crit}-collisions"].q).any()
    assert max(fractions) > 0.2  # without the constraints, designs do collide


def test_summary_matches_the_table(smoke_study):
    summary = json.loads((smoke_study.out_dir / "summary.json").read_text())
    rows = read_csv(smoke_study.out_dir / "results.csv")
    assert summary["n_cases"] == summary["n_done"] == 2 and summary["failures"] == []
    assert summary["machine"]["cpu_count"] >= 1 and summary["wall_seconds"] > 0
    assert "100 * (1 - V_kpi_optimal / V_other)" in summary["improvement_convention"]

    def value(case_id, kind, crit="", flag="True"):
        (r,) = [r for r in rows if (r["case_id"], r["kind"], r["criterion"], r["collisions"])
                == (case_id, kind, crit, flag)]
        return float(r["kpi_avg_variance_mm2"])

    for case in summary["cases"]:
        cid = case["case_id"]
        median = value(cid, "heuristic_median")
        assert case["heuristic_median_mm2"] == pytest.approx(median, rel=1e-9)
        for key, flag in (("collisions", "True"), ("no_collisions", "False")):
            block = case[key]
            kpi, params = value(cid, "optimal", "kpi", flag), value(cid, "optimal", "params", flag)
            assert block["optimal_mm2"] == pytest.approx({"kpi": kpi, "params": params}, rel=1e-9)
            assert block["improvement_pct"]["vs_heuristic"] == pytest.approx(
                100 * (1 - kpi / median), rel=1e-6)
            assert block["improvement_pct"]["vs_params"] == pytest.approx(
                improvement_pct(kpi, params), rel=1e-6)


def test_case_files_are_complete(smoke_study):
    for case in smoke_study.cases:
        data = json.loads((smoke_study.out_dir / "cases" / f"{case.case_id}.json").read_text())
        assert data["config_hash"] == case.case.config_hash
        assert set(data["designs"]) == {"heuristic_median", "params-collisions",
                                        "kpi-collisions", "params-no_collisions",
                                        "kpi-no_collisions"}
        assert data["identity"]["n"] == 20


def test_resume_recomputes_only_missing_cases(smoke_study, tmp_path, monkeypatch):
    out = tmp_path / "resumed"
    shutil.copytree(smoke_study.out_dir, out)
    missing = smoke_study.cases[1].case_id
    (out / "cases" / f"{missing}.json").unlink()
    calls = []
    real = study_module.run_case

    def counted(case):
        calls.append(case.case_id)
        return real(case)

    monkeypatch.setattr(study_module, "run_case", counted)
    result = run_study(study_config_from_dict(smoke()), out, n_jobs=1, progress=False)
    assert calls == [missing]
    assert result.computed == (missing,) and result.loaded == (smoke_study.cases[0].case_id,)
    # deterministic: the same table (SQP limited by iterations, not time)
    assert without_timing(read_csv(out / "results.csv")) == without_timing(
        read_csv(smoke_study.out_dir / "results.csv"))
    # everything done: nothing is recomputed
    calls.clear()
    run_study(study_config_from_dict(smoke()), out, n_jobs=1, progress=False)
    assert calls == []


def test_resume_refuses_other_settings(smoke_study, tmp_path):
    out = tmp_path / "other"
    shutil.copytree(smoke_study.out_dir, out)
    with pytest.raises(StudyResumeError, match="n: 20 -> 21"):
        run_study(study_config_from_dict(smoke(n=21)), out, n_jobs=1, progress=False)


def test_failed_case_is_reported_not_stored(tmp_path, monkeypatch):
    def broken(case):
        raise RuntimeError(f"no luck with {case.case_id}")

    monkeypatch.setattr(study_module, "run_case", broken)
    result = run_study(study_config_from_dict(smoke()), tmp_path, n_jobs=1, progress=False)
    assert result.cases == () and len(result.failures) == 2
    assert isinstance(result.failures[0], CaseFailure)
    assert "RuntimeError: no luck with notional_l650_m600" in result.failures[0].error
    assert list((tmp_path / "cases").iterdir()) == []
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert len(summary["failures"]) == 2


def test_interrupted_case_is_not_stored(tmp_path, monkeypatch):
    """A design stopped by Ctrl-C/SIGTERM returns its best-so-far design (interrupted); the
    case then stops the study instead of being saved as finished (issue 31)."""
    import dataclasses

    import calib_oed.study.case as case_module

    real = case_module.design

    def stopped(*args, **kwargs):
        d = real(*args, **{**kwargs, "settings": dataclasses.replace(kwargs["settings"], max_iterations=1)})
        return dataclasses.replace(d, solver={**d.solver, "interrupted": True})

    monkeypatch.setattr(case_module, "design", stopped)
    with pytest.raises(KeyboardInterrupt):
        run_study(study_config_from_dict(smoke()), tmp_path, n_jobs=1, progress=False)
    assert list((tmp_path / "cases").iterdir()) == []
    assert not (tmp_path / "summary.json").exists()


def test_one_process_owns_a_study_folder(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(study_module, "run_case", lambda case: calls.append(case))
    with study_module.folder_lock(tmp_path):
        with pytest.raises(StudyLockError, match=r"in use by another study process \(pid \d+\).*-o"):
            run_study(study_config_from_dict(smoke()), tmp_path, n_jobs=1, progress=False)
    assert calls == [] and not (tmp_path / "summary.json").exists()


def test_a_cluster_without_workers_is_an_error(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        with pytest.raises(StudyConfigError, match="has no workers"):
            run_study(study_config_from_dict(smoke()), tmp_path, scheduler=cluster.scheduler_address,
                      progress=False)


def test_dask_cluster_gives_the_same_results(smoke_study, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        result = run_study(study_config_from_dict(smoke()), tmp_path,
                           scheduler=cluster.scheduler_address, progress=False)
        assert cluster.scheduler_info["workers"]  # the cluster outlives the study's client
    assert result.scheduler == cluster.scheduler_address and not result.failures
    assert without_timing(read_csv(tmp_path / "results.csv")) == without_timing(
        read_csv(smoke_study.out_dir / "results.csv"))


def test_scheduler_without_dask_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(OptionalDependencyError, match=r"pip install 'calib_oed\[dask\]'"):
        run_study(study_config_from_dict(smoke()), tmp_path, scheduler="tcp://127.0.0.1:1",
                  progress=False)


def test_corrupt_case_file_is_named(smoke_study, tmp_path):
    out = tmp_path / "corrupt"
    shutil.copytree(smoke_study.out_dir, out)
    path = out / "cases" / f"{smoke_study.cases[0].case_id}.json"
    path.write_text("{")
    with pytest.raises(StudyResumeError, match="unreadable") as info:
        run_study(study_config_from_dict(smoke()), out, n_jobs=1, progress=False)
    assert info.value.path == str(path)


# ---------------------------------------------------------------- report

def test_report_tables_match_the_table(smoke_study, tmp_path):
    paths = write_report(smoke_study, tmp_path, figures=False)
    text = paths["report"].read_text()
    for heading in ("## Table 6", "## Table 7", "## Table 8", "## Colliding poses",
                    "## Solver", "## The paper's claims and ours"):
        assert heading in text
    assert f"`{smoke_study.command}`" in text and "logical CPUs" in text
    tables = study_tables(smoke_study)
    rows = read_csv(smoke_study.out_dir / "results.csv")
    for entry in tables["cases"][True]:
        (kpi,) = [float(r["kpi_avg_variance_mm2"]) for r in rows if
                  (r["case_id"], r["kind"], r["criterion"], r["collisions"])
                  == (entry["case_id"], "optimal", "kpi", "True")]
        assert entry["kpi"] == pytest.approx(kpi, rel=1e-9)
        assert f"| {kpi:.4g} |" in text
        assert f"| {entry['vs_heuristic']:.1f} % |" in text
    means = tables["means"]
    assert means[True]["heuristic"] == means[False]["heuristic"]
    assert f"{means[False]['kpi']:.4g}" in text
    minmax = tables["minmax"][True]
    assert minmax["min"]["kpi"] == min(e["kpi"] for e in tables["cases"][True])
    colliding = tables["colliding"]
    assert colliding[("kpi", True)]["max"] == 0.0
    assert f"{100 * colliding[('params', False)]['mean']:.1f} %" in text
    # the same report from the folder alone
    again = write_report(smoke_study.out_dir, tmp_path / "again", figures=False)
    assert again["report"].read_text() == text


def test_report_flags_designs_stopped_by_the_clock(smoke_study, tmp_path):
    heading = "## Designs stopped by the wall clock (load-dependent)"
    assert smoke_study.clock_stopped() == []
    assert heading not in write_report(smoke_study, tmp_path, figures=False)["report"].read_text()
    first = smoke_study.cases[0]
    stopped = dataclasses.replace(first.row("optimal", "kpi", False), status="time_limit")
    rows = tuple(stopped if r == first.row("optimal", "kpi", False) else r for r in first.rows)
    result = dataclasses.replace(smoke_study, cases=(dataclasses.replace(first, rows=rows),
                                                     *smoke_study.cases[1:]))
    assert result.clock_stopped() == [stopped]
    text = write_report(result, tmp_path / "stopped", figures=False)["report"].read_text()
    assert heading in text and f"`{first.case_id}` kpi-no_collisions" in text


def test_report_exports_the_figure7_case_designs(smoke_study, tmp_path):
    from calib_oed.io.design_file import read_design_csv
    from calib_oed.study.report import figure7_case

    paths = write_report(smoke_study, tmp_path, figures=False)
    case = figure7_case(smoke_study)
    robot = case.case.spec.load_scene().robot
    files = sorted(paths["designs"].glob("*.csv"))
    assert [f.stem for f in files] == sorted(case.designs)
    for f in files:
        np.testing.assert_array_equal(read_design_csv(f, robot), case.designs[f.stem].q)
    assert f"designs/{case.case_id}/" in paths["report"].read_text()


def test_report_figures(smoke_study, tmp_path):
    paths = write_report(read_study(smoke_study.out_dir), tmp_path)
    for key in ("figure7", "figure8"):
        assert paths[key].stat().st_size > 10_000
        assert f"]({paths[key].name})" in paths["report"].read_text()


# ---------------------------------------------------------------- the paper's studies

@pytest.mark.slow
@pytest.mark.parametrize("name", ["kuka", "notional90"])
def test_full_study(name, tmp_path):
    """The shipped studies (minutes to half an hour on 2 cores; never in CI)."""
    result = run_study(load_study_config(name), tmp_path / name, progress=False)
    assert not result.failures
    for case in result.cases:
        for flag in (True, False):
            kpi = case.row("optimal", "kpi", flag)
            assert kpi.kpi_avg_variance_mm2 < case.row("heuristic_median").kpi_avg_variance_mm2
            assert kpi.kpi_avg_variance_mm2 < case.row("optimal", "params",
                                                       flag).kpi_avg_variance_mm2
        assert case.row("optimal", "kpi", True).feasible
        assert case.row("optimal", "params", True).feasible
    paths = write_report(result, tmp_path / name, figures=False)
    assert paths["report"].exists()


def test_sigma_improvement_is_the_standard_deviation_ratio():
    from calib_oed.study.report import sigma_improvement_pct

    v0, v1 = 1.256e-05, 4.021e-06
    from_variance = 100 * (1 - v1 / v0)
    assert sigma_improvement_pct(from_variance) == pytest.approx(100 * (1 - np.sqrt(v1) / np.sqrt(v0)))
    assert sigma_improvement_pct([0.0, 75.0]).tolist() == pytest.approx([0.0, 50.0])


# ---------------------------------------------------------------- certificate

def test_certificate_bounds_every_feasible_design(tmp_path):
    data = smoke(heuristic_seeds=[0, 1], criteria=["params", "kpi"], collisions=[True, False],
                 certificate={"pool": 300, "seed": 0, "local_starts": 0})
    data["cases"] = {"robots": [data["cases"]["robots"][0]]}
    config = study_config_from_dict(data)
    assert config.plan.certificate.pool == 300
    assert "certificate" not in load_study_config("smoke").plan.to_dict()  # old hashes unchanged
    result = run_study(config, tmp_path, n_jobs=1, progress=False)
    (case,) = result.cases
    cert = case.certificate
    assert cert["residual"] <= cert["tol"] and cert["converged"]
    assert cert["n"] == config.plan.n and cert["criterion"] == "kpi"
    feasible = [r for r in case.rows if r.feasible]
    assert len(feasible) >= 4  # the heuristic designs, their median and the designs with collisions
    for r in case.rows:
        assert r.kpi_bound_mm2 == cert["bound"]
        if r.feasible:
            assert cert["bound"] <= r.kpi_avg_variance_mm2
            assert 0 < r.kpi_efficiency <= 1
            assert r.kpi_efficiency == pytest.approx(cert["bound"] / r.kpi_avg_variance_mm2)
        else:
            assert np.isnan(r.kpi_efficiency)
    kpi_opt = case.row("optimal", "kpi", True)
    assert kpi_opt.kpi_efficiency > case.row("heuristic_median").kpi_efficiency
    # stored and reloaded, the check still holds; the report shows the columns
    again = read_study(tmp_path)
    assert again.cases[0].certificate["bound"] == cert["bound"]
    tables = study_tables(again)
    assert tables["cases"][True][0]["efficiency"] == pytest.approx(kpi_opt.kpi_efficiency)
    report = write_report(again, tmp_path, figures=False)["report"].read_text()
    assert "lower bound [mm²]" in report and "## Optimality certificate" in report


@pytest.mark.slow
@pytest.mark.skipif(not Path(sys.executable).with_name("dask").exists(), reason="needs the dask command")
def test_sigterm_on_a_command_line_cluster_then_resume_equals_jobs_1(smoke_study, tmp_path):
    """Issue 31's target: scheduler and worker started from the command line on 127.0.0.1, the
    study SIGTERM'd while it runs, resumed: the same table as the uninterrupted --jobs 1 run."""
    import signal
    import subprocess
    import time

    dask = str(Path(sys.executable).with_name("dask"))
    info = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(info)], stderr=subprocess.DEVNULL)]
    try:
        t0 = time.monotonic()
        while not info.exists() and time.monotonic() - t0 < 60:
            time.sleep(0.2)
        address = json.loads(info.read_text())["address"]
        procs.append(subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--nworkers", "1",
                                       "--no-dashboard"], stderr=subprocess.DEVNULL))
        out = tmp_path / "out"
        argv = [sys.executable, "-m", "calib_oed", "study", "smoke", "-o", str(out), "--scheduler", address,
                "--no-report"]
        first = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(20)  # inside the first case (smoke: two cases)
        first.send_signal(signal.SIGTERM)
        _, err = first.communicate(timeout=120)
        assert first.returncode in (0, 130), err
        second = subprocess.run(argv, capture_output=True, text=True, timeout=1800)
        assert second.returncode == 0, second.stderr
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=60)
    assert without_timing(read_csv(out / "results.csv")) == without_timing(
        read_csv(smoke_study.out_dir / "results.csv"))
