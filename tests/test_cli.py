"""The calib-oed command: output, JSON, and one-line errors with exit code 2."""

from __future__ import annotations

import json

import pytest

from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main


def test_identifiability_text(capsys):
    assert main(["identifiability", "fms_kr16"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "free (identifiable): 25" in out
    assert "joint1.tx" in out and "redundant with" in out
    assert "NOT estimable" in out  # the world-frame TCP depends on the base gauge


def test_identifiability_json(capsys):
    assert main(["identifiability", "fms_kr16", "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["rank"] == len(data["free"]) == 25
    assert data["n_parameters"] == len(data["free"]) + len(data["fixed"]) == 45
    assert data["condition_number"] > 1
    (kpi,) = data["kpi"]["estimability"]
    assert kpi["estimable"] is False and kpi["residual"] > 1e-3 and kpi["gauge"]


def test_demo_prints_kpi_sigma(capsys):
    assert main(["demo", "ur5_table", "-n", "40", "--seed", "1"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "KPI standard deviation" in out and " mm" in out


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["identifiability", "no_such_scene"], "shipped scenes are"),
        (["identifiability", "/tmp/does/not/exist.yaml"], "not found"),
    ],
)
def test_errors_are_one_line(capsys, argv, fragment):
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert fragment in err and err.count("\n") == 1 and "Traceback" not in err


def test_scenes_and_robots(capsys):
    assert main(["scenes"]) == EXIT_OK
    assert "fms_kr16" in capsys.readouterr().out.split()
    assert main(["robots"]) == EXIT_OK
    assert {"kr16", "ur5", "panda"} <= set(capsys.readouterr().out.split())


def test_demo_rejects_a_non_positive_pose_count(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "-n", "0"])
    assert exc.value.code == 2 and "expected an integer >= 1" in capsys.readouterr().err


def test_demo_with_too_few_poses_says_so(capsys):
    assert main(["demo", "-n", "5"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "measure more configurations" in err and "Traceback" not in err
