"""What the commands share (cli/_common.py): the parser of a subcommand, ``--json``/``--quiet``, the
model flags (``--joint-gains`` like ``--compliance``) and the deflection note of a model-error design."""

from __future__ import annotations

import argparse
import json
import warnings

from calib_oed.calibration.workflow import setup
from calib_oed.cli import EXIT_OK, main
from calib_oed.cli._common import _note_deflection, add_command, add_json_quiet
from calib_oed.exceptions import CalibOedNote
from calib_oed.scene.reader import load_scene


def _extra_parameters(capsys, *flags) -> list[str]:
    """The gain and compliance parameters ``identifiability --json`` names."""
    capsys.readouterr()
    assert main(["identifiability", "fms_kr16", "--json", *flags]) == EXIT_OK
    text = json.dumps(json.loads(capsys.readouterr().out))
    return sorted({p for p in text.split('"') if p.endswith((".gain", ".c"))})


def test_joint_gains_flag_models_the_gains_of_the_joints_named(capsys):
    assert _extra_parameters(capsys) == []
    assert _extra_parameters(capsys, "--joint-gains") == [f"joint{i}.gain" for i in range(1, 7)]
    assert _extra_parameters(capsys, "--joint-gains", "2,3") == ["joint2.gain", "joint3.gain"]
    both = _extra_parameters(capsys, "--joint-gains=5", "--compliance")
    assert "joint5.gain" in both and "joint2.c" in both and "joint1.gain" not in both


def test_add_command_declares_scene_function_and_outputs():
    sub = argparse.ArgumentParser().add_subparsers(dest="command")
    p = add_command(sub, "write", len, "writes", outputs={"output": "dir"})
    add_json_quiet(p, "print nothing")
    args = p.parse_args(["cell.yaml", "--json"])
    assert (args.scene, args.func, args.outputs, args.json, args.quiet) == ("cell.yaml", len, {"output": "dir"}, True, False)
    bare = add_command(sub, "list", len, "lists", scene=False)
    add_json_quiet(bare)
    assert vars(bare.parse_args([])) == {"func": len, "json": False}


def test_the_design_command_notes_the_deflection():
    """``calib-oed design`` says so on stderr before a model-error design (not for ``kpi``)."""
    s = setup(load_scene("fms_kr300"))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        _note_deflection(s, "kpi_model")
        _note_deflection(s, "kpi")
    notes = [w for w in seen if issubclass(w.category, CalibOedNote)]
    assert len(notes) == 1 and "deflect" in str(notes[0].message)
