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
