"""The design command's own checks (cli/design_commands.py)."""

from __future__ import annotations

import json

import numpy as np

from calib_oed.cli import EXIT_OK, main


def test_design_warns_when_home_may_not_wind_to_a_pose(capsys, tmp_path):
    """Issue 31: a design whose pose has a joint a whole turn from a value nearer home is named
    by the design command (stderr, and ``home_winding`` in --json), before the program fails.
    The default joint window (one turn about home) keeps designs from it; ``full`` does not."""
    from importlib import resources

    from calib_oed.calibration.workflow import setup
    from calib_oed.io.design_file import write_design_csv
    from calib_oed.oed.starts import candidate_pool
    from calib_oed.program.build import home_configuration, nearest_turns
    from calib_oed.program.settings import ProgramSettings
    from calib_oed.scene.reader import load_scene

    text = resources.files("calib_oed.scene.shipped").joinpath("ur5_table.yaml").read_text()
    scene = tmp_path / "ur5_full.yaml"
    scene.write_text(text + "\nfeasibility:\n  joint_window: full\n")
    s = setup(load_scene(scene))
    home, _ = home_configuration(s.scene, ProgramSettings())
    # the pool's poses at the values nearest home (the program's --wrap): none a turn away
    q, _ = nearest_turns(s.problem.robot, candidate_pool(s, 12, 0).q, home, s.scene.feasibility.margins.joint)
    start = tmp_path / "start.csv"
    write_design_csv(start, s.problem.robot, q)
    argv = ["design", str(scene), "--start", str(start), "--iterations", "1", "--no-certificate", "--quiet"]
    assert main([*argv, "--json"]) == EXIT_OK
    captured = capsys.readouterr()
    assert json.loads(captured.out)["home_winding"] == "" and "whole turn" not in captured.err
    k = int(np.argmin(np.abs(q[:, 0] - home[0]) + 9.0 * (q[:, 0] > home[0])))  # pan nearest home, below
    q[k, 0] += 2 * np.pi  # a turn up: within +-360 deg, almost a turn from home
    write_design_csv(start, s.problem.robot, q)
    assert main(argv) == EXIT_OK
    err = capsys.readouterr().err
    assert err.startswith("warning: 1 of 12 poses have a joint a whole turn from a value nearer home")
    assert f"pose {k + 1}: shoulder_pan_joint" in err and "program --wrap" in err


def test_sequential_step_says_what_its_sigma_covers(capsys, tmp_path):
    """Review finding: ``sequential --measured`` on data with model error (realistic truth, sigma0
    about 5, TCP error 0.1 mm) printed a KPI sigma of 6 um and "target 0.02 mm reached: stop
    measuring" without a word that the sigma is the measurement noise's share only. It now says so,
    and warns when the fit's sigma0 shows model error; clean data get no warning."""
    from calib_oed.calibration.workflow import (
        realistic_measurements,
        setup,
        simulated_measurements,
        write_measurement_file,
    )
    from calib_oed.scene.reader import load_scene

    s = setup(load_scene("fms_kr16"))
    q = s.problem.robot.random_configurations(30, 4)
    texts = {}
    for name, mset in (("realistic", realistic_measurements(s, q, 3)[0]),
                       ("clean", simulated_measurements(s, q, 3)[0])):
        path = tmp_path / f"{name}.csv"
        write_measurement_file(s, path, mset, name)
        argv = ["sequential", "fms_kr16", "--target-sigma", "0.05mm", "--measured", str(path)]
        assert main(argv) == EXIT_OK
        texts[name] = capsys.readouterr().out
        assert main([*argv, "--json"]) == EXIT_OK
        data = json.loads(capsys.readouterr().out)
        assert data["done"] and data["sigma_covers"].startswith("measurement noise only")
        assert bool(data["model_error_warning"]) == (name == "realistic")
    assert "(measurement noise only, the model taken as exact)" in texts["clean"]
    assert "reached: stop measuring" in texts["clean"] and "warning" not in texts["clean"]
    assert "warning: sigma0 = " in texts["realistic"] and "these data show model error" in texts["realistic"]
    assert "reached: stop measuring (by the noise-only sigma" in texts["realistic"]


def test_design_says_what_its_kpi_sigma_covers(capsys, tmp_path):
    """Review finding: ``design`` printed "KPI sigma per axis car_side 0.00310 mm" with no word that
    this is the measurement noise's share only (``evaluate`` and ``demo`` said it; issue 29: the
    3 um read as what the cell can reach, where a real arm misses new poses by 0.2 mm); ``compare``
    neither, under its "KPI sigma" column."""
    from calib_oed.calibration.report import KPI_SIGMA_COVERS

    assert main(["design", "fms_kr16", "-n", "30", "--no-refine", "--pool", "60",
                 "--no-certificate", "--quiet", "-o", str(tmp_path / "d")]) == EXIT_OK
    out = capsys.readouterr().out
    assert "KPI sigma per axis car_side" in out and KPI_SIGMA_COVERS in out
    assert "covers the measurement noise only" in KPI_SIGMA_COVERS
    design = str(tmp_path / "d" / "design.csv")
    assert main(["compare", "fms_kr16", design, design, "--quiet"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "KPI sigma" in out and KPI_SIGMA_COVERS in out


def test_evaluate_names_the_unit_of_every_criterion(capsys, tmp_path):
    """Review finding: ``evaluate`` listed ``kpi_model 0.037825, kpi_kriging 0.035506`` under a
    header that named the unit of every other criterion: they are mean squared KPI errors per
    axis with the model-error prior [mm²] (0.19 mm per axis beside a noise-only 0.0031 mm)."""
    from calib_oed.calibration.workflow import setup
    from calib_oed.io.design_file import write_design_csv
    from calib_oed.oed.starts import candidate_pool
    from calib_oed.scene.reader import load_scene

    s = setup(load_scene("fms_kr16"))
    design = tmp_path / "d.csv"
    write_design_csv(design, s.problem.robot, candidate_pool(s, 30, 0).q)
    assert main(["evaluate", "fms_kr16", str(design), "--no-mesh-check", "--quiet"]) == EXIT_OK
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith("criterion values ("))
    values = out.splitlines()[out.splitlines().index(header) + 1]
    names = [item.split()[0] for item in values.strip().split(", ")]
    assert "kpi_model" in names and "kpi_kriging" in names
    for name in names:  # every criterion printed is explained in the header
        assert name in header or (name.startswith("O") and "O1..O5" in header), name
    assert "kpi_kriging: mean squared KPI error per axis with the scene's model-error prior [mm²]" in header


def test_the_default_call_keeps_the_model_error_criterion_s_iteration_cap(capsys, monkeypatch):
    """Without --iterations/--time-limit the command gives the design its own defaults: for
    kpi_model (exact Hessian) its iteration budget (``oed.model_error.exact_iterations``), not the
    SQP's own limit; with --iterations, that limit."""
    import calib_oed.oed.model_error as model_error

    monkeypatch.setattr(model_error, "MODEL_ERROR_ITERATIONS", 2)
    monkeypatch.setattr(model_error, "MODEL_ERROR_EXACT_ITERATIONS", 2)
    assert main(["design", "fms_kr16", "-n", "12", "--pool", "200", "--no-collisions", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["criterion"] == "kpi_model" and data["solver"]["iterations"] <= 2
    assert main(["design", "fms_kr16", "-n", "12", "--pool", "200", "--no-collisions", "--iterations", "4",
                 "--json"]) == 0
    assert 2 < json.loads(capsys.readouterr().out)["solver"]["iterations"] <= 4
