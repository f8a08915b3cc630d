"""The scene's program block: units, defaults, errors naming the key."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calib_oed.exceptions import ProgramError, SceneError
from calib_oed.program.settings import ProgramSettings, program_settings_from_scene


def test_block_in_file_units(kr16_scene):
    block = {"home": [0, -90, 90, 0, 0, 0], "dwell": 1.5, "velocities": {"joint_a1": 90},
             "move_tolerance": 2, "velocity_scale": 0.8}
    s = program_settings_from_scene(dataclasses.replace(kr16_scene, program=block))
    assert np.allclose(s.home, np.deg2rad([0, -90, 90, 0, 0, 0]))
    assert s.dwell == 1.5 and s.velocity_scale == 0.8
    assert s.velocities["joint_a1"] == pytest.approx(np.pi / 2)
    assert s.move_tolerance == pytest.approx(0.002)  # mm in the file
    assert program_settings_from_scene(kr16_scene).dwell == ProgramSettings().dwell


@pytest.mark.parametrize("block, key", [({"dwel": 1}, "program.dwel"),
                                        ({"velocities": {"a1": 1}}, "program.velocities.a1"),
                                        ({"home": [0, 0]}, "program.home"),
                                        ({"velocity_scale": 2}, "program.velocity_scale")])
def test_bad_block_names_the_key(kr16_scene, block, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        program_settings_from_scene(dataclasses.replace(kr16_scene, program=block))


def test_bad_settings():
    with pytest.raises(ProgramError, match="dwell"):
        ProgramSettings(dwell=-1.0)


def test_planner_budget_is_an_iteration_count(kr16_scene):
    scene = dataclasses.replace(kr16_scene, program={"planner_iterations": 500})
    assert program_settings_from_scene(scene).planner_iterations == 500
    assert program_settings_from_scene(scene, planner_iterations=7).planner_iterations == 7
    for bad in (0, 2.5, "many", True):
        with pytest.raises(SceneError, match="program.planner_iterations"):
            program_settings_from_scene(dataclasses.replace(kr16_scene, program={"planner_iterations": bad}))
    with pytest.raises(ProgramError, match="planner_iterations"):
        ProgramSettings(planner_iterations=0)


def test_handshake_block(kr16_scene):
    from calib_oed.program.settings import Handshake

    def read(block):
        return program_settings_from_scene(dataclasses.replace(kr16_scene, program={"handshake": block}))

    assert read({"output": 1, "input": 2}).handshake == Handshake(output=1, input=2)
    assert read({"routine": "measure"}).handshake == Handshake(routine="measure")
    assert ProgramSettings().handshake is None
    assert Handshake(output=1, input=2).signal_names == ("do1", "di2")
    named = read({"output": 1, "input": 2, "output_name": "doMeasure", "input_name": "diDone"}).handshake
    assert named.signal_names == ("doMeasure", "diDone")
    for bad in ({"output": 1}, {"output": 1, "input": 2, "routine": "x"}, {"routine": "a b"},
                {"output": -1, "input": 2}, {"signal": 1}):
        with pytest.raises(SceneError, match="program.handshake"):
            read(bad)


def test_tool_base_payload_blocks(kr16_scene):
    """In the scene's units (mm, deg in the shipped scenes); the payload defaults to
    robot.compliance's when compliance is modelled (not the rated load of a disabled block)."""
    block = {"tool": {"number": 2, "xyz": [0, 0, 50], "rpy": [0, 90, 0]}, "base": {"xyz": [1000, 0, 0]},
             "payload": {"mass": 1.2, "com": [0, 0, 30]}}
    s = program_settings_from_scene(dataclasses.replace(kr16_scene, program=block))
    assert s.tool.number == 2 and np.allclose(s.tool.xyz, [0, 0, 0.05]) and np.allclose(s.tool.rpy, [0, np.pi / 2, 0])
    assert s.base.number == 1 and np.allclose(s.base.xyz, [1, 0, 0])
    assert s.payload.mass == 1.2 and np.allclose(s.payload.com, [0, 0, 0.03])
    with pytest.raises(SceneError, match="program.payload"):
        program_settings_from_scene(dataclasses.replace(kr16_scene, program={"payload": {"com": [0, 0, 0]}}))
    from calib_oed import load_scene

    heavy = load_scene("fms_kr300")
    assert heavy.compliance is not None and not heavy.compliance.enabled
    assert program_settings_from_scene(heavy).payload is None
    on = dataclasses.replace(heavy, compliance=dataclasses.replace(heavy.compliance, enabled=True))
    assert program_settings_from_scene(on).payload.mass == heavy.compliance.payload.payload_mass > 0
