"""A design written in controller joint values reads back as URDF joints through ``read_design_file``
and through the command line (the scene's ``controller:`` block)."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest
import yaml

from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.cli import EXIT_OK, main
from calib_oed.exceptions import MeasurementFileError
from calib_oed.io.design_file import read_design_file, write_design_csv
from calib_oed.io.measurement_reader import read_measurements
from calib_oed.scene.reader import scene_from_dict

FANUC = {"name": "fanuc", "angle": "deg",
         "joints": [{}, {"sign": -1}, {"sign": -1, "offset": 90}, {}, {"scale": 1.5}, {}],
         "couplings": [{"joint": 3, "from": 2, "ratio": 1.0}]}


@pytest.fixture(scope="module")
def fanuc_scene(tmp_path_factory):
    raw = yaml.safe_load((resources.files("calib_oed.scene.shipped") / "fms_kr16.yaml").read_text())
    raw["controller"] = FANUC
    path = tmp_path_factory.mktemp("scene") / "fanuc.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path, scene_from_dict(raw)


def test_read_design_file_round_trip(tmp_path, fanuc_scene):
    _, scene = fanuc_scene
    s = setup(scene)
    q = heuristic_design(s, 8, 0)
    conv = scene.controller
    path = write_design_csv(tmp_path / "design_controller.csv", scene.robot, q, angle_unit="deg", controller=conv)
    rows = [line for line in path.read_text().splitlines() if line and not line.startswith("#")]
    values = np.array([[float(v) for v in line.split(",")] for line in rows[1:]])
    assert not np.allclose(np.deg2rad(values), q, atol=1e-3)  # the file holds controller values
    np.testing.assert_allclose(read_design_file(path, scene.robot, controller=conv), q, atol=1e-12)
    with pytest.raises(MeasurementFileError, match="no controller convention is given"):
        read_design_file(path, scene.robot)


def test_cli_reads_a_controller_design_as_the_urdf_design(tmp_path, fanuc_scene):
    """``simulate`` at a design written in controller values measures the URDF poses it stands for."""
    path, scene = fanuc_scene
    q = heuristic_design(setup(scene), 12, 1)
    ctrl = write_design_csv(tmp_path / "design_controller.csv", scene.robot, q, angle_unit="deg",
                            controller=scene.controller)
    out = tmp_path / "m.csv"
    assert main(["simulate", str(path), str(ctrl), "-o", str(out), "--quiet"]) == EXIT_OK
    np.testing.assert_allclose(read_measurements(out, scene.robot).q, q, rtol=0, atol=1e-9)
