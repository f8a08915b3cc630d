"""Controller conventions: the map q = A c + b, its inverse, a FANUC J2/J3 example by hand,
the scene block and its errors (each naming the key)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

import calib_oed.scene.shipped
from calib_oed.exceptions import SceneError
from calib_oed.model.controller import controller_from_mapping
from calib_oed.scene.reader import scene_from_dict

FANUC = {"name": "fanuc", "angle": "deg",
         "joints": [{}, {}, {"sign": -1, "offset": 90}, {}, {"scale": 2.0}, {"sign": -1}],
         "couplings": [{"joint": 3, "from": 2, "ratio": 1.0}]}


def test_round_trip_random_blocks():
    rng = np.random.default_rng(3)
    for _ in range(20):
        block = {"angle": "deg",
                 "joints": [{"sign": int(rng.choice([-1, 1])), "offset": float(rng.uniform(-180, 180)),
                             "scale": float(rng.uniform(0.5, 2.0))} for _ in range(6)],
                 "couplings": [{"joint": 3, "from": 2, "ratio": float(rng.uniform(-1, 1))},
                               {"joint": 6, "from": 5, "ratio": float(rng.uniform(-1, 1))}]}
        conv = controller_from_mapping(block, 6)
        q = rng.uniform(-3, 3, size=(7, 6))
        np.testing.assert_allclose(conv.to_model(conv.to_controller(q)), q, atol=1e-12)
        c = rng.uniform(-3, 3, size=6)
        np.testing.assert_allclose(conv.to_controller(conv.to_model(c)), c, atol=1e-12)
        # the map is affine: q = A c + b with the documented A
        np.testing.assert_allclose(conv.to_model(c), conv.matrix @ c + conv.offset, atol=1e-12)


def test_fanuc_j2_j3_by_hand():
    """ROS-I fanuc_driver: J3_urdf = J3_ctrl + J23_factor * J2_ctrl (factor 1)."""
    plain = controller_from_mapping({"name": "fanuc", "couplings": [{"joint": 3, "from": 2}]}, 6)
    c = np.deg2rad([10.0, 30.0, -20.0, 0.0, 45.0, 0.0])
    np.testing.assert_allclose(np.rad2deg(plain.to_model(c)), [10, 30, 10, 0, 45, 0], atol=1e-12)
    # with sign -1 and offset 90 deg on joint 3, scale 2 on joint 5, sign -1 on joint 6:
    # q3 = -(c3 + c2) + 90 = -(-20 + 30) + 90 = 80 deg; q5 = 2 * 45 = 90 deg; q6 = -c6
    conv = controller_from_mapping(FANUC, 6)
    c = np.deg2rad([10.0, 30.0, -20.0, 0.0, 45.0, 7.0])
    np.testing.assert_allclose(np.rad2deg(conv.to_model(c)), [10, 30, 80, 0, 90, -7], atol=1e-12)
    np.testing.assert_allclose(np.rad2deg(conv.to_controller(np.deg2rad([10, 30, 80, 0, 90, -7]))),
                               [10, 30, -20, 0, 45, 7], atol=1e-12)
    assert "c3 -> c3 + 1*c2" in conv.describe() and "q3 = -1*c3 + 90 deg" in conv.describe()


@pytest.mark.parametrize(("block", "key"), [
    ({"joints": [{}] * 5}, "controller.joints"),
    ({"joints": [{}, {"sign": 2}, {}, {}, {}, {}]}, "controller.joints[2].sign"),
    ({"joints": [{}, {}, {"scale": 0}, {}, {}, {}]}, "controller.joints[3].scale"),
    ({"joints": [{}, {}, {}, {"offset": "x"}, {}, {}]}, "controller.joints[4].offset"),
    ({"joints": [{"gain": 1}, {}, {}, {}, {}, {}]}, "controller.joints[1]"),
    ({"angle": "grad"}, "controller.angle"),
    ({"colour": 1}, "controller"),
    ({"couplings": [{"joint": 7, "from": 2}]}, "controller.couplings[1].joint"),
    ({"couplings": [{"joint": 3, "from": 3}]}, "controller.couplings[1]"),
    ({"couplings": [{"joint": 3, "from": 2, "ratio": 2.0}, {"joint": 2, "from": 3, "ratio": 0.5}]},
     "controller.couplings"),
])
def test_bad_blocks_name_the_key(block, key):
    with pytest.raises(SceneError) as info:
        controller_from_mapping(block, 6)
    assert info.value.key == key


def test_scene_block_is_read():
    data = yaml.safe_load((Path(calib_oed.scene.shipped.__file__).parent / "fms_kr16.yaml").read_text())
    assert scene_from_dict(copy.deepcopy(data), check=False).controller is None
    data["controller"] = FANUC
    conv = scene_from_dict(data, check=False).controller
    assert conv.name == "fanuc" and conv.angle == "deg"
    np.testing.assert_allclose(conv.offset, np.deg2rad([0, 0, 90, 0, 0, 0]))
