"""The CLI on a KPI of several points: `design --aggregate max` and `evaluate` on fms_kr16_program."""

from __future__ import annotations

import json

import numpy as np

from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main


def test_design_worst_case_then_evaluate(capsys, tmp_path):
    argv = ["design", "fms_kr16_program", "-n", "12", "--aggregate", "max", "--iterations", "8",
            "--json", "-o", str(tmp_path)]
    assert main(argv) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    sigma = data["kpi_sigma_mm"]
    assert len(sigma) == 30 and "sweep_z800@8" in sigma
    assert data["criterion"] == "kpi_max" and data["feasible"]
    # the value is the worst point's variance, and it went down from the start
    assert np.isclose(data["value"], max(sigma.values()) ** 2, rtol=1e-6)
    assert data["kpi_worst"] == max(sigma, key=sigma.get)
    assert data["value"] < 0.8 * data["start_value"]
    assert np.isclose(data["kpi_max_variance_mm2"], data["value"], rtol=1e-6)

    assert main(["evaluate", "fms_kr16_program", str(tmp_path / "design.csv"), "--no-mesh-check"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "30 KPI points: mean variance" in out and f"at {data['kpi_worst']}" in out


def test_aggregate_max_needs_the_kpi_criterion(capsys):
    argv = ["design", "fms_kr16_program", "-n", "12", "--criterion", "D", "--aggregate", "max"]
    assert main(argv) == EXIT_BAD_INPUT
    assert "'kpi' only" in capsys.readouterr().err


def test_the_scene_aggregate_is_the_default(capsys, tmp_path):
    from importlib import resources

    text = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16_program.yaml").read_text()
    scene = tmp_path / "worst.yaml"
    scene.write_text(text.replace("\n  aggregate: mean ", "\n  aggregate: max "))
    argv = ["design", str(scene), "-n", "12", "--iterations", "2", "--no-certificate", "--json"]
    assert main(argv) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["criterion"] == "kpi_max"
    assert main([*argv, "--aggregate", "mean"]) == EXIT_OK  # the flag overrides the scene
    assert json.loads(capsys.readouterr().out)["criterion"] == "kpi"
