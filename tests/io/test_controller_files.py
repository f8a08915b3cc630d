"""Measurement and design files in controller joint values (``# joints: controller <name>``)
read back to the same URDF joint values; the directive without a convention is an error."""

from __future__ import annotations

import io

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import MeasurementFileError
from calib_oed.io.design_file import read_design_csv, write_design_csv
from calib_oed.io.measurement_reader import read_measurements
from calib_oed.io.measurement_writer import write_measurements
from calib_oed.model.controller import controller_from_mapping

FANUC = {"name": "fanuc", "angle": "deg",
         "joints": [{}, {"sign": -1}, {"sign": -1, "offset": 90}, {}, {"scale": 1.5}, {}],
         "couplings": [{"joint": 3, "from": 2, "ratio": 1.0}]}


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


@pytest.fixture(scope="module")
def conv():
    return controller_from_mapping(FANUC, 6)


@pytest.fixture(scope="module")
def data(kr16):
    rng = np.random.default_rng(11)
    q = kr16.lower + (kr16.upper - kr16.lower) * rng.uniform(0.1, 0.9, size=(8, 6))
    return {"q": q, "positions": rng.uniform(-2, 2, size=(8, 3))}


def test_measurement_file_in_controller_values_reads_as_urdf_file(tmp_path, kr16, conv, data):
    urdf = read_measurements(write_measurements(tmp_path / "urdf.csv", data, kr16), kr16)
    path = write_measurements(tmp_path / "ctrl.csv", data, kr16, controller=conv)
    text = path.read_text()
    assert "# joints: controller fanuc" in text
    # the joint columns are the controller's values, in degrees
    first = np.array([float(v) for v in text.splitlines()[6].split(",")[:6]])
    np.testing.assert_allclose(np.deg2rad(first), conv.to_controller(data["q"][0]), atol=1e-12)
    assert not np.allclose(np.deg2rad(first), data["q"][0], atol=1e-3)
    ctrl = read_measurements(path, kr16, controller=conv)
    np.testing.assert_allclose(ctrl.q, urdf.q, atol=1e-12)
    np.testing.assert_allclose(ctrl.positions, urdf.positions, atol=1e-15)


def test_controller_file_limits_are_checked_on_urdf_values(kr16, conv):
    # controller J2 = -10, J3 = -80 deg: q2 = 10 deg (in limits) and
    # q3 = -(J3 + J2) + 90 = -(-90) + 90 = 180 deg, outside kr16's A3 limits [-130, 154] deg
    text = ("# units: length=mm angle=deg\n# joints: controller fanuc\n"
            "joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6,x,y,z\n"
            "0,-10,-80,0,20,0,1,2,3\n")
    with pytest.raises(MeasurementFileError) as info:
        read_measurements(io.StringIO(text), kr16, controller=conv)
    assert info.value.problems[0][0] == 4
    assert "joint_a3 = 180 deg (URDF value, from the controller values)" in info.value.problems[0][1]


@pytest.mark.parametrize(("line", "needs"), [
    ("# joints: controller fanuc", "no controller convention is given"),
    ("# joints: controller kuka", "'kuka'"),
    ("# joints: motor", "expected 'urdf' or"),
])
def test_joints_directive_errors(kr16, conv, line, needs):
    text = (f"# units: length=mm angle=deg\n{line}\n"
            "joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6,x,y,z\n0,0,0,0,20,0,1,2,3\n")
    given = None if "no controller" in needs else conv
    with pytest.raises(MeasurementFileError) as info:
        read_measurements(io.StringIO(text), kr16, controller=given)
    assert info.value.problems[0][0] == 2 and needs in info.value.problems[0][1]


def test_urdf_directive_and_no_directive_ignore_the_convention(kr16, conv):
    rows = "joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6,x,y,z\n0,-90,90,0,20,0,1,2,3\n"
    for head in ("# units: length=mm angle=deg\n# joints: urdf\n", "# units: length=mm angle=deg\n"):
        mset = read_measurements(io.StringIO(head + rows), kr16, controller=conv)
        np.testing.assert_allclose(np.rad2deg(mset.q[0]), [0, -90, 90, 0, 20, 0], atol=1e-12)


def test_design_csv_in_controller_degrees_round_trips(tmp_path, kr16, conv, data):
    path = write_design_csv(tmp_path / "d.csv", kr16, data["q"], angle_unit="deg", controller=conv)
    text = path.read_text().splitlines()
    assert text[1] == "# units: angle=deg length=m" and text[2] == "# joints: controller fanuc"
    assert text[3].startswith("# controller fanuc (q = A c + b:")
    values = np.array([[float(v) for v in line.split(",")] for line in text[5:]])
    np.testing.assert_allclose(np.deg2rad(values), conv.to_controller(data["q"]), atol=1e-12)
    np.testing.assert_allclose(read_design_csv(path, kr16, controller=conv), data["q"], atol=1e-12)
    with pytest.raises(MeasurementFileError, match="no controller convention is given"):
        read_design_csv(path, kr16)
