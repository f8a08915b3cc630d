"""identify and validate on real-data mistakes: sanity exit 2 before any file, outliers by file line,
residuals.csv, cross-validation, the validation verdict (exit 3)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from calib_oed.calibration.workflow import setup, simulated_measurements, write_measurement_file
from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main
from calib_oed.cli.calibration_commands import EXIT_VALIDATION_FAILED
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """60 calibration and 60 validation poses of one simulated kr16 (truth seed 5), files in mm."""
    folder = tmp_path_factory.mktemp("id")
    s = setup(load_scene("fms_kr16"))
    q = s.problem.robot.random_configurations(120, 11)
    mset, _ = simulated_measurements(s, q, 5)
    from calib_oed.calibration.crossval import subset

    cal, val = folder / "cal.csv", folder / "val.csv"
    write_measurement_file(s, cal, subset(mset, np.arange(60)), "test calibration data")
    write_measurement_file(s, val, subset(mset, np.arange(60, 120)), "test validation data")
    return folder, cal, val


def _variant(folder, cal, name, edit):
    path = folder / name
    path.write_text(edit(cal.read_text()))
    return path


@pytest.mark.parametrize("name, edit, cause", [
    ("units.csv", lambda t: t.replace("length=mm", "length=m"), "1000 times too large"),
    ("swapped.csv", lambda t: t.replace("reflector,x,y,z", "reflector,y,x,z"),
     "column x holds y, y holds x"),
])
def test_data_mistakes_stop_with_exit_2_before_any_file(files, capsys, name, edit, cause):
    folder, cal, _ = files
    bad = _variant(folder, cal, name, edit)
    out = folder / f"out_{name}"
    assert main(["identify", "fms_kr16", str(bad), "-o", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "registration RMS" in err and cause in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_outlier_flagged_by_line_and_validation_verdict(files, capsys):
    folder, cal, val = files
    rows = cal.read_text().splitlines()
    header = next(i for i, r in enumerate(rows) if r.startswith("joint_a1"))
    target = header + 1 + 23  # the 24th data row, 0-based index in the text
    fields = rows[target].split(",")
    fields[-3] = f"{float(fields[-3]) + 5.0:.6f}"  # x + 5 mm
    rows[target] = ",".join(fields)
    bad = folder / "outlier.csv"
    bad.write_text("\n".join(rows) + "\n")
    out = folder / "cal_out"
    assert main(["identify", "fms_kr16", str(bad), "-o", str(out), "--cv", "4", "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    fit = data["fit"]
    assert [o["line"] for o in fit["outliers"]] == [target + 1]  # 1-based file line
    (o,) = fit["outliers"]
    assert o["reflector"] == "smr0" and o["weight"] == 0.0 and o["normalised"] > 100
    assert o["after_mm"] > 4.0
    table = list(csv.DictReader(r for r in (out / "residuals.csv").read_text().splitlines()
                                if not r.startswith("#")))
    assert len(table) == 60 and [int(r["line"]) for r in table if r["outlier"] == "1"] == [target + 1]
    assert set(fit["per_reflector"]) == {"smr0"}
    assert 0.8 < fit["sigma0"] < 1.2
    cv = data["cross_validation"]
    assert cv["k"] == 4 and cv["rms_mm"] > 0 and cv["warnings"] == []
    assert "every one of the 60 rows" not in json.dumps(cv)  # (the text report says it)
    # the dropped gross row is in the folds and in the held-out error, and counted
    assert cv["rows"] == 60 and cv["gross_rows"] == 1
    assert cv["rms_without_gross_mm"] < 0.5 * cv["rms_mm"]  # a 5 mm row among 0.05 mm ones
    # the predicted accuracy covers parameter uncertainty, model error and noise, in JSON too
    pred = data["predicted_accuracy"]["uncompensated"]
    assert "model error" in pred["covers"] and pred["new_pose_rms_mm"] > 0
    assert [w["name"] for w in pred["working_configurations"]] == ["car_side"]
    assert data["model_error"]["fitted"]["sigma_mm"] > 0 and data["training_joint_ranges"]
    # no tolerance: no verdict (exit 0), the achieved error against the prediction
    assert main(["validate", "fms_kr16", str(out), str(val), "--json"]) == EXIT_OK
    report = json.loads(capsys.readouterr().out)
    verdict = report["verdict"]
    assert verdict["passed"] is None and 0.6 < verdict["achieved_over_predicted"] < 1.25
    # judged against the prediction at these very measurements, not the headline on new poses
    assert verdict["predicted_rms_mm"] == report["predicted_rms_mm"]
    assert verdict["predicted_where"] == "at these validation measurements"
    assert pred["new_poses"] == "feasible poses in the training joint ranges" and pred["tcp_frame"] == "tracker"
    # the floor of the scene's tracker error model and repeatability (sqrt(mean tr Sigma_i))
    floor = report["noise_floor_mm"]
    assert floor > 1.5 * 0.01 * np.sqrt(3)
    assert verdict["rms_mm"] <= 1.2 * floor
    assert main(["validate", "fms_kr16", str(out), str(val), "--max-rms", "0.001"]) \
        == EXIT_VALIDATION_FAILED
    assert "verdict: FAIL" in capsys.readouterr().out
    assert main(["validate", "fms_kr16", str(out), str(val), "--max-error", "1", "--compensate"]) \
        == EXIT_OK
    assert "verdict: PASS" in capsys.readouterr().out
    assert main(["validate", "fms_kr16", str(out), str(val), "--max-error", "-1"]) == EXIT_BAD_INPUT
    assert "--max-error" in capsys.readouterr().err


def test_validate_stops_on_a_unit_mistake(files, capsys):
    folder, cal, val = files
    out = folder / "cal_plain"
    assert main(["identify", "fms_kr16", str(cal), "-o", str(out), "--loss", "linear"]) == EXIT_OK
    text = capsys.readouterr().out
    assert "reflector smr0" in text and "sigma0 =" in text and "worst-determined" in text
    bad = _variant(folder, val, "val_units.csv", lambda t: t.replace("length=mm", "length=m"))
    assert main(["validate", "fms_kr16", str(out), str(bad)]) == EXIT_BAD_INPUT
    assert "1000 times too large" in capsys.readouterr().err


def test_identify_report_names_one_set_of_outliers(tmp_path, capsys):
    """Review finding: on data with model error (realistic truth) the plain 3-sigma rule of the
    fit counts rows the robust rule (noise + model error) keeps; the report said "without the
    outliers sigma0^2 = ..." on the sigma0 line and "outliers ...: none" below it, and the JSON
    carried that rule's ``noise_factor_inliers`` beside an empty ``outliers``. One rule only."""
    from calib_oed.calibration.workflow import realistic_measurements

    s = setup(load_scene("fms_kr16"))
    q = s.problem.robot.random_configurations(40, 3)
    mset, _, _ = realistic_measurements(s, q, 3)
    meas = tmp_path / "meas.csv"
    write_measurement_file(s, meas, mset, "realistic truth seed 3")
    out = tmp_path / "cal"
    assert main(["identify", "fms_kr16", str(meas), "-o", str(out)]) == EXIT_OK
    text = capsys.readouterr().out
    data = json.loads((out / "identification.json").read_text())
    assert data["sigma0"] > 3  # model error: the plain 3-sigma rule has rows to count
    assert data["outliers"] == [] and "outliers (leave-one-out" in text
    assert "without the outliers" not in text
    assert "noise_factor_inliers" not in data
    # the report's path as written (it said "and identification.json", without the folder)
    assert f"and {out / 'identification.json'};" in text
    assert data["files"]["report"] == str(out / "identification.json")


def test_validate_names_poses_of_the_identification_itself(files, capsys):
    """Review finding: ``validate`` on the identification's own measurement file passed without a
    word (its errors are the fit's residuals, not an independent validation). Validation poses
    that are training poses are now counted and warned about; separate poses get no warning."""
    folder, cal, val = files
    out = folder / "cal_self"
    assert main(["identify", "fms_kr16", str(cal), "-o", str(out), "--quiet"]) == EXIT_OK
    capsys.readouterr()
    for path, shared in ((cal, 60), (val, 0)):
        assert main(["validate", "fms_kr16", str(out), str(path)]) == EXIT_OK
        text = capsys.readouterr().out
        assert ("warning: 60 of 60 validation poses are poses the identification was fitted to"
                in text) is (shared > 0)
        assert main(["validate", "fms_kr16", str(out), str(path), "--json"]) == EXIT_OK
        assert json.loads(capsys.readouterr().out)["poses_in_training"] == shared


def test_identify_takes_the_scenes_joint_prior_for_the_world_frame(files, tmp_path, capsys):
    """The scene's ``robot.model_error: {kind: joint}`` is the prior of identify's world-frame
    numbers (the same prior as the design's), not the size-class default."""
    from pathlib import Path

    import calib_oed.scene.shipped as shipped

    _, cal, _ = files
    text = (Path(shipped.__file__).parent / "fms_kr16.yaml").read_text()
    assert "\nrobot:\n" in text
    scene = tmp_path / "kr16_prior.yaml"
    scene.write_text(text.replace("\nrobot:\n", "\nrobot:\n  model_error: {kind: joint, once_arcsec: 120}\n", 1))
    worlds = []
    for name, where in (("default", "fms_kr16"), ("scene", str(scene))):
        assert main(["identify", where, str(cal), "-o", str(tmp_path / name), "--json"]) == EXIT_OK
        worlds.append(json.loads(capsys.readouterr().out)["predicted_accuracy"]["uncompensated"]["world_frame"])
    default, given = worlds
    assert given["prior"].startswith("scene (default") and default["prior"].startswith("default")
    assert given["working_configurations"][0]["gauge_share_mm2"] != default["working_configurations"][0]["gauge_share_mm2"]
