"""ABB RAPID: a ``.mod`` with ``MoveAbsJ`` to ``jointtarget`` constants.

``CONST jointtarget jNAME:=[[j1,..,j6],[9E9,9E9,9E9,9E9,9E9,9E9]];`` [deg], moves
``MoveAbsJ jNAME\\NoEOffs, v1000\\T:=t, fine, tool0;``, ``WaitTime dwell;`` at each
measurement pose with a comment naming it. ``\\T:=t`` is the move's estimated time [s]
(its slowest joint at the timing's limits): without it ``v1000`` caps the TCP at
1000 mm/s and long moves take longer than the estimate. The routine is ``PROC <name>_run()``, not
``main``: a task's ``main`` is the task's entry point and may exist in another module
already (a second one does not load). Checked by ``rapidchecker`` in the tests.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ProgramError
from calib_oed.program.format_common import (
    MeasureWords,
    degrees,
    header_lines,
    require_six_axes,
    steps,
)
from calib_oed.program.records import Program

#: Moves shorter than this [s] get no ``\\T`` (a zero time is not a RAPID move time).
MIN_TIME = 1e-3

#: Longest RAPID identifier (characters).
RAPID_NAME_LENGTH = 32


def _pose(xyz, rpy) -> str:
    """``[[x,y,z],[q1,q2,q3,q4]]``: [mm] and the unit quaternion (w first, RAPID's order)."""
    q = pin.Quaternion(pin.rpy.rpyToMatrix(*np.asarray(rpy, float)))
    x, y, z = (1e3 * np.asarray(xyz, float)).tolist()
    return f"[[{x:.3f},{y:.3f},{z:.3f}],[{q.w:.6f},{q.x:.6f},{q.y:.6f},{q.z:.6f}]]"


def _declarations(program: Program, name: str) -> tuple[str, str, list[str]]:
    """The tool and work object arguments of the moves and their ``PERS`` declarations.

    A tool frame or payload gives ``PERS tooldata t<name>`` (held by the robot; its mass is
    the payload's, which RAPID needs > 0); a base frame ``PERS wobjdata w<name>``.
    """
    decl, tool, wobj = [], "tool0", ""
    if program.tool is not None or program.payload is not None:
        frame = program.tool
        load = program.payload
        if load is None or load.mass <= 0:
            raise ProgramError("program.payload", None if load is None else load.mass,
                               "RAPID's tooldata needs the tool's mass > 0: give program.payload.mass [kg]")
        c = (1e3 * np.asarray(load.com, float)).tolist()
        pose = _pose(np.zeros(3), np.zeros(3)) if frame is None else _pose(frame.xyz, frame.rpy)
        tool = f"t{name}"
        decl.append(f"  PERS tooldata {tool}:=[TRUE,{pose},[{load.mass:.3f},[{c[0]:.3f},{c[1]:.3f},"
                    f"{c[2]:.3f}],[1,0,0,0],0,0,0]];")
    if program.base is not None:
        wobj = f"\\WObj:=w{name}"
        decl.append(f"  PERS wobjdata w{name}:=[FALSE,TRUE,\"\",{_pose(program.base.xyz, program.base.rpy)},"
                    "[[0,0,0],[1,0,0,0]]];")
    return tool, wobj, decl


#: The lines at a measurement pose (:class:`~calib_oed.program.format_common.MeasureWords`).
MEASURE = MeasureWords("    WaitTime {dwell:.2f}; ! measure pose {pose}", "    {routine}; ! measure pose {pose}",
                       ("    SetDO {output_name}, 1; ! measure pose {pose}", "    WaitDI {input_name}, 1;",
                        "    SetDO {output_name}, 0;"))


def write_rapid(program: Program, name: str) -> dict[str, str]:
    """``{name.mod: text}``; ``name`` is the module name."""
    require_six_axes(program, "rapid")
    if len(name) > RAPID_NAME_LENGTH - len("_run"):
        raise ProgramError("name", name, f"RAPID names hold {RAPID_NAME_LENGTH} characters: give at most "
                           f"{RAPID_NAME_LENGTH - len('_run')} (the routine is NAME_run)")
    all_steps = steps(program)
    lines = [f"MODULE {name}"]
    lines += [f"  ! {line}" for line in header_lines(program, "degrees (robax rax_1..rax_6)")]
    seen = set()
    for step in all_steps:
        if step.name in seen:
            continue
        seen.add(step.name)
        lines.append(f"  CONST jointtarget j{step.name}:=[[{','.join(degrees(step.q))}],"
                     "[9E9,9E9,9E9,9E9,9E9,9E9]];")
    tool, wobj, decl = _declarations(program, name)
    lines += decl
    lines.append(f"  PROC {name}_run()")
    for step in all_steps:
        what = {"home": "home", "via": "via point (no measurement)"}.get(step.kind, f"pose {step.pose}")
        # \T: the move takes the estimated time (v1000 alone caps the TCP at 1 m/s)
        speed = "v1000" if not step.time or step.time < MIN_TIME else f"v1000\\T:={step.time:.3f}"
        lines.append(f"    MoveAbsJ j{step.name}\\NoEOffs, {speed}, fine, {tool}{wobj}; ! {what}")
        if step.kind == "pose":
            lines += MEASURE.compute_lines(program, step.pose)
    lines += ["  ENDPROC", "ENDMODULE"]
    return {f"{name}.mod": "\n".join(lines) + "\n"}
