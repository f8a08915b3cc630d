"""The calib-oed command: output, JSON, and one-line errors with exit code 2."""

from __future__ import annotations

import json

import pytest

from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main


def test_identifiability_text(capsys):
    assert main(["identifiability", "fms_kr16"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "free (identifiable): 25" in out
    assert "joint1.tx" in out and "redundant with" in out
    # the world-frame TCP depends on the gauge: stated positively, with its frame
    assert "car_side: estimated relative to the robot base frame the calibration defines" in out
    assert "NOT estimable" not in out


def test_a_kpi_no_measurement_sees_is_not_estimable(capsys, tmp_path):
    """Off the A6 axis, the TCP turns with A6's zero offset, which a reflector on the axis never sees."""
    from importlib import resources

    text = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml").read_text()
    scene = tmp_path / "off_axis.yaml"
    scene.write_text(text.replace("  point: [0, 0, 0]  ", "  point: [100, 0, 0]"))
    assert main(["identifiability", str(scene)]) == EXIT_OK
    assert "car_side: NOT estimable (residual 0.41): it depends on joint6.rx, which no measurement " \
        "sees" in capsys.readouterr().out


def test_identifiability_json(capsys):
    assert main(["identifiability", "fms_kr16", "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["rank"] == len(data["free"]) == 25
    assert data["n_parameters"] == len(data["free"]) + len(data["fixed"]) == 45
    assert data["condition_number"] > 1
    (kpi,) = data["kpi"]["estimability"]
    assert kpi["estimable"] is False and kpi["residual"] > 1e-3 and kpi["gauge"]


def test_demo_runs_the_whole_job(capsys, tmp_path):
    argv = ["demo", "fms_kr16", "-n", "20", "--seed", "1", "-N", "6", "--jobs", "1", "--quiet",
            "--iterations", "15", "--pool", "400", "-o", str(tmp_path)]
    assert main(argv) == EXIT_OK
    out = capsys.readouterr().out
    assert "KPI standard deviation" in out and " mm" in out
    assert "feasible: True" in out
    assert "TCP error before" in out and "round trip" in out
    assert "coverage of the 95% ellipsoid" in out
    assert (tmp_path / "kr16_calibrated.urdf").is_file() and (tmp_path / "kr16_sensor.yaml").is_file()
    assert "C_p-optimal" in out and "KPI-optimal" in out and (tmp_path / "design.yaml").is_file()
    assert "KPI-optimal: " in out and "% of the best any 20-pose feasible design" in out
    assert "round trip: largest tool difference" in out and " nm" not in out
    assert out.rstrip().endswith(f"the demo's files are in {tmp_path.resolve()} (overwritten by the next run)")


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["identifiability", "no_such_scene"], "shipped scenes are"),
        (["identifiability", "/tmp/does/not/exist.yaml"], "not found"),
    ],
)
def test_errors_are_one_line(capsys, argv, fragment):
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert fragment in err and err.count("\n") == 1 and "Traceback" not in err


def test_scenes_and_robots(capsys):
    assert main(["scenes"]) == EXIT_OK
    assert "fms_kr16" in capsys.readouterr().out.split()
    assert main(["robots"]) == EXIT_OK
    assert {"kr16", "ur5", "panda"} <= set(capsys.readouterr().out.split())


def test_demo_rejects_a_non_positive_pose_count(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "-n", "0"])
    assert exc.value.code == 2 and "expected a number of poses from 1 to 10000" in capsys.readouterr().err


def test_demo_with_too_few_poses_says_so(capsys):
    assert main(["demo", "-n", "5"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "measure more configurations" in err and "Traceback" not in err


def test_feasibility_command(capsys, tmp_path):
    design = tmp_path / "design.csv"
    assert main(["feasibility", "fms_kr16", "-n", "10", "-o", str(design)]) == EXIT_OK
    out = capsys.readouterr().out
    assert "paper formula" in out and "10 of 10 feasible" in out
    assert "incidence" in out and "all 10 poses" in out.lower() or "feasible" in out
    from calib_oed.io.design_file import read_design_csv
    from calib_oed.scene.reader import load_scene

    q = read_design_csv(design, load_scene("fms_kr16").robot)
    assert q.shape == (10, 6)
    assert main(["feasibility", "fms_kr16", "--design", str(design), "--json", "--no-mesh-check"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["feasible"] == 10 and data["constraints_per_pose"]["joint"] == 12


def test_simulate_then_identify_with_export(capsys, tmp_path):
    meas = tmp_path / "meas.csv"
    assert main(["simulate", "fms_kr16", "-n", "40", "--seed", "2", "--truth-seed", "3",
                 "-o", str(meas)]) == EXIT_OK
    truth = tmp_path / "meas_truth.yaml"
    assert meas.is_file() and truth.is_file()
    out_dir = tmp_path / "cal"
    capsys.readouterr()
    assert main(["identify", "fms_kr16", str(meas), "--truth", str(truth), "-o", str(out_dir),
                 "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["status"] == "converged"
    before, after = data["tcp_error_mm"]["before"][0], data["tcp_error_mm"]["after"][0]
    assert after < 0.05 < before
    assert data["round_trip_m"] < 1e-9
    assert (out_dir / "kr16_calibrated.urdf").is_file() and (out_dir / "identification.json").is_file()


def test_montecarlo_command_json(capsys, tmp_path):
    assert main(["montecarlo", "fms_kr16", "-n", "30", "-N", "8", "--jobs", "1", "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    (wc,) = data["working_configurations"]
    assert wc["rms_after_mm"] < wc["rms_before_mm"] and 0 <= wc["coverage"] <= 1


def test_identify_bad_file_names_the_lines(capsys, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("# units: length=mm angle=deg\n"
                   "joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6,x,y,z\n"
                   "0,-90,90,0,0,0,1,2,3\n"
                   "0,-90,nan,0,0,0,1,2,3\n")
    assert main(["identify", "fms_kr16", str(bad)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "line 4" in err and "Traceback" not in err


def test_bad_design_file_is_reported(capsys, tmp_path):
    bad = tmp_path / "design.csv"
    bad.write_text("joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a9\n0,0,0,0,0,0\n")
    assert main(["feasibility", "fms_kr16", "--design", str(bad)]) == EXIT_BAD_INPUT
    assert "joint_a9" in capsys.readouterr().err


def test_design_command_writes_both_files(capsys, tmp_path):
    import yaml

    argv = ["design", "fms_kr16", "-n", "12", "--seed", "4", "--iterations", "10", "--quiet",
            "--time-limit", "60", "--no-certificate", "-o", str(tmp_path)]
    assert main(argv) == EXIT_OK
    out = capsys.readouterr().out
    assert "sqp design of 12 poses" in out and "feasible: True" in out
    data = yaml.safe_load((tmp_path / "design.yaml").read_text())
    assert data["criterion"] == "kpi_model" and len(data["configurations_rad"]) == 12  # the default
    assert data["value"] < data["start_value"]
    header = (tmp_path / "design.csv").read_text().splitlines()
    assert "joint_a1" in [h for h in header if not h.startswith("#")][0]


def test_design_command_json_and_errors(capsys, tmp_path):
    assert main(["design", "fms_kr16", "-n", "12", "--criterion", "D", "--iterations", "3",
                 "--no-certificate", "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["criterion"] == "D" and data["files"] == {}
    with pytest.raises(SystemExit):
        main(["design", "fms_kr16", "--criterion", "Z"])
    assert "invalid choice" in capsys.readouterr().err
    assert main(["design", "fms_kr16", "-n", "3"]) == EXIT_BAD_INPUT
    assert "measure more configurations" in capsys.readouterr().err
    assert main(["design", "fms_kr16", "--start", str(tmp_path / "missing.csv")]) == EXIT_BAD_INPUT


def test_design_command_from_the_exchange_start(capsys):
    argv = ["design", "fms_kr16", "-n", "12", "--start", "exchange", "--iterations", "2",
            "--no-certificate", "--json"]
    assert main(argv) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["feasible"] and data["value"] <= data["start_value"]
