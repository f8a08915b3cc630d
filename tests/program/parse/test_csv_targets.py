"""Target CSVs: the project's program CSV (both unit columns) and Cartesian targets."""

from __future__ import annotations

import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse import csv_targets
from tests.program.parse import samples

JOINTS = tuple(f"joint_a{i}" for i in range(1, 7))


def test_cartesian_targets():
    parsed = csv_targets.parse({"p.csv": samples.CSV_POSES}, JOINTS)
    assert [(t.name, t.kind, t.line) for t in parsed.targets] == [("a", "pose", 2), ("b", "pose", 3)]


def test_joint_columns_in_both_units_are_one_target():
    header = ",".join(["step"] + [f"{j}_deg" for j in JOINTS] + [f"{j}_rad" for j in JOINTS])
    text = header + "\n1," + ",".join(["10.0"] * 6 + ["0.17453"] * 6) + "\n"
    (target,) = csv_targets.parse({"p.csv": text}, JOINTS).targets
    assert target.unit == "rad+deg" and len(target.numbers) == 12 and target.values[0] == 0.17453
    edited = text.replace("1,10.0,10.0", "1,10.0,20.0")  # joint_a2_deg edited, its _rad not
    with pytest.raises(ProgramError, match=r"line 2: joint_a2_deg 20.0 and joint_a2_rad 0.17453 \(= 9.9998 deg\) disagree"):
        csv_targets.parse({"p.csv": edited}, JOINTS)


@pytest.mark.parametrize("text, message", [
    ("a,b\n1,2\n", "needs the columns"),
    ("name,x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg\na,1,2\n", "3 cells"),
    ("name,x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg\na,1,2,x,0,0,0\n", "not a number"),
])
def test_errors(text, message):
    with pytest.raises(ProgramError, match=message):
        csv_targets.parse({"p.csv": text}, JOINTS)
