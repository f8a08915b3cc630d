"""Every script in examples/ runs and passes its own checks."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).parent.parent / "examples").glob("*.py"))


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs(path, capsys, tmp_path, monkeypatch):
    # the examples that write files take their path from the command line: keep them in tmp_path
    monkeypatch.setattr(sys, "argv", [str(path), str(tmp_path / "view.html"), str(tmp_path / "cell.yaml")])
    runpy.run_path(str(path), run_name="__main__")
    assert capsys.readouterr().out.strip()
    if path.stem.startswith("05_"):  # the scene it prints is there after the run, with its URDF
        assert (tmp_path / "cell.yaml").is_file() and (tmp_path / "my_robot.urdf").is_file()


def test_examples_exist():
    assert EXAMPLES
