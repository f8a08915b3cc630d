"""The scene's ``cell:`` obstacles (boxes, cylinders, spheres, meshes, ignore_links) and the
per-reflector ``normal``: values in SI, and errors naming the key and the valid choices."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from test_scene_reader import valid

from calib_oed.exceptions import SceneError
from calib_oed.scene.reader import scene_from_dict

#: An octahedron of half-diagonal 1 (file units), as OBJ text.
OCTA_OBJ = "\n".join(
    [f"v {x} {y} {z}" for x, y, z in np.vstack([np.eye(3), -np.eye(3)]).astype(int)]
    + ["f 1 2 3", "f 2 4 3", "f 4 5 3", "f 5 1 3", "f 2 1 6", "f 4 2 6", "f 5 4 6", "f 1 5 6"]
) + "\n"


def scene_with(cell=None, reflector=None, tmp_path=None):
    data = valid()
    if cell is not None:
        data["cell"] = cell
    if reflector is not None:
        data["reflectors"][0].update(reflector)
    return scene_from_dict(data, source=str(tmp_path / "scene.yaml") if tmp_path else "cell.yaml")


def test_obstacles_in_si(tmp_path):
    (tmp_path / "octa.obj").write_text(OCTA_OBJ)
    cell = scene_with({
        "boxes": [{"name": "car", "center": [2500, 0, 400], "size": [1000, 2000, 800], "rpy": [0, 0, 90],
                   "ignore_links": ["link_1"]}],
        "cylinders": [{"name": "column", "center": [-2000, 0, 1000], "radius": 150, "length": 2000}],
        "spheres": [{"name": "ball", "center": [0, 2500, 500], "radius": 100}],
        "meshes": [{"name": "fixture", "file": "octa.obj", "scale": [200, 100, 100], "xyz": [0, -2500, 300],
                    "rpy": [0, 0, 90]}],
        "halfspaces": [{"name": "floor", "z_min": -10, "ignore_links": ["base_link"]}],
    }, tmp_path=tmp_path).cell
    (box,), (cyl,), (mesh,) = cell.boxes, cell.cylinders, cell.meshes
    np.testing.assert_allclose(box.center, [2.5, 0.0, 0.4])
    np.testing.assert_allclose(box.size, [1.0, 2.0, 0.8])
    np.testing.assert_allclose(box.rotation, pin.rpy.rpyToMatrix(0, 0, np.pi / 2), atol=1e-15)
    assert box.ignore_links == ("link_1",)
    assert (cyl.radius, cyl.length) == pytest.approx((0.15, 2.0))
    ball = next(c for c in cell.capsules if c.name == "ball")
    np.testing.assert_allclose(ball.a, ball.b)
    assert ball.radius == pytest.approx(0.1)
    # x scaled by 200 mm, then turned 90 deg about z: the x extent becomes the y extent
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    np.testing.assert_allclose(lo, [-0.1, -2.7, 0.2], atol=1e-12)
    np.testing.assert_allclose(hi, [0.1, -2.3, 0.4], atol=1e-12)
    assert cell.halfspaces[0].ignore_links == ("base_link",)
    assert [s.name for s in cell.solids] == ["car", "column", "fixture"]


def test_reflector_normal_is_normalised():
    scene = scene_with(reflector={"normal": [0, 3, 4]})
    np.testing.assert_allclose(scene.reflectors[0].normal, [0, 0.6, 0.8])
    np.testing.assert_allclose(scene_with().reflectors[0].normal, [0, 0, 1])


@pytest.mark.parametrize("cell, key, text", [
    ({"boxes": [{"name": "b", "center": [0, 0, 0], "size": [1, 0, 1]}]}, "cell.boxes[0].size", "> 0"),
    ({"boxes": [{"name": "b", "center": [0, 0, 0]}]}, "cell.boxes[0].size", "requires: name, center, size"),
    ({"boxes": [{"name": "b", "center": [0, 0, 0], "size": [1, 1, 1], "ignore_links": ["wing"]}]},
     "cell.boxes[0].ignore_links[0]", "link_1"),
    ({"halfspaces": [{"name": "f", "z_min": 0, "ignore_links": "base_link"}]}, "cell.halfspaces[0].ignore_links",
     "list of link names"),
    ({"spheres": [{"name": "s", "center": [0, 0, 0], "radius": -1}]}, "cell.spheres[0].radius", ">"),
    ({"cylinders": [{"name": "c", "center": [0, 0, 0], "radius": 1, "length": 1, "size": 1}]},
     "cell.cylinders[0].size", "rpy"),
    ({"meshes": [{"name": "m", "file": "missing.stl"}]}, "cell.meshes[0].file", "not found"),
    ({"boxes": [{"name": "x", "center": [0, 0, 0], "size": [1, 1, 1]}],
      "spheres": [{"name": "x", "center": [0, 0, 0], "radius": 1}]}, "cell.spheres[0].name", "duplicate"),
    ({"walls": []}, "cell.walls", "boxes"),
])
def test_invalid_obstacles(cell, key, text):
    with pytest.raises(SceneError) as err:
        scene_with(cell)
    message = str(err.value)
    assert f"{key}:" in message and text in message, message


def test_invalid_reflector_normal():
    with pytest.raises(SceneError, match=r"reflectors\[0\]\.normal: must be non-zero"):
        scene_with(reflector={"normal": [0, 0, 0]})


def test_flat_mesh_is_an_error(tmp_path):
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n")
    with pytest.raises(SceneError, match=r"cell\.meshes\[0\]\.file: .*flat"):
        scene_with({"meshes": [{"name": "m", "file": "flat.obj"}]}, tmp_path=tmp_path)



def test_link_fit_setting_is_read_and_validated():
    data = valid()
    assert scene_from_dict(data, check=False).feasibility.link_fit == "hulls"  # the default
    data["feasibility"] = {"link_fit": "single"}
    assert scene_from_dict(data, check=False).feasibility.link_fit == "single"
    data["feasibility"] = {"link_fit": "several"}
    with pytest.raises(SceneError, match=r"feasibility\.link_fit.*single.*hulls"):
        scene_from_dict(data, check=False)
