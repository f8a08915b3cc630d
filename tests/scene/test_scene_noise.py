"""Scene keys of the measurement error model: ``tracker.noise`` and ``robot.repeatability``."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.exceptions import SceneError
from calib_oed.scene.reader import scene_from_dict
from tests.scene.test_scene_reader import mutated, valid

NOISE = {"radial": [0.005, 0.00015], "lateral": [0.0075, 0.003]}  # [mm, mm per m]


def with_noise(noise=NOISE, repeatability=0.011) -> dict:
    data = mutated(("tracker", "noise"), noise)
    data["robot"]["repeatability"] = repeatability
    return data


def test_keys_read_in_si():
    scene = scene_from_dict(with_noise())
    assert scene.tracker.noise.radial == pytest.approx((5e-6, 1.5e-7), rel=1e-12)
    assert scene.tracker.noise.lateral == pytest.approx((7.5e-6, 3e-6), rel=1e-12)
    assert scene.repeatability == pytest.approx(1.1e-5, rel=1e-12)
    noise = scene.position_noise()
    assert noise.repeatability == pytest.approx(1.1e-5, rel=1e-12)
    models = CalibrationProblem.from_scene(scene).models
    assert all(m.noise == noise for m in models)


def test_absent_keys_keep_the_isotropic_model():
    scene = scene_from_dict(valid())
    assert scene.tracker.noise is None and scene.repeatability == 0.0
    assert scene.position_noise() is None
    assert all(m.noise is None for m in CalibrationProblem.from_scene(scene).models)


def test_repeatability_alone_adds_to_sigma():
    data = valid()
    data["robot"]["repeatability"] = 0.04
    noise = scene_from_dict(data).position_noise()
    y = np.array([[1.0, 2.0, 0.5]])
    np.testing.assert_allclose(noise.covariance(y)[0], (1e-10 + 1.6e-9) * np.eye(3), rtol=1e-12)


@pytest.mark.parametrize(("data", "key", "text"), [
    (mutated(("tracker", "noise"), {"radial": [0.005, 0.0]}), "tracker.noise.lateral",
     "missing"),
    (mutated(("tracker", "noise"), {**NOISE, "angular": [1, 2]}), "tracker.noise.angular",
     "radial"),
    (mutated(("tracker", "noise"), {**NOISE, "radial": [0.005]}), "tracker.noise.radial", "2"),
    (mutated(("tracker", "noise"), {**NOISE, "lateral": [0.0075, -0.003]}),
     "tracker.noise.lateral", ">= 0"),
    (mutated(("tracker", "noise"), {**NOISE, "radial": [0.0, 0.001]}),
     "tracker.noise.radial", "> 0"),
    ({**with_noise(), "measurement": "pose"}, "tracker.noise", "position only"),
    (with_noise(repeatability=-0.01), "robot.repeatability", ">= 0"),
    ({**mutated(("tracker", "sigma"), [0.01, 0.02, 0.01]), "robot": {
        "name": "kr16", "repeatability": 0.04}}, "robot.repeatability", "scalar tracker.sigma"),
])
def test_bad_keys_are_named(data, key, text):
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, source="cell.yaml")
    assert err.value.key == key
    assert str(err.value).startswith(f"cell.yaml: {key}: ")
    assert text in str(err.value)


def test_vendor_specifications_as_the_data_sheet_states_them():
    """``tracker.mpe`` (MPE +-(a + b L) at k = 2) and ``robot.rp`` (ISO 9283 RP) give the
    sigmas a user would have converted by hand (issue 34)."""
    from calib_oed.measurement.noise import ISO9283_RP_PER_SIGMA

    data = mutated(("tracker", "mpe"), {"radial": [0.010, 0.0003], "lateral": [0.015, 0.006]})
    data["robot"]["rp"] = 0.05
    scene = scene_from_dict(data)
    assert scene.tracker.noise.radial == pytest.approx((5e-6, 1.5e-7), rel=1e-12)
    assert scene.tracker.noise.lateral == pytest.approx((7.5e-6, 3e-6), rel=1e-12)
    assert scene.repeatability == pytest.approx(5e-5 / ISO9283_RP_PER_SIGMA, rel=1e-12)
    data["tracker"]["mpe"]["k"] = 3
    assert scene_from_dict(data).tracker.noise.radial == pytest.approx((1e-5 / 3, 1e-7), rel=1e-12)


@pytest.mark.parametrize("edit, fragment", [
    (lambda d: d["tracker"].update(noise=NOISE), "not both"),
    (lambda d: d["robot"].update(repeatability=0.01), "not both"),
    (lambda d: d["tracker"]["mpe"].update(k=0), "tracker.mpe.k"),
    (lambda d: d["tracker"]["mpe"].update(radial=[-1, 0]), "must be >= 0"),
    (lambda d: d["tracker"]["mpe"].update(axial=[1, 0]), "axial"),
])
def test_vendor_specification_mistakes(edit, fragment):
    data = mutated(("tracker", "mpe"), {"radial": [0.010, 0.0003], "lateral": [0.015, 0.006]})
    data["robot"]["rp"] = 0.05
    edit(data)
    with pytest.raises(SceneError, match=fragment):
        scene_from_dict(data)
