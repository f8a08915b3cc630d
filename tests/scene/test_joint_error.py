"""Tests of calib_oed.scene.joint_error: ``robot.model_error`` with ``kind: joint``, its units,
one test per validation failure, and the prior taken from an identification JSON."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib_oed.calibration.joint_prior_choice import joint_prior
from calib_oed.calibration.workflow import setup
from calib_oed.exceptions import IdentificationFileError, SceneError
from calib_oed.measurement.joint_prior import ARCSEC
from calib_oed.scene.joint_error import spec_from_identification
from calib_oed.scene.reader import load_scene, scene_from_dict

SHIPPED = Path(load_scene("fms_kr16").source)


def _scene_dict(error) -> dict:
    data = yaml.safe_load(SHIPPED.read_text())
    data["robot"]["model_error"] = copy.deepcopy(error)
    return data


def _identification(harmonic=True, gains=None) -> dict:
    fitted = {"sigma_mm": 0.05, "length_scales_deg": [40, 50, None, 90, 90, 120], "kernel": "matern52"}
    if harmonic:
        fitted["harmonic_mm"] = [[0.01 * (i + 1), 0.005] for i in range(6)]
    p = {f"joint{i}.tx": 0.0 for i in range(1, 7)}
    for i, g in (gains or {}).items():
        p[f"joint{i}.gain"] = g
    return {"model_error": {"fitted": fitted}, "p": p}


def test_joint_keys_in_their_units_and_defaults_elsewhere():
    scene = scene_from_dict(_scene_dict({"kind": "joint", "once_arcsec": [10, 10, 10, 5, 5, 5],
                                         "length_deg": 30, "stiffness_knm_per_rad": 200,
                                         "gain": 1e-4, "scale": 2}))
    spec = scene.joint_error
    assert scene.model_error is None and spec.source == "scene" and spec.scale == 2.0
    np.testing.assert_allclose(spec.values["once"], np.array([10, 10, 10, 5, 5, 5]) * ARCSEC)
    np.testing.assert_allclose(spec.values["length"], np.full(6, np.radians(30)))
    np.testing.assert_allclose(spec.values["compliance"], np.full(6, 1 / 200e3))  # rad/(N m)
    np.testing.assert_allclose(spec.values["gain"], np.full(6, 1e-4))
    assert set(spec.values) == {"once", "length", "compliance", "gain"}  # twice, smooth: defaults
    direct = scene_from_dict(_scene_dict({"kind": "joint", "compliance_urad_per_nm": 5}))
    np.testing.assert_allclose(direct.joint_error.values["compliance"], np.full(6, 5e-6))
    motor = scene_from_dict(_scene_dict({"kind": "joint", "motor_arcsec": 0, "motor_length_mrad": 30,
                                         "smooth_arcsec": 10}))
    np.testing.assert_allclose(motor.joint_error.values["motor"], np.zeros(6))
    np.testing.assert_allclose(motor.joint_error.values["motor_length"], np.full(6, 0.03))
    prior = joint_prior(setup(motor).problem, motor.joint_error)  # the default before its motor-side part
    assert not prior.has_motor and np.allclose(prior.smooth, 10 * ARCSEC)


@pytest.mark.parametrize("error, key, says", [
    ({"kind": "joint", "once_arcsec": -1}, "robot.model_error.once_arcsec[0]", ">= 0"),
    ({"kind": "joint", "length_deg": 0}, "robot.model_error.length_deg[0]", "> 0"),
    ({"kind": "joint", "motor_length_mrad": 0}, "robot.model_error.motor_length_mrad[0]", "> 0"),
    ({"kind": "joint", "twice_arcsec": [1, 2]}, "robot.model_error.twice_arcsec", "6 (one per joint)"),
    ({"kind": "joint", "gain": "big"}, "robot.model_error.gain[0]", "expected a number"),
    ({"kind": "joint", "compliance_urad_per_nm": 5, "stiffness_knm_per_rad": 100},
     "robot.model_error.stiffness_knm_per_rad", "not both"),
    ({"kind": "joint", "scale": 0}, "robot.model_error.scale", "> 0"),
    ({"kind": "joint", "once": 3}, "robot.model_error.once", "unknown key"),
    ({"kind": "cartesian", "sigma": 0.1}, "robot.model_error.kind", "expected 'joint'"),
    ({"kind": "joint", "from": "missing.json"}, "robot.model_error.from", "cannot read"),
])
def test_bad_values_name_the_key(error, key, says):
    with pytest.raises(SceneError) as info:
        scene_from_dict(_scene_dict(error))
    assert key in str(info.value) and says in str(info.value)


def test_from_an_identification_relative_to_the_scene_keys_override(tmp_path):
    (tmp_path / "id.json").write_text(json.dumps(_identification(gains={2: -3e-4, 3: 1e-4})))
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(yaml.safe_dump(_scene_dict({"kind": "joint", "from": "id.json", "gain": 2e-5})))
    spec = load_scene(scene_file).joint_error
    assert str(tmp_path / "id.json") in spec.source
    np.testing.assert_allclose(spec.values["gain"], np.full(6, 2e-5))  # the key wins over the file
    np.testing.assert_allclose(spec.at_point["once"], 1e-5 * np.arange(1, 7))
    np.testing.assert_allclose(spec.at_point["smooth"], [5e-5, 5e-5, 0, 5e-5, 5e-5, 5e-5])  # joint 3 ignored
    assert np.isnan(spec.values["length"][2]) and spec.values["length"][0] == pytest.approx(np.radians(40))


def test_identification_gains_and_a_fit_without_harmonics():
    spec = spec_from_identification(_identification(harmonic=False, gains={2: -3e-4}), 6)
    np.testing.assert_array_equal(spec.values["once"], np.zeros(6))  # the smooth part holds it
    assert "once" not in spec.at_point and "compliance" not in spec.values
    gain = spec.values["gain"]
    assert gain[1] == pytest.approx(3e-4) and np.isnan(gain[0])  # others keep the default


@pytest.mark.parametrize("data, says", [
    ({"p": {}}, "no model_error.fitted"),
    ({"model_error": {"fitted": {"sigma_mm": 0.1, "length_scales_deg": [40] * 5}}}, "6 length scales"),
    ({"model_error": {"fitted": {"sigma_mm": 0.1, "length_scales_deg": [40] * 6,
                                 "harmonic_mm": [[1, 2]]}}}, "harmonic_mm needs 6 pairs"),
    ({"model_error": {"fitted": {"sigma_mm": "x", "length_scales_deg": [40] * 6}}}, "not a number"),
])
def test_bad_identification_files_say_what_is_missing(data, says):
    with pytest.raises(IdentificationFileError, match=says):
        spec_from_identification(data, 6)
