"""The inspection commands: evaluate, compare, validate (and the positional DESIGN argument)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, EXIT_VALIDATION_FAILED, main
from calib_oed.io.design_file import read_design_file
from calib_oed.oed.design import evaluate_design
from calib_oed.oed.result import write_design
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def designs(kr16, tmp_path_factory):
    """Two heuristic designs of 25 poses: one as design.yaml in a folder, one as a CSV."""
    root = tmp_path_factory.mktemp("designs")
    a = evaluate_design(kr16, heuristic_design(kr16, 25, 0), "kpi", method="heuristic", seed=0)
    b = evaluate_design(kr16, heuristic_design(kr16, 25, 7), "kpi", method="heuristic", seed=7)
    files_a = write_design(root / "seed0", a, kr16.problem.robot)
    files_b = write_design(root / "seed7", b, kr16.problem.robot)
    return {"a": a, "b": b, "yaml": files_a["yaml"], "csv": files_b["csv"], "root": root}


def test_design_yaml_and_csv_read_back(kr16, designs):
    robot = kr16.problem.robot
    np.testing.assert_array_equal(read_design_file(designs["yaml"], robot), designs["a"].q)
    np.testing.assert_array_equal(read_design_file(designs["csv"], robot), designs["b"].q)


def test_evaluate_reports_sigma_criteria_margins_and_meshes(capsys, kr16, designs):
    assert main(["evaluate", "fms_kr16", str(designs["yaml"])]) == EXIT_OK
    out = capsys.readouterr().out
    sigma = designs["a"].kpi_sigma_mm[0]
    assert f"car_side: {sigma:.4f} mm" in out
    # the world TCP depends on the gauge: estimated relative to the base frame it defines
    assert "car_side is estimated relative to the robot base frame the calibration defines" in out
    assert f"kpi {designs['a'].criteria['kpi']:.5g}" in out
    assert "feasible (every constraint" in out and "incidence" in out
    assert "mesh check: 25 poses" in out


def test_evaluate_json_matches_the_api(capsys, kr16, designs):
    assert main(["evaluate", "fms_kr16", str(designs["csv"]), "--json", "--no-mesh-check"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    expect = designs["b"]
    assert data["n"] == 25 and data["feasible"] is True and data["mesh_feasible"] is None
    assert data["criteria"]["kpi"] == pytest.approx(expect.criteria["kpi"], rel=1e-12)
    assert data["kpi_sigma_mm"]["car_side"] == pytest.approx(expect.kpi_sigma_mm[0], rel=1e-12)
    assert data["kpi_estimability"][0]["estimable"] is False


def test_compare_puts_designs_side_by_side(capsys, designs):
    assert main(["compare", "fms_kr16", str(designs["yaml"]), str(designs["csv"]), "--quiet"]) == EXIT_OK
    out = capsys.readouterr().out
    ratio = designs["b"].kpi_variance / designs["a"].kpi_variance
    assert "seed0" in out and "seed7" in out  # labelled by their folders
    assert f"{ratio:.1%}" in out and "100.0%" in out
    assert "O5" in out and "n poses" in out
    rows = {line.split()[0]: line for line in out.splitlines() if line.strip()}
    assert rows["kpi"].endswith("mm² (mean KPI variance, noise only)")      # every value says its unit
    assert rows["D"].endswith("log det C (mm, mrad)") and rows["O5"].endswith("(larger is better)")
    assert main(["compare", "fms_kr16", str(designs["yaml"]), str(designs["csv"]), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["designs"]["seed7"]["criteria"]["kpi"] == pytest.approx(designs["b"].kpi_variance, rel=1e-12)


@pytest.mark.parametrize("argv, fragment", [
    (["evaluate", "fms_kr16", "missing.yaml"], "cannot read the design file: not found"),
    (["compare", "fms_kr16", "missing.csv"], "cannot read the design file"),
])
def test_missing_design_files_are_one_clear_line(capsys, argv, fragment):
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err


def test_a_yaml_that_is_not_a_design_is_refused(capsys, tmp_path):
    bad = tmp_path / "scene.yaml"
    bad.write_text("version: 1\nname: x\n")
    assert main(["evaluate", "fms_kr16", str(bad)]) == EXIT_BAD_INPUT
    assert "not a calib_oed design YAML" in capsys.readouterr().err


def test_a_design_of_another_robot_is_refused(capsys, tmp_path, designs):
    text = designs["yaml"].read_text().replace("joint_a6", "wrist_3")
    (tmp_path / "design.yaml").write_text(text)
    assert main(["evaluate", "ur5_table", str(tmp_path / "design.yaml")]) == EXIT_BAD_INPUT
    assert "a design of robot 'kr16', not of this scene's robot 'ur5'" in capsys.readouterr().err


def test_positional_design_for_simulate_and_montecarlo(capsys, tmp_path, designs):
    meas = tmp_path / "m.csv"
    assert main(["simulate", "fms_kr16", str(designs["yaml"]), "-o", str(meas), "--quiet"]) == EXIT_OK
    assert len([ln for ln in meas.read_text().splitlines() if ln and not ln.startswith("#")]) == 26
    assert main(["montecarlo", "fms_kr16", str(designs["csv"]), "-N", "4", "--jobs", "1", "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["design"] == f"design file {designs['csv']}"


def test_validate_a_calibration_on_separate_data(capsys, tmp_path):
    """Identify on one simulated session, validate on another of the same robot
    (same truth seed): the calibrated model's errors drop to the noise floor.

    The shipped scene has the tracker error model and the robot's repeatability: the
    data are simulated with Sigma_i, and the floor is sqrt(mean tr Sigma_i), not the
    isotropic sqrt(3) x 0.01 mm, so a correct calibration passes (exit 0) and a wrong
    one still fails (exit 3)."""
    cal, val, out = tmp_path / "cal.csv", tmp_path / "val.csv", tmp_path / "cal"
    assert main(["simulate", "fms_kr16", "-n", "40", "--seed", "0", "--truth-seed", "4",
                 "-o", str(cal), "--quiet"]) == EXIT_OK
    assert main(["simulate", "fms_kr16", "-n", "30", "--seed", "9", "--truth-seed", "4",
                 "-o", str(val), "--quiet"]) == EXIT_OK
    assert main(["identify", "fms_kr16", str(cal), "-o", str(out), "--json"]) == EXIT_OK
    capsys.readouterr()
    assert main(["validate", "fms_kr16", str(out), str(val), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["n"] == 30
    # the floor of the scene's error model, computed here from Sigma_i at the measured positions
    from calib_oed.calibration.workflow import read_scene_measurements

    s = setup(load_scene("fms_kr16"))
    y = read_scene_measurements(s, val).positions  # tracker frame [m]
    cov = s.scene.position_noise().covariance(y)
    floor = np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))) * 1e3
    assert data["noise_floor_mm"] == pytest.approx(floor, rel=1e-12)
    assert data["noise_floor_mm"] > 1.5 * 0.01 * np.sqrt(3)  # well above the isotropic 0.0173 mm
    assert data["verdict"]["passed"] is None  # no tolerance given: no verdict
    assert data["verdict"]["predicted_rms_mm"] > 0 and len(data["poses"]) == 30
    assert data["nominal"]["rms_mm"] > 0.3  # millimetre-level geometric errors before
    # calibrated: measurement noise plus a little estimation error, nothing more
    assert 0.7 < data["rms_over_noise_floor"] < 1.3
    assert data["calibrated"]["max_mm"] < 5 * data["noise_floor_mm"]
    assert main(["validate", "fms_kr16", str(out), str(val)]) == EXIT_OK
    assert "noise floor" in capsys.readouterr().out
    # a different robot (truth seed) is caught: the calibration does not transfer
    other = tmp_path / "other.csv"
    assert main(["simulate", "fms_kr16", "-n", "30", "--seed", "9", "--truth-seed", "5",
                 "-o", str(other), "--quiet"]) == EXIT_OK
    # ... and judged against a tolerance: the verdict FAIL is exit code 3
    tol = ["--max-rms", "0.06", "--json"]
    assert main(["validate", "fms_kr16", str(out), str(other), *tol]) == EXIT_VALIDATION_FAILED
    data = json.loads(capsys.readouterr().out)
    assert data["rms_over_noise_floor"] > 5 and data["verdict"]["achieved_over_predicted"] > 5
    assert main(["validate", "fms_kr16", str(out), str(val), *tol]) == EXIT_OK
    # a calibration off by only 0.1 mm in the reflector offset (~3 x the floor) fails too
    import yaml

    sensor = out / "kr16_sensor.yaml"
    spec = yaml.safe_load(sensor.read_text())
    spec["reflectors"][0]["offset_m"][0] += 1e-4
    spec["reflectors"][0]["offset_mm"][0] += 0.1
    sensor.write_text(yaml.safe_dump(spec))
    capsys.readouterr()
    assert main(["validate", "fms_kr16", str(out), str(val), *tol]) == EXIT_VALIDATION_FAILED
    assert json.loads(capsys.readouterr().out)["verdict"]["passed"] is False


@pytest.mark.parametrize("target, fragment", [
    ("missing_dir", "does not exist"),
    ("empty", "no unique calibrated URDF"),
])
def test_validate_errors(capsys, tmp_path, target, fragment):
    (tmp_path / "empty").mkdir()
    meas = tmp_path / "m.csv"
    assert main(["simulate", "fms_kr16", "-n", "10", "-o", str(meas), "--quiet"]) == EXIT_OK
    assert main(["validate", "fms_kr16", str(tmp_path / target), str(meas)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err


def test_plots_from_evaluate_compare_and_identify(capsys, tmp_path, designs):
    assert main(["evaluate", "fms_kr16", str(designs["yaml"]), "--no-mesh-check",
                 "--plot", str(tmp_path / "ev")]) == EXIT_OK
    for name in ("kpi_ellipsoid.png", "pose_contributions.png"):
        assert (tmp_path / "ev" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["compare", "fms_kr16", str(designs["yaml"]), str(designs["csv"]), "--quiet",
                 "--plot", str(tmp_path / "cmp.svg")]) == EXIT_OK
    assert b"<svg" in (tmp_path / "cmp.svg").read_bytes()[:500]
    meas = tmp_path / "m.csv"
    assert main(["simulate", "fms_kr16", str(designs["csv"]), "-o", str(meas), "--quiet"]) == EXIT_OK
    assert main(["identify", "fms_kr16", str(meas), "--plot", str(tmp_path / "res.pdf")]) == EXIT_OK
    assert (tmp_path / "res.pdf").read_bytes()[:5] == b"%PDF-"
    capsys.readouterr()
    assert main(["compare", "fms_kr16", str(designs["csv"]), "--plot", str(tmp_path / "x.jpg")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "'.png', '.svg', '.pdf'" in err and not (tmp_path / "x.jpg").exists()


def test_view_writes_a_static_page_and_serves_live(capsys, tmp_path, designs):
    html = tmp_path / "view.html"
    assert main(["view", "fms_kr16", str(designs["yaml"]), "--html", str(html), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["poses"] == 25 and html.stat().st_size > 10_000
    assert "<html" in html.read_text()[:2000].lower()
    # the drawn scale brings the largest true half-axis to a visible size (1-2-5 number near 50 mm)
    assert 20 <= data["ellipsoid_scale"] * data["ellipsoid_half_axes_mm"][0][0] <= 125
    assert main(["view", "fms_kr16", "--for", "0"]) == EXIT_OK
    assert "meshcat viewer at http://" in capsys.readouterr().out


@pytest.mark.parametrize("extra, fragment", [
    (["--scale", "-1"], "--scale: expected a drawing scale > 0"),
    (["--level", "1.5"], "level"),
])
def test_view_errors(capsys, tmp_path, designs, extra, fragment):
    html = tmp_path / "v.html"
    assert main(["view", "fms_kr16", str(designs["csv"]), "--html", str(html), *extra]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err and not html.exists()


def test_study_smoke_runs_resumes_and_reports(capsys, tmp_path):
    out = tmp_path / "smoke"
    assert main(["study", "smoke", "-o", str(out), "--jobs", "1", "--quiet", "--no-figures"]) == EXIT_OK
    text = capsys.readouterr().out
    assert "2 of 2 cases done (2 computed now, 0 loaded" in text
    table = (out / "results.csv").read_text()
    assert (out / "report.md").is_file() and "heuristic_median" in table
    assert main(["study", "smoke", "-o", str(out), "--json", "--no-report"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["computed"] == [] and len(data["loaded"]) == 2 and data["n_done"] == 2
    assert (out / "results.csv").read_text() == table
    runs = json.loads((out / "runs.json").read_text())  # the computing run's time is kept
    assert [r["computed"] for r in runs] == [2, 0] and runs[0]["wall_seconds"] > runs[1]["wall_seconds"]
    assert main(["study", "smoke", "-o", str(out), "--quiet", "--no-figures"]) == EXIT_OK
    report = (out / "report.md").read_text()
    assert report.count("cases computed") == 3 and "2 cases computed" in report


def test_study_errors(capsys, tmp_path):
    assert main(["study", "no_such_study", "-o", str(tmp_path)]) == EXIT_BAD_INPUT
    assert "kuka" in capsys.readouterr().err  # names the shipped studies
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ncases: {robots: [{robot: kr16, scene: fms_kr16}]}\nn: -3\n")
    assert main(["study", str(bad), "-o", str(tmp_path / "o")]) == EXIT_BAD_INPUT
    assert "Traceback" not in capsys.readouterr().err


def test_every_command_is_documented():
    from pathlib import Path

    from calib_oed.cli import build_parser

    text = (Path(__file__).parents[2] / "docs" / "cli.md").read_text()
    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    missing = [name for name in sub.choices if f"`{name}" not in text]
    assert not missing, f"docs/cli.md lacks {missing}"


def test_json_listings_and_simulate(capsys, tmp_path):
    assert main(["scenes", "--json"]) == EXIT_OK
    assert "fms_kr16" in json.loads(capsys.readouterr().out)
    assert main(["robots", "--json"]) == EXIT_OK
    assert "kr16" in json.loads(capsys.readouterr().out)
    assert main(["simulate", "fms_kr16", "-n", "12", "-o", str(tmp_path / "m.csv"), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["n"] == 12 and (tmp_path / "m_truth.yaml").is_file()


def test_evaluate_with_a_certificate(capsys, designs):
    """The bound of the certificate lies below the design's own value (a small pool keeps it fast)."""
    assert main(["evaluate", "fms_kr16", str(designs["csv"]), "--no-mesh-check", "--json",
                 "--certificate", "--pool", "150"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    cert = data["certificate"]
    assert cert["criterion"] == "kpi" and cert["n"] == 25
    assert cert["bound"] <= data["criteria"]["kpi"]
    assert 0 < cert["efficiency"] <= 1
