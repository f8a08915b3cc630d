"""Measurement files: round trips, units, every kind of bad input, observation blocks."""

from __future__ import annotations

import io

import numpy as np
import pinocchio as pin
import pytest
from conftest import make_space

from calib_oed import load_robot
from calib_oed.exceptions import (
    ExportError,
    MeasurementFileError,
    NonFiniteError,
    ShapeError,
    UnknownJointError,
)
from calib_oed.io.measurement_reader import read_measurements
from calib_oed.io.measurement_writer import write_measurements
from calib_oed.measurement import PoseMeasurement, TrackerPosition, evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet

KR16_JOINTS = ",".join(f"joint_a{i}" for i in range(1, 7))
UNITS = "# units: length=mm angle=deg"
GOOD = "10.0,-80.0,95.0,0.0,30.0,0.0,smr0,1234.5678,-210.25,455.0"


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5")


def kr16_text(*rows: str, header: str = f"{KR16_JOINTS},reflector,x,y,z", units: str = UNITS):
    """Units on line 1, the header on line 2, ``rows`` from line 3 on."""
    return "\n".join([units, header, *rows]) + "\n"


def read_text(text, robot, **kwargs):
    return read_measurements(io.StringIO(text), robot, **kwargs)


def problems_of(text, robot, **kwargs) -> list[tuple[int | None, str]]:
    with pytest.raises(MeasurementFileError) as info:
        read_text(text, robot, **kwargs)
    assert info.value.source == "<string>"
    assert "nothing was read" in str(info.value)
    return info.value.problems


def lines_of(problems) -> list[int | None]:
    return [line for line, _ in problems]


def simulated(robot, n=7, seed=3, pose=False, sigma=True):
    """A set at random configurations with two reflectors, positions from the nominal model."""
    space = make_space(robot)
    q = robot.random_configurations(n, seed)
    reflector = np.arange(n) % 2
    state = evaluate_setup(space, None, q)
    model = PoseMeasurement if pose else TrackerPosition
    values = [model(j).compute_values(state) for j in (0, 1)]
    values = np.where(reflector[:, None] == 0, values[0], values[1])
    rng = np.random.default_rng(seed)
    return space, MeasurementSet.from_arrays(
        robot, q, values[:, :3], reflector=reflector,
        sigma=rng.uniform(5e-6, 2e-5, n) if sigma else None,
        rotations=values[:, 3:] if pose else None,
    )


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("units", [("mm", "deg"), ("m", "rad")])
@pytest.mark.parametrize("name", ["kr16", "ur5"])
@pytest.mark.parametrize("pose", [False, True])
def test_round_trip_is_exact(tmp_path, name, units, pose):
    robot = load_robot(name)
    _, mset = simulated(robot, pose=pose)
    path = tmp_path / "session.csv"
    written = write_measurements(path, mset, robot, ("smr0", "smr1"),
                                 length_unit=units[0], angle_unit=units[1], comment="cell 4\nday 2")
    assert written == path and [p.name for p in tmp_path.iterdir()] == ["session.csv"]
    back = read_measurements(path, robot, ("smr0", "smr1"))
    text = path.read_text().splitlines()
    assert text[:5] == ["# calib_oed measurements v1",
                        f"# units: length={units[0]} angle={units[1]}",
                        f"# robot: {name}", "# cell 4", "# day 2"]
    for attr in ("q", "positions", "sigma", "rotations"):
        want, got = getattr(mset, attr), getattr(back, attr)
        if want is None:
            assert got is None
            continue
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    np.testing.assert_array_equal(back.reflector, mset.reflector)
    np.testing.assert_array_equal(back.lines, np.arange(7) + 7)  # 5 comments and the header
    assert back.source == str(path) and back.joint_names == robot.joint_names


def test_write_accepts_arrays_and_reflector_defaults(tmp_path, kr16):
    q = np.radians([[10, -80, 95, 0, 30, 0], [0, -90, 90, 0, 0, 0]])
    path = write_measurements(tmp_path / "a.csv", {"q": q, "positions": np.ones((2, 3))}, kr16)
    back = read_measurements(path, kr16)
    assert back.sigma is None and back.rotations is None
    np.testing.assert_array_equal(back.reflector, [0, 0])
    np.testing.assert_allclose(back.q, q, rtol=1e-15)
    assert ",smr0," in path.read_text()


def test_arrays_are_read_only(kr16):
    mset = read_text(kr16_text(GOOD), kr16)
    for arr in (mset.q, mset.reflector, mset.positions, mset.lines):
        with pytest.raises(ValueError):
            arr[0] = 1


# ----------------------------------------------------------------------------- reading


def test_stringio_and_values_in_si(kr16):
    mset = read_text(kr16_text(GOOD, GOOD.replace("smr0", "0")), kr16)
    assert mset.n == 2 and mset.source == "<string>"
    np.testing.assert_allclose(mset.q[0], np.radians([10, -80, 95, 0, 30, 0]), rtol=1e-15)
    np.testing.assert_allclose(mset.positions[1], [1.2345678, -0.21025, 0.455], rtol=1e-15)
    np.testing.assert_array_equal(mset.reflector, [0, 0])
    np.testing.assert_array_equal(mset.lines, [3, 4])
    assert mset.sigma is None and mset.rotations is None


def test_columns_in_any_order_and_no_reflector_column(kr16):
    text = "\n".join([UNITS, "z,y,x,joint_a6,joint_a5,joint_a4,joint_a3,joint_a2,joint_a1",
                      "3,2,1,6,5,4,3,2,1"])
    mset = read_text(text, kr16)
    np.testing.assert_allclose(mset.q[0], np.radians([1, 2, 3, 4, 5, 6]), rtol=1e-15)
    np.testing.assert_allclose(mset.positions[0], [1e-3, 2e-3, 3e-3], rtol=1e-15)
    np.testing.assert_array_equal(mset.reflector, [0])


def test_crlf_bom_spaces_and_comments(kr16):
    text = "\ufeff# a note\r\n" + UNITS + "\r\n\r\n" + " joint_a1 , joint_a2,joint_a3,joint_a4," \
        "joint_a5,joint_a6 , x,y,z\r\n# between rows\r\n 1 ,2,3,4,5,6, 7,8,9\r\n"
    mset = read_text(text, kr16)
    np.testing.assert_array_equal(mset.lines, [6])


def test_units_from_flags_equal_units_from_header(kr16):
    from_header = read_text(kr16_text(GOOD), kr16)
    from_flags = read_text(kr16_text(GOOD, units="# no units here"), kr16,
                           length_unit="mm", angle_unit="deg")
    np.testing.assert_array_equal(from_flags.q, from_header.q)
    np.testing.assert_array_equal(from_flags.positions, from_header.positions)
    spaced = read_text(kr16_text(GOOD, units="#Units: length = mm, angle= deg"), kr16)
    np.testing.assert_array_equal(spaced.q, from_header.q)


def test_a_flag_that_contradicts_the_units_line_is_a_problem(kr16):
    text = kr16_text("1,0,0,0,0,0,smr0,1,2,3", units="# units: length=m angle=rad")
    problems = problems_of(text, kr16, length_unit="mm", angle_unit="deg")
    assert len(problems) == 2 and all(line == 1 for line, _ in problems)
    assert "--length-unit mm (length_unit='mm') contradicts" in problems[0][1] and "length=m)" in problems[0][1]
    assert "--angle-unit deg (angle_unit='deg') contradicts" in problems[1][1]
    # a flag that agrees with the line changes nothing
    same = read_text(text, kr16, length_unit="m", angle_unit="rad")
    np.testing.assert_array_equal(same.positions, read_text(text, kr16).positions)


def test_flag_supplies_what_the_units_line_leaves_out(kr16):
    mset = read_text(kr16_text(GOOD, units="# units: length=mm"), kr16, angle_unit="deg")
    np.testing.assert_allclose(mset.q[0, 0], np.radians(10), rtol=1e-15)
    (problem,) = problems_of(kr16_text(GOOD, units="# units: length=mm"), kr16)
    assert problem[0] is None and "angle unit is not given" in problem[1]
    assert "(line 1)" in problem[1] and "'rad', 'deg'" in problem[1]


def test_missing_units(kr16):
    (problem,) = problems_of(kr16_text(GOOD, units="# measured on Monday"), kr16)
    line, message = problem
    assert line is None
    assert "length and angle units are not given" in message
    assert "# units: length=mm angle=deg" in message
    assert "length_unit=" in message and "angle_unit=" in message
    assert "--length-unit and --angle-unit on the command line" in message
    assert "'m', 'mm'" in message and "'rad', 'deg'" in message


def test_bad_units(kr16):
    problems = problems_of(kr16_text(GOOD, units="# units: length=cm angle=deg"), kr16)
    assert lines_of(problems) == [1] and "'m', 'mm'" in problems[0][1]
    problems = problems_of(kr16_text(GOOD), kr16, length_unit="inch")
    assert lines_of(problems) == [None] and "length_unit='inch'" in problems[0][1]
    problems = problems_of(UNITS + "\n" + kr16_text(GOOD), kr16)
    assert lines_of(problems) == [2] and "second '# units:' line" in problems[0][1]


# ----------------------------------------------------------------------------- bad input


def test_nan_names_line_and_joint(kr16):
    text = kr16_text(GOOD, "10.0,nan,95.0,0.0,30.0,0.0,smr0,1,2,3")
    (problem,) = problems_of(text, kr16)
    assert problem[0] == 4 and "joint_a2 is NaN" in problem[1]
    (problem,) = problems_of(kr16_text(GOOD.replace("455.0", "inf")), kr16)
    assert problem[0] == 3 and "z is infinite" in problem[1]


def test_wrong_number_of_fields(kr16):
    short = "10.0,-80.0,95.0,0.0,30.0,smr0,1,2,3"
    problems = problems_of(kr16_text(GOOD, short, GOOD + ",7"), kr16)
    assert lines_of(problems) == [4, 5]
    assert "expected 10 comma-separated fields" in problems[0][1] and "got 9" in problems[0][1]
    assert "got 11" in problems[1][1] and "(line 2)" in problems[1][1]


def test_unknown_joint_name(kr16):
    header = f"{KR16_JOINTS.replace('joint_a3', 'joint_a7')},reflector,x,y,z"
    problems = problems_of(kr16_text(GOOD, header=header), kr16)
    assert lines_of(problems) == [2, 2]
    assert "unknown column 'joint_a7'" in problems[0][1]
    assert "valid columns are: joint_a1, joint_a2, joint_a3" in problems[0][1]
    assert "missing joint column(s) 'joint_a3'" in problems[1][1]


def test_ur5_misspelt_joint_gets_a_hint(ur5):
    header = "shoulder_pan,shoulder_lift_joint,elbow_joint,wrist_1_joint,wrist_2_joint," \
        "wrist_3_joint,x,y,z"
    problems = problems_of(kr16_text("0,0,0,0,0,0,1,2,3", header=header), ur5)
    assert "unknown column 'shoulder_pan' (did you mean 'shoulder_pan_joint'?)" in problems[0][1]
    assert "missing joint column(s) 'shoulder_pan_joint'" in problems[1][1]


def test_missing_joint_and_position_columns(kr16):
    header = "joint_a1,joint_a2,joint_a4,joint_a5,joint_a6,reflector,x,y,rx"
    problems = problems_of(kr16_text("1,2,4,5,6,smr0,1,2,0", header=header), kr16)
    assert lines_of(problems) == [2, 2, 2]
    messages = " | ".join(m for _, m in problems)
    assert "missing joint column(s) 'joint_a3'" in messages
    assert "missing column(s) z" in messages
    assert "missing column(s) ry, rz: give all of rx, ry, rz or none of them" in messages


def test_duplicate_header_column(kr16):
    header = f"{KR16_JOINTS},reflector,x,y,z,joint_a2"
    (problem,) = problems_of(kr16_text(GOOD + ",1", header=header), kr16)
    assert problem == (2, "duplicate column 'joint_a2' (columns 2 and 11)")


def test_unknown_extra_column(kr16):
    (problem,) = problems_of(kr16_text(GOOD + ",21.5", header=f"{KR16_JOINTS},reflector,x,y,z,"
                                       "temperature"), kr16)
    assert problem[0] == 2 and "unknown column 'temperature'" in problem[1]
    assert "reflector, x, y, z, rx, ry, rz, sigma" in problem[1]


def test_semicolons_get_a_hint(kr16):
    problems = problems_of(kr16_text(header=KR16_JOINTS.replace(",", ";") + ";x;y;z"), kr16)
    assert "fields must be separated by commas" in problems[0][1]


def test_out_of_limit_joint(kr16):
    row = "10.0,40.0,95.0,0.0,30.0,0.0,smr0,1,2,3"
    (problem,) = problems_of(kr16_text(GOOD, row), kr16)
    assert problem == (4, "joint_a2 = 40 deg is outside its limits [-155, 35] deg")
    (problem,) = problems_of(kr16_text("0.1,0.7,0.2,0,0.3,0,smr0,1,2,3",
                                       units="# units: length=m angle=rad"), kr16)
    assert problem[0] == 3 and "joint_a2 = 0.7 rad is outside its limits [-2.70526, 0.610865] rad" \
        == problem[1]
    assert read_text(kr16_text(GOOD, row), kr16, check_limits=False).n == 2
    at_limit = read_text(kr16_text(row.replace("40.0", "35")), kr16)  # rounding tolerated
    assert at_limit.q[0, 1] == pytest.approx(kr16.upper[1], abs=1e-12)


def test_unknown_reflector(kr16):
    text = kr16_text(GOOD, GOOD.replace("smr0", "smr2"), GOOD.replace("smr0", "2"),
                     GOOD.replace("smr0", "-1"))
    problems = problems_of(text, kr16, reflector_names=("smr0", "smr1"))
    assert lines_of(problems) == [4, 5, 6]
    assert "unknown reflector 'smr2'; valid reflectors are 'smr0', 'smr1' or their indices 0..1" \
        == problems[0][1]


def test_non_positive_sigma(kr16):
    header = f"{KR16_JOINTS},reflector,x,y,z,sigma"
    problems = problems_of(kr16_text(GOOD + ",0.01", GOOD + ",0", GOOD + ",-0.01", header=header),
                           kr16)
    assert problems == [(4, "sigma = 0 mm must be > 0"), (5, "sigma = -0.01 mm must be > 0")]


def test_unparsable_number(kr16):
    (problem,) = problems_of(kr16_text(GOOD, GOOD.replace("1234.5678", "1,234.5678")), kr16)
    assert problem[0] == 4 and "got 11" in problem[1]
    (problem,) = problems_of(kr16_text(GOOD, GOOD.replace("0.0,smr0", "smr0,0.0")), kr16)
    assert problem == (4, "joint_a6 is not a number: 'smr0'; unknown reflector '0.0'; "
                          "valid reflectors are 'smr0' or their index 0")
    (problem,) = problems_of(kr16_text(GOOD.replace("30.0", "3O.0"), GOOD), kr16)
    assert problem == (3, "joint_a5 is not a number: '3O.0'")


def test_empty_field(kr16):
    problems = problems_of(kr16_text(GOOD, GOOD.replace("30.0", "")), kr16)
    assert problems == [(4, "joint_a5 is empty")]


@pytest.mark.parametrize("text", ["", "\n\n", "# only\n# comments\n" + UNITS + "\n"])
def test_empty_file(kr16, text):
    (problem,) = problems_of(text, kr16)
    assert problem[0] is None and "no column header and no data rows" in problem[1]


def test_header_without_data_rows(kr16):
    assert problems_of(kr16_text() + "# the end\n", kr16) == [
        (2, "no data rows after the column header")]


def test_data_row_instead_of_header(kr16):
    (problem,) = problems_of(UNITS + "\n" + GOOD.replace("smr0", "0") + "\n", kr16)
    assert problem[0] == 2 and "expected the column header, got a row of numbers" in problem[1]


def test_directives(kr16):
    problems = problems_of("# calib_oed measurements v2\n" + kr16_text(GOOD) + UNITS + "\n", kr16)
    assert lines_of(problems) == [1, 5]
    assert "unsupported format version 'v2'" in problems[0][1]
    assert "must come before the column header (line 3)" in problems[1][1]
    assert read_text("# CALIB_OED measurements v1\n# robot: KR16\n" + kr16_text(GOOD), kr16).n == 1
    (problem,) = problems_of("# robot: other\n" + kr16_text(GOOD), kr16)  # a file of another robot
    assert problem[0] == 1 and "the file is of robot 'other', the scene's robot is 'kr16'" in problem[1]


def test_rotation_vector_beyond_pi(kr16):
    header = f"{KR16_JOINTS},reflector,x,y,z,rx,ry,rz"
    (problem,) = problems_of(kr16_text(GOOD + ",0,0,180", GOOD + ",0,0,190", header=header), kr16)
    assert problem[0] == 4 and "norm 190 deg > 180 deg" in problem[1]


def test_all_problems_reported_together(kr16):
    header = f"{KR16_JOINTS},reflector,x,y,z,sigma,colour"
    rows = [GOOD + ",0.01,red",                                     # line 3: fine
            "10.0,nan,95.0,0.0,30.0,0.0,smr0,1,2,3,0.01,red",       # 4: NaN
            GOOD + ",0.01",                                         # 5: field count
            "10.0,40.0,95.0,0.0,30.0,0.0,smrX,1,2,3,-1,red",        # 6: limit, reflector, sigma
            GOOD + ",0.01,red",                                     # 7: fine
            GOOD.replace("455.0", "x") + ",0.01,red"]               # 8: number
    problems = problems_of(kr16_text(*rows, header=header), kr16)
    assert lines_of(problems) == [2, 4, 5, 6, 8]
    assert "unknown column 'colour'" in problems[0][1]
    assert "joint_a2 is NaN" in problems[1][1]
    assert "joint_a2 = 40 deg" in problems[3][1] and "'smrX'" in problems[3][1]
    assert "sigma = -1 mm" in problems[3][1]
    with pytest.raises(MeasurementFileError, match=r"5 problem\(s\)(.|\n)*line 8: z is not a num"):
        read_text(kr16_text(*rows, header=header), kr16)


def test_unreadable_path(tmp_path, kr16):
    with pytest.raises(MeasurementFileError, match="cannot read the measurement file") as info:
        read_measurements(tmp_path / "missing.csv", kr16)
    assert info.value.problems[0][0] is None


def test_prismatic_joint_takes_the_length_unit(tmp_path):
    urdf = tmp_path / "rp.urdf"
    link = '<link name="{}"/>'
    joint = ('<joint name="{0}" type="{1}"><parent link="{2}"/><child link="{3}"/>'
             '<origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>'
             '<limit lower="{4}" upper="{5}" effort="1" velocity="1"/></joint>')
    urdf.write_text('<robot name="rp">' + "".join(link.format(n) for n in ("base", "l1", "tool0"))
                    + joint.format("turn", "revolute", "base", "l1", -3, 3)
                    + joint.format("slide", "prismatic", "l1", "tool0", 0, 0.5) + "</robot>")
    robot = load_robot(urdf)
    mset = read_text(f"{UNITS}\nslide,turn,x,y,z\n250,90,1,2,3\n", robot)
    np.testing.assert_allclose(mset.q[0], [np.pi / 2, 0.25], rtol=1e-15)
    (problem,) = problems_of(f"{UNITS}\nslide,turn,x,y,z\n600,90,1,2,3\n", robot)
    assert problem == (3, "slide = 600 mm is outside its limits [0, 500] mm")
    path = write_measurements(tmp_path / "rp.csv", mset, robot)
    assert "90.0,250.0" in path.read_text()


# ----------------------------------------------------------------------------- records and writing


def test_from_arrays_validates(kr16):
    q = np.zeros((2, 6))
    with pytest.raises(ShapeError):
        MeasurementSet.from_arrays(kr16, np.zeros((2, 5)), np.zeros((2, 3)))
    with pytest.raises(ShapeError):
        MeasurementSet.from_arrays(kr16, q, np.zeros((3, 3)))
    with pytest.raises(NonFiniteError):
        MeasurementSet.from_arrays(kr16, q, [[0, np.nan, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match="sigma"):
        MeasurementSet.from_arrays(kr16, q, np.zeros((2, 3)), sigma=[1e-5, 0])
    with pytest.raises(ValueError, match="reflector"):
        MeasurementSet.from_arrays(kr16, q, np.zeros((2, 3)), reflector=[0, -1])
    mset = MeasurementSet.from_arrays(kr16, q[0], [1, 2, 3], sigma=1e-5)
    assert mset.n == 1 and mset.sigma.tolist() == [1e-5] and mset.lines.tolist() == [1]


def test_write_errors(tmp_path, kr16, ur5):
    mset = read_text(kr16_text(GOOD), kr16)
    with pytest.raises(ExportError, match="'m', 'mm'"):
        write_measurements(tmp_path / "a.csv", mset, kr16, length_unit="cm")
    with pytest.raises(ExportError, match="reflector index 1 has no name"):
        write_measurements(tmp_path / "a.csv", {"q": np.zeros(6), "positions": np.zeros(3),
                                                "reflector": 1}, kr16)
    with pytest.raises(UnknownJointError, match="joint_a1"):
        write_measurements(tmp_path / "a.csv", mset, ur5)
    with pytest.raises(ExportError, match="directive"):
        write_measurements(tmp_path / "a.csv", mset, kr16, comment="ok\nunits: length=m")
    with pytest.raises(ExportError, match="does not exist"):
        write_measurements(tmp_path / "no" / "a.csv", mset, kr16)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- blocks


def test_blocks_group_by_reflector_with_row_sigma(kr16):
    header = f"{KR16_JOINTS},reflector,x,y,z,sigma"
    rows = [GOOD.replace("smr0", r).replace("1234.5678", str(k)) + f",{s}"
            for k, (r, s) in enumerate([("smr1", 0.02), ("smr0", 0.01), ("1", 0.03)])]
    mset = read_text(kr16_text(*rows, header=header), kr16, reflector_names=("smr0", "smr1"))
    assert mset.reflectors == (0, 1)
    b0, b1 = mset.blocks(sigma=1e-5)
    assert isinstance(b0.model, TrackerPosition) and isinstance(b1.model, TrackerPosition)
    assert (b0.model.reflector, b1.model.reflector) == (0, 1)
    assert b0.values.shape == (1, 3) and b1.values.shape == (2, 3) and b1.q.shape == (2, 6)
    np.testing.assert_allclose(b1.values[:, 0], [0, 2e-3], atol=1e-15)    # file order kept
    np.testing.assert_allclose(b1.sigma, [[2e-5] * 3, [3e-5] * 3], rtol=1e-15)
    np.testing.assert_allclose(b0.sigma, [[1e-5] * 3], rtol=1e-15)
    np.testing.assert_array_equal(mset.lines[mset.reflector == 1], [3, 5])


def test_blocks_without_row_sigma_use_the_model(kr16):
    (block,) = read_text(kr16_text(GOOD, GOOD), kr16).blocks(sigma=(1e-5, 2e-5, 3e-5))
    np.testing.assert_array_equal(block.sigma, [[1e-5, 2e-5, 3e-5]] * 2)


def test_pose_rows_give_pose_blocks(kr16):
    header = f"{KR16_JOINTS},reflector,x,y,z,rx,ry,rz,sigma"
    mset = read_text(kr16_text(GOOD + ",10,0,0,0.02", GOOD + ",0,-5,0,0.01", header=header), kr16)
    (block,) = mset.blocks(sigma=1e-5, sigma_angle=2e-5)
    assert isinstance(block.model, PoseMeasurement) and block.values.shape == (2, 6)
    np.testing.assert_allclose(block.values[:, 3:], np.radians([[10, 0, 0], [0, -5, 0]]),
                               rtol=1e-15)
    np.testing.assert_allclose(block.sigma, [[2e-5] * 3 + [2e-5] * 3, [1e-5] * 3 + [2e-5] * 3],
                               rtol=1e-15)


@pytest.mark.parametrize("name", ["kr16", "ur5"])
@pytest.mark.parametrize("pose", [False, True])
def test_file_values_match_the_model(tmp_path, name, pose):
    """Simulated session: model values written in mm/deg read back as the model's values."""
    robot = load_robot(name)
    space, mset = simulated(robot, n=9, seed=5, pose=pose)
    path = write_measurements(tmp_path / "sim.csv", mset, robot, ("front", "side"))
    blocks = read_measurements(path, robot, ("front", "side")).blocks()
    assert [b.model.reflector for b in blocks] == [0, 1] and sum(b.n for b in blocks) == 9
    for block in blocks:
        model = type(block.model)(block.model.reflector)
        expected = model.compute_values(evaluate_setup(space, None, block.q))
        assert np.abs(block.values - expected).max() < 1e-12
        if pose:
            rot = pin.exp3(block.values[0, 3:])
            assert np.allclose(rot.T @ rot, np.eye(3))


def test_rows_identical_to_an_earlier_row_are_a_note(kr16):
    """A copied line (same configuration, reflector and measured values) is read, with a note;
    the same configuration measured again (other values) is a repeated measurement, no note."""
    from calib_oed.exceptions import CalibOedNote

    again = GOOD.replace("1234.5678", "1234.5679")
    with pytest.warns(CalibOedNote, match=r"<string>: 2 row\(s\) identical to an earlier row.*line 5 = line 3, "
                                          r"line 6 = line 3"):
        mset = read_text(kr16_text(GOOD, again, GOOD, GOOD), kr16)
    assert mset.n == 4
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", CalibOedNote)
        assert read_text(kr16_text(GOOD, again), kr16).n == 2
