"""Tracker exports (issue 34): a headerless pose array with the SMRs of a pose side by side,
a point export with U95, air sensor and time stamp (comma and semicolon/decimal-comma
flavours), a 6-DoF probe's quaternion; each imported and identified without hand conversion.

The files are written here as the export layouts of docs/data_format.md#tracker-exports
describe them (a measurement script's whitespace-separated log; a tracker software's point
export with a target id per point, a unit in each coordinate header, U95 at k = 2).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.calibration.workflow import (
    identify_measurements,
    read_scene_measurements,
    setup,
    simulated_measurements,
)
from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main
from calib_oed.exceptions import MeasurementFileError
from calib_oed.io.design_file import write_design_csv
from calib_oed.io.tracker_import import read_point_export, read_tracker_export
from tests.cli.test_bad_inputs import SHIPPED

N_POSES = 30


@pytest.fixture(scope="module")
def two_smrs(tmp_path_factory):
    """A scene with two SMRs, a simulated session at random poses, its truth and design."""
    d = tmp_path_factory.mktemp("tracker")
    text = SHIPPED.read_text().replace("    offset: [0, 0, 50]", "    offset: [0, 0, 50]\n"
                                       "  - name: smr1\n    offset: [60, 0, 40]", 1)
    (d / "scene.yaml").write_text(text)
    s = setup(str(d / "scene.yaml"))
    q = s.problem.robot.random_configurations(N_POSES, 3)
    mset, p_true = simulated_measurements(s, q, 1)
    xyz = np.zeros((N_POSES, 2, 3))
    for j in (0, 1):
        xyz[:, j] = mset.positions[mset.reflector == j]
    write_design_csv(d / "design.csv", s.problem.robot, q)
    return d, s, q, xyz, p_true


def _identified_near_truth(s, path, p_true):
    result = identify_measurements(s, read_scene_measurements(s, path))
    free = s.problem.identifiability.free_indices
    assert result.std.shape == free.shape
    assert np.all(np.abs(result.p - p_true)[free] <= 5 * result.std)
    return result


def test_a_headerless_pose_array_is_imported_and_identified(two_smrs, tmp_path):
    d, s, q, xyz, p_true = two_smrs
    rows = ["// robot measurement log: A1..A6 [deg], SMR A x y z, SMR B x y z [mm]"]
    for k in range(N_POSES):
        smr_b = "NaN NaN NaN" if k == 7 else " ".join(f"{v:.6f}" for v in xyz[k, 1] * 1e3)
        rows.append(" ".join(f"{v:.7f}" for v in np.degrees(q[k])) + "   "
                    + " ".join(f"{v:.6f}" for v in xyz[k, 0] * 1e3) + "   " + smr_b)
    (tmp_path / "log.txt").write_text("\n".join(rows) + "\n")
    out = tmp_path / "m.csv"
    assert main(["import", str(d / "scene.yaml"), str(tmp_path / "log.txt"), "-o", str(out), "--quiet"]) == EXIT_OK
    mset = read_scene_measurements(s, out)
    assert len(mset.q) == 2 * N_POSES - 1  # SMR B lost its beam at pose 8
    _identified_near_truth(s, out, p_true)


def _point_export(xyz, sep=",", decimal=".", u95=0.02):
    header = ["Target", "X [mm]", "Y [mm]", "Z [mm]", "U95 [mm]", "Temperature [°C]", "Pressure [hPa]",
              "Time"]
    lines = [sep.join(f'"{h}"' if sep == ";" else h for h in header)]
    for k in range(len(xyz)):
        for j, smr in enumerate(("A", "B")):
            numbers = [*(xyz[k, j] * 1e3), u95, 20.5 + 0.01 * k, 1013.2]
            text = [f"{v:.6f}".replace(".", decimal) for v in numbers]
            lines.append(sep.join([f"P{k + 1:03d}_{smr}", *text, f"2026-11-26T10:{k:02d}:00"]))
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("sep, decimal", [(",", "."), (";", ",")], ids=["comma", "semicolon-decimal-comma"])
def test_a_point_export_with_u95_is_imported_and_identified(two_smrs, tmp_path, sep, decimal):
    d, s, q, xyz, p_true = two_smrs
    (tmp_path / "export.csv").write_text(_point_export(xyz, sep, decimal), encoding="utf-8")
    out = tmp_path / "m.csv"
    assert main(["import", str(d / "scene.yaml"), str(tmp_path / "export.csv"), "--design",
                 str(d / "design.csv"), "--smrs", "A,B", "-o", str(out), "--quiet"]) == EXIT_OK
    mset = read_scene_measurements(s, out)
    np.testing.assert_allclose(mset.sigma, 1e-5)  # U95 0.02 mm at k = 2
    np.testing.assert_allclose(mset.positions[mset.reflector == 1], xyz[:, 1], atol=1e-9)
    _identified_near_truth(s, out, p_true)


@pytest.mark.parametrize("group, target", [("P{k:03d}", "{smr}"), ("Robot", "P{k:03d}_{smr}")],
                         ids=["pose-as-group", "pose-in-target"])
def test_spatialanalyzer_ascii_point_export_is_imported(two_smrs, tmp_path, group, target):
    """SpatialAnalyzer's "Export ASCII points" (SA User's Manual, "Exporting ASCII Formatted
    Points"): no header; ``//`` comments with the SA version and working frame; each line
    "Collection Group Target x y z" in the working frame, blank separated, then the columns
    the export's options add (here the coordinate uncertainty, mapped with --columns)."""
    d, s, q, xyz, p_true = two_smrs
    lines = ["// SA Version 2026.1.0101.1", "// Working Frame: A::Tracker", "// Units: mm"]
    for k in range(N_POSES):
        for j, smr in enumerate(("A", "B")):
            names = ["Calib", group.format(k=k + 1), target.format(k=k + 1, smr=smr)]
            lines.append(" ".join([*names, *(f"{v:.6f}" for v in xyz[k, j] * 1e3), "0.020000"]))
    (tmp_path / "export.txt").write_text("\n".join(lines) + "\n")
    out = tmp_path / "m.csv"
    assert main(["import", str(d / "scene.yaml"), str(tmp_path / "export.txt"), "--design",
                 str(d / "design.csv"), "--smrs", "A,B", "--columns", "u95=column7", "-o", str(out),
                 "--quiet"]) == EXIT_OK
    mset = read_scene_measurements(s, out)
    assert len(mset.q) == 2 * N_POSES
    np.testing.assert_allclose(mset.sigma, 1e-5)  # 0.02 mm at k = 2
    np.testing.assert_allclose(mset.positions[mset.reflector == 0], xyz[:, 0], atol=1e-9)
    np.testing.assert_allclose(mset.q[mset.reflector == 1], q, atol=1e-12)
    _identified_near_truth(s, out, p_true)


def test_a_six_dof_probe_quaternion_becomes_the_rotation_vector(two_smrs, tmp_path):
    d, s, q, xyz, _ = two_smrs
    rng = np.random.default_rng(0)
    rotations = [pin.log3(pin.exp3(rng.normal(size=3))) for _ in range(N_POSES)]
    lines = ["Point Name,X,Y,Z,Q0,Q1,Q2,Q3"]
    for k, r in enumerate(rotations):
        w = pin.Quaternion(pin.exp3(r))
        lines.append(f"T{k + 1}-A," + ",".join(f"{v:.9f}" for v in (*(xyz[k, 0] * 1e3), w.w, w.x, w.y, w.z)))
    (tmp_path / "probe.csv").write_text("\n".join(lines) + "\n")
    result = read_tracker_export(tmp_path / "probe.csv", s.problem.robot, s.reflector_names, design_q=q,
                                 smrs={"A": "smr0"})
    assert result.layout == "points" and result.mset.rotations is not None
    for r, got in zip(rotations, result.mset.rotations, strict=True):
        assert np.linalg.norm(pin.log3(pin.exp3(r).T @ pin.exp3(got))) < 1e-7


@pytest.mark.parametrize("edit, fragment", [
    (lambda t: t.replace("P002_A", "Q-A"), "does not match the target pattern"),
    (lambda t: t.replace("P002_A", f"P{N_POSES + 1}_A"), f"not a row of the design (1..{N_POSES})"),
    (lambda t: t.replace("P002_A", "P002_C"), "SMR 'C'"),
    (lambda t: t.replace("X [mm]", "X [m]"), "pass length_unit='m'"),
    (lambda t: t.replace("P002_A", "P001_A"), "measured twice"),
    (lambda t: t.replace("1013.200000", "101.320000", 1), "pressure 101.32 hPa is outside"),
    (lambda t: t.replace(",0.020000,", ",,", 1), "U95 is missing on some points"),
    (lambda t: t.replace(",0.020000,", ",-0.020000,", 1), "U95 = -0.02 mm must be > 0"),
    (lambda t: t.replace("Target,", "Label,"), "no target column"),
])
def test_bad_point_exports_name_the_line(two_smrs, tmp_path, edit, fragment):
    d, s, q, xyz, _ = two_smrs
    (tmp_path / "e.csv").write_text(edit(_point_export(xyz)))
    with pytest.raises(MeasurementFileError, match="tracker export") as info:
        read_point_export(tmp_path / "e.csv", s.problem.robot, s.reflector_names, q,
                          smrs={"A": "smr0", "B": "smr1"})
    assert fragment in str(info.value)


@pytest.mark.parametrize("argv, fragment", [
    (["--layout", "points"], "give the design the robot ran"),
    (["--columns", "joint_a1,skip"], "missing joint_a2"),
    (["--smrs", "smr9"], "give distinct names of the scene's reflectors"),
    (["--design", "{d}/design.csv", "--layout", "poses"], "belong to the points layout"),
])
def test_bad_import_arguments_are_one_line(two_smrs, tmp_path, capsys, argv, fragment):
    d, *_ = two_smrs
    (tmp_path / "log.txt").write_text("1 2 3\n")
    argv = [a.format(d=d) for a in argv]
    assert main(["import", str(d / "scene.yaml"), str(tmp_path / "log.txt"), "-o", str(tmp_path / "m.csv"),
                 *argv]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and fragment in err, err
    assert not (tmp_path / "m.csv").exists()


_FANUC = ("\ncontroller:\n  name: fanuc\n  angle: deg\n  joints: [{sign: -1}, {}, {}, {}, {}, {}]\n"
          "  couplings: [{joint: 3, from: 2, ratio: 1.0}]\n")


def _pose_log(values_deg: np.ndarray, xyz: np.ndarray) -> str:
    return "\n".join(" ".join(f"{v:.9f}" for v in values_deg[k]) + "   "
                     + " ".join(f"{v:.6f}" for v in xyz[k, 0] * 1e3) for k in range(len(values_deg))) + "\n"


@pytest.mark.parametrize("convention", ["controller", "urdf"])
def test_a_pose_array_in_controller_values_maps_like_a_design(two_smrs, tmp_path, capsys, convention):
    """A scene with a controller block: the log's joints are the controller's by default (mapped
    q = A c + b, as a design file in controller values is); --joints urdf reads them as URDF."""
    d, s, q, xyz, _ = two_smrs
    (tmp_path / "scene.yaml").write_text((d / "scene.yaml").read_text() + _FANUC)
    conv = setup(str(tmp_path / "scene.yaml")).scene.controller
    values = np.degrees(conv.to_controller(q) if convention == "controller" else q)
    (tmp_path / "log.txt").write_text(_pose_log(values, xyz))
    out = tmp_path / "m.csv"
    extra = [] if convention == "controller" else ["--joints", "urdf"]
    assert main(["import", str(tmp_path / "scene.yaml"), str(tmp_path / "log.txt"), "-o", str(out), "--smrs",
                 "smr0", "--quiet", *extra]) == EXIT_OK
    np.testing.assert_allclose(read_scene_measurements(s, out).q, q, atol=1e-9)


def test_controller_joints_without_a_controller_block_is_one_line(two_smrs, tmp_path, capsys):
    d, s, q, xyz, _ = two_smrs
    (tmp_path / "log.txt").write_text(_pose_log(np.degrees(q), xyz))
    assert main(["import", str(d / "scene.yaml"), str(tmp_path / "log.txt"), "-o", str(tmp_path / "m.csv"),
                 "--smrs", "smr0", "--joints", "controller"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the scene has no controller: block" in err, err
