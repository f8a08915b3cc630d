"""`calib-oed program`: files in every format, JSON, and one-line errors with exit 2."""

from __future__ import annotations

import json

import pytest

from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.io.design_file import write_design_csv
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def design(tmp_path_factory):
    scene = load_scene("fms_kr16")
    model, _ = feasibility_from_scene(scene)
    path = tmp_path_factory.mktemp("design") / "design.csv"
    write_design_csv(path, scene.robot, sample_feasible(model, 6, 11))
    return path


def test_program_writes_krl_and_json(design, tmp_path, capsys):
    out = tmp_path / "prog"
    assert main(["program", "fms_kr16", str(design), "--format", "krl", "-o", str(out), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert sorted(data["order"]) == list(range(1, 7))
    assert data["cycle_time_s"]["optimised"] <= data["cycle_time_s"]["nearest neighbour"] + 1e-9
    assert sorted(p.rsplit("/", 1)[1] for p in data["files"]) == ["calib_program.dat", "calib_program.src"]
    assert (out / "calib_program.src").read_text().count("WAIT SEC") == 6


def test_program_text_output_and_home(design, capsys):
    assert main(["program", "fms_kr16", str(design), "--home=-9,-73,104,-38,-13,0",
                 "--dwell", "1"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "estimated cycle time" in out and "nothing written" in out
    assert "dwell 1.00 s per pose" in out  # --dwell reaches the program


def test_dwell_reaches_every_measurement(design, tmp_path, capsys):
    out = tmp_path / "prog"
    assert main(["program", "fms_kr16", str(design), "--dwell", "3.5", "-o", str(out), "--json"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["dwell_s"] == 3.5
    rows = [r.split(",") for r in (out / "calib_program.csv").read_text().splitlines() if not r.startswith("#")]
    dwells = [r[3] for r in rows[1:] if r[1] == "pose"]
    assert len(dwells) == 6 and set(dwells) == {"3.50"}


def test_a_home_in_collision_names_its_angles_and_the_pair(design, capsys):
    assert main(["program", "fms_kr16", str(design), "--home=-4,31,90,-134,-60,254"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "home = '-4, 31, 90, -134, -60, 254 deg': in collision by the scene's capsule model" in err
    assert "floor" in err and "given (program.home or --home)" in err and "--home, or program.home" in err


@pytest.mark.parametrize("argv, message", [
    (["--home", "1,2"], "--home"),
    (["--home", "0,0,0,0,0,400"], "outside the joint limits"),
    (["--name", "9bad"], "--name"),
    (["--format", "krl", "--name", "end"], "KRL keyword"),
    (["--dwell", "-1"], "--dwell = -1.0: expected a settle and measure time in seconds >= 0"),
    (["--dwell", "nan"], "--dwell = nan"),
])
def test_bad_input_is_one_line(design, capsys, argv, message):
    assert main(["program", "fms_kr16", str(design), *argv]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
