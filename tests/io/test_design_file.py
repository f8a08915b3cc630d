"""Design files: exact round trips, any column order, every kind of bad input, atomic writes."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import ExportError, MeasurementFileError
from calib_oed.io.design_file import read_design_csv, write_design_csv

JOINTS = [f"joint_a{i}" for i in range(1, 7)]
ROW = "0.1,-1.2,1.5,0.0,0.3,-0.4"  # inside kr16's limits [rad]


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


def write_text(tmp_path, text: str, name: str = "design.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def problems_of(path, robot, **kwargs) -> list[tuple[int | None, str]]:
    """The ``(line, message)`` problems of a design file that must not be read."""
    with pytest.raises(MeasurementFileError) as info:
        read_design_csv(path, robot, **kwargs)
    assert info.value.source == str(path)
    assert "nothing was read" in str(info.value)
    return info.value.problems


# ----------------------------------------------------------------------------- round trips


def test_round_trip_is_exact(kr16, tmp_path):
    q = kr16.random_configurations(25, 4)
    q[0] = kr16.lower  # the limits themselves are inside
    q[1] = kr16.upper
    q[2] = [np.pi / 3, -1e-17, 1.0 / 3.0, 2.0**-40, -0.0, 123456789e-9]
    path = write_design_csv(tmp_path / "design.csv", kr16, q, comment="scene fms_kr16\nseed 4")
    assert path == tmp_path / "design.csv"
    back = read_design_csv(path, kr16)
    assert back.shape == (25, 6) and back.dtype == float
    np.testing.assert_array_equal(back, q)  # repr(float) round-trips bit for bit
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# calib_oed design v1")
    assert lines[1:4] == ["# units: angle=rad length=m", "# scene fms_kr16", "# seed 4"]
    assert lines[4] == ",".join(kr16.joint_names) == ",".join(JOINTS)


def test_a_single_configuration_is_one_row(kr16, tmp_path):
    q = np.array([0.1, -1.2, 1.5, 0.0, 0.3, -0.4])
    back = read_design_csv(write_design_csv(tmp_path / "one.csv", kr16, q), kr16)
    np.testing.assert_array_equal(back, q[None])


def test_columns_in_another_order_are_reordered(kr16, tmp_path):
    q = kr16.random_configurations(5, 1)
    order = [3, 0, 5, 1, 4, 2]
    header = ",".join(JOINTS[i] for i in order)
    rows = [",".join(repr(float(v)) for v in row[order]) for row in q]
    path = write_text(tmp_path, "\n".join([header, *rows]) + "\n")
    np.testing.assert_array_equal(read_design_csv(path, kr16), q)


def test_comments_and_blank_lines_are_ignored(kr16, tmp_path):
    text = "\n".join([
        "# a design written by hand",
        "",
        "   # an indented comment",
        ",".join(JOINTS),
        "# between rows",
        ROW,
        "",
        "0,0,0,0,0,0",
        "# the end",
    ])  # fmt: skip
    back = read_design_csv(write_text(tmp_path, text), kr16)
    np.testing.assert_array_equal(back, [[0.1, -1.2, 1.5, 0.0, 0.3, -0.4], [0.0] * 6])


def test_byte_order_mark_and_spaces_in_the_header(kr16, tmp_path):
    path = tmp_path / "bom.csv"
    path.write_bytes(("\ufeff" + ", ".join(JOINTS) + "\n" + ROW + "\n").encode("utf-8"))
    np.testing.assert_array_equal(read_design_csv(path, kr16), [[0.1, -1.2, 1.5, 0.0, 0.3, -0.4]])


# ----------------------------------------------------------------------------- header errors


def test_unknown_column(kr16, tmp_path):
    header = ",".join(JOINTS + ["gripper"])
    path = write_text(tmp_path, f"# comment\n{header}\n{ROW},0.0\n")
    problems = problems_of(path, kr16)
    assert len(problems) == 1
    line, message = problems[0]
    assert line == 2  # the header, after one comment line
    assert "unknown column(s) ['gripper']" in message and "joint_a1" in message


def test_missing_column(kr16, tmp_path):
    path = write_text(tmp_path, ",".join(JOINTS[:5]) + "\n0.1,-1.2,1.5,0.0,0.3\n")
    assert problems_of(path, kr16) == [(1, "missing joint column(s) ['joint_a6']")]


def test_duplicate_column(kr16, tmp_path):
    # all six joints, one of them twice
    path = write_text(tmp_path, ",".join([*JOINTS, "joint_a3"]) + f"\n{ROW},1.5\n")
    assert problems_of(path, kr16) == [(1, "duplicate column(s) ['joint_a3']")]
    # a duplicate in place of a joint: missing and duplicate, both on the header line
    header = ",".join(["joint_a1", "joint_a1", *JOINTS[2:]])
    problems = problems_of(write_text(tmp_path, f"\n\n{header}\n{ROW}\n", "dup2.csv"), kr16)
    assert problems == [
        (3, "missing joint column(s) ['joint_a2']"),
        (3, "duplicate column(s) ['joint_a1']"),
    ]


def test_empty_file_and_comments_only(kr16, tmp_path):
    for name, text in (("empty.csv", ""), ("comments.csv", "# nothing here\n\n# still nothing\n")):
        problems = problems_of(write_text(tmp_path, text, name), kr16)
        assert problems == [(None, "no header line with the joint names")]


def test_header_only(kr16, tmp_path):
    path = write_text(tmp_path, "# calib_oed design v1\n" + ",".join(JOINTS) + "\n# no rows\n")
    assert problems_of(path, kr16) == [(2, "no configurations after the header")]


def test_missing_file(kr16, tmp_path):
    problems = problems_of(tmp_path / "nowhere.csv", kr16)
    assert len(problems) == 1 and problems[0][0] is None
    assert "cannot read the design file" in problems[0][1]


# ----------------------------------------------------------------------------- row errors


def test_bad_rows_are_all_reported_with_their_line_numbers(kr16, tmp_path):
    text = "\n".join([
        "# calib_oed design v1",        # 1
        ",".join(JOINTS),               # 2
        ROW,                            # 3 good
        "0.1,-1.2,1.5,0.0,0.3",         # 4 five fields
        "0.1,-1.2,1.5,0.0,0.3,-0.4,0",  # 5 seven fields
        "# a comment keeps its line",   # 6
        "0.1,-1.2,abc,0.0,0.3,-0.4",    # 7 not a number
        "0.1,-1.2,,0.0,0.3,-0.4",       # 8 empty field
        "0.1,nan,1.5,0.0,0.3,-0.4",     # 9 NaN
        "0.1,-1.2,1.5,inf,0.3,-0.4",    # 10 infinite
        ROW,                            # 11 good
    ])  # fmt: skip
    problems = problems_of(write_text(tmp_path, text), kr16)
    assert problems == [
        (4, "5 fields, expected 6"),
        (5, "7 fields, expected 6"),
        (7, "a value is not a number"),
        (8, "a value is not a number"),
        (9, "NaN or infinite value"),
        (10, "NaN or infinite value"),
    ]


def test_out_of_limit_values(kr16, tmp_path):
    lo, hi = kr16.lower, kr16.upper
    over = np.array([0.1, -1.2, 1.5, 0.0, 0.3, -0.4])
    over[1] = hi[1] + 0.01  # joint_a2 above its upper limit
    both = over.copy()
    both[0] = lo[0] - 0.5  # and joint_a1 below its lower limit
    rows = [",".join(repr(float(v)) for v in r) for r in (over, both)]
    path = write_text(tmp_path, "\n".join([",".join(JOINTS), ROW, *rows]) + "\n")
    problems = problems_of(path, kr16)
    assert [line for line, _ in problems] == [3, 4, 4]
    assert problems[0][1].startswith("joint_a2 = ") and "outside the limits" in problems[0][1]
    assert problems[1][1].startswith("joint_a1 = ") and problems[2][1].startswith("joint_a2 = ")
    assert f"{hi[1]:.6g}" in problems[0][1]
    # without the check the values are read as written
    q = read_design_csv(path, kr16, check_limits=False)
    np.testing.assert_array_equal(q, [[0.1, -1.2, 1.5, 0.0, 0.3, -0.4], over, both])


def test_values_at_the_limits_are_inside(kr16, tmp_path):
    rows = [",".join(repr(float(v)) for v in r) for r in (kr16.lower, kr16.upper)]
    path = write_text(tmp_path, "\n".join([",".join(JOINTS), *rows]) + "\n")
    np.testing.assert_array_equal(read_design_csv(path, kr16), [kr16.lower, kr16.upper])


# ----------------------------------------------------------------------------- atomic writes


def test_write_to_a_missing_folder_leaves_nothing(kr16, tmp_path):
    target = tmp_path / "missing" / "design.csv"
    with pytest.raises(ExportError, match="does not exist"):
        write_design_csv(target, kr16, np.zeros((2, 6)))
    assert not target.parent.exists()
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_the_old_file_and_no_temporary(kr16, tmp_path, monkeypatch):
    import calib_oed.io.atomic as io_utils

    path = write_design_csv(tmp_path / "design.csv", kr16, np.zeros((1, 6)))
    before = path.read_bytes()

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(io_utils.os, "replace", broken_replace)
    from calib_oed.exceptions import ExportError

    with pytest.raises(ExportError, match="disk full"):  # the OS error, named with the file
        write_design_csv(path, kr16, np.ones((3, 6)))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["design.csv"]  # the temporary file is gone


def test_bad_configurations_are_not_written(kr16, tmp_path):
    from calib_oed.exceptions import NonFiniteError, ShapeError

    with pytest.raises(ShapeError):
        write_design_csv(tmp_path / "a.csv", kr16, np.zeros((2, 5)))
    with pytest.raises(NonFiniteError):
        write_design_csv(tmp_path / "b.csv", kr16, np.full((2, 6), np.nan))
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- units line


def test_a_design_in_degrees_reads_as_radians(kr16, tmp_path):
    q = kr16.random_configurations(5, 1)
    path = write_design_csv(tmp_path / "deg.csv", kr16, q, angle_unit="deg")
    assert "# units: angle=deg length=m" in path.read_text().splitlines()[1]
    np.testing.assert_allclose(read_design_csv(path, kr16), q, rtol=1e-14, atol=1e-15)
    by_hand = write_text(tmp_path, "# units: length=mm, angle = deg\n" + ",".join(JOINTS) + "\n10,-80,95,0,30,0\n")
    np.testing.assert_allclose(read_design_csv(by_hand, kr16)[0], np.radians([10, -80, 95, 0, 30, 0]), rtol=1e-15)


def test_without_a_units_line_a_design_is_in_radians(kr16, tmp_path):
    path = write_text(tmp_path, ",".join(JOINTS) + "\n" + ROW + "\n")
    np.testing.assert_array_equal(read_design_csv(path, kr16)[0], [float(v) for v in ROW.split(",")])
    (line, message), = problems_of(write_text(tmp_path, ",".join(JOINTS) + "\n0.1,-80,1.5,0,0.3,-0.4\n", "d.csv"), kr16)
    assert line == 2 and "joint_a2 = -80 rad outside" in message
    assert "no '# units:' line: read as rad and m; in degrees? add '# units: angle=deg'" in message


@pytest.mark.parametrize("units, fragment", [
    ("# units: angle=grad", "unknown angle unit 'grad'; valid angle units are 'rad', 'deg'"),
    ("# units: angle=deg angle=rad", "angle is given twice"),
    ("# units: degrees", "cannot read 'degrees'"),
])
def test_bad_units_lines(kr16, tmp_path, units, fragment):
    (line, message), = problems_of(write_text(tmp_path, f"{units}\n{','.join(JOINTS)}\n{ROW}\n"), kr16)
    assert line == 1 and fragment in message


def test_a_units_line_after_the_header_is_refused(kr16, tmp_path):
    text = f"{','.join(JOINTS)}\n# units: angle=deg\n{ROW}\n"
    (line, message), = problems_of(write_text(tmp_path, text), kr16)
    assert line == 2 and "before the column header" in message


def test_an_unknown_angle_unit_is_not_written(kr16, tmp_path):
    with pytest.raises(MeasurementFileError, match="valid angle units are 'rad', 'deg'"):
        write_design_csv(tmp_path / "d.csv", kr16, kr16.random_configurations(2, 0), angle_unit="grad")
    assert not (tmp_path / "d.csv").exists()


def test_repeated_rows_are_read_with_a_note(kr16, tmp_path):
    from calib_oed.exceptions import CalibOedNote

    path = write_text(tmp_path, "\n".join([",".join(JOINTS), ROW, "0,0,0,0,0,0", ROW, ROW]) + "\n")
    with pytest.warns(CalibOedNote, match=r"2 row\(s\) repeat an earlier row \(line 4 = line 2, line 5 = line 2\)"):
        assert read_design_csv(path, kr16).shape == (4, 6)
