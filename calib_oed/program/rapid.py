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

from calib_oed.exceptions import ProgramError
from calib_oed.program.format_common import degrees, header_lines, require_six_axes, steps
from calib_oed.program.records import Program

#: Moves shorter than this [s] get no ``\\T`` (a zero time is not a RAPID move time).
MIN_TIME = 1e-3

#: Longest RAPID identifier (characters).
RAPID_NAME_LENGTH = 32


def _measure(program: Program, pose: int) -> list[str]:
    """The lines at a measurement pose: the dwell, or the handshake (docs/program.md)."""
    hs = program.handshake
    if hs is None:
        return [f"    WaitTime {program.dwell:.2f}; ! measure pose {pose}"]
    if hs.routine is not None:
        return [f"    {hs.routine}; ! measure pose {pose}"]
    do, di = hs.output_name or f"do{hs.output}", hs.input_name or f"di{hs.input}"
    return [f"    SetDO {do}, 1; ! measure pose {pose}", f"    WaitDI {di}, 1;", f"    SetDO {do}, 0;"]


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
    lines.append(f"  PROC {name}_run()")
    for step in all_steps:
        what = {"home": "home", "via": "via point (no measurement)"}.get(step.kind, f"pose {step.pose}")
        # \T: the move takes the estimated time (v1000 alone caps the TCP at 1 m/s)
        speed = "v1000" if not step.time or step.time < MIN_TIME else f"v1000\\T:={step.time:.3f}"
        lines.append(f"    MoveAbsJ j{step.name}\\NoEOffs, {speed}, fine, tool0; ! {what}")
        if step.kind == "pose":
            lines += _measure(program, step.pose)
    lines += ["  ENDPROC", "ENDMODULE"]
    return {f"{name}.mod": "\n".join(lines) + "\n"}
