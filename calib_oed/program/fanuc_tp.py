"""FANUC TP (ASCII ``.ls``): ``J P[k] 100% FINE`` to positions in joint representation.

Positions are written ``J1= .. deg`` ... ``J6= .. deg`` in the ``/POS`` section.
**J2/J3 convention**: FANUC controllers show J3 measured from the horizontal
(the J2/J3 interaction), while a URDF's J3 is relative to the upper arm:
:math:`q_3 = J3 + J2`, i.e. :math:`J3 = q_3 - J2`, in the sign conventions of
ROS-Industrial's fanuc URDFs (``fanuc_driver``: ``J3_out = J3_in + J23_factor *
J2_in`` on the controller's state, ``J23_factor`` 1 for the coupled arms). With a scene
``controller:`` block (e.g. ``couplings: [{joint: 3, from: 2, ratio: 1}]``,
docs/scenes.md) the positions are the controller's values and the header states
the map; without one the URDF's J3 is written unchanged and the header says so:
convert (and check the signs of) J3 before loading on a FANUC arm.
TP comments hold 32 characters, so the header is cut into short ``!`` lines;
``;`` ends a TP statement, so a comment never holds one (written as ``,``).
"""

from __future__ import annotations

import textwrap

from calib_oed.program.format_common import (
    MeasureWords,
    degrees,
    header_lines,
    require_six_axes,
    steps,
)
from calib_oed.program.records import Program

#: What a FANUC user must know about J3, in the header.
J2_J3_NOTE = ("J2/J3: J3 is the URDF angle relative to the upper arm, NOT the FANUC J3 "
              "measured from the horizontal (J3_FANUC = J3 - J2, check signs): convert first, "
              "or add a controller: block to the scene")


#: The statements at a measurement pose (:class:`~calib_oed.program.format_common.MeasureWords`).
MEASURE = MeasureWords("WAIT {dwell:6.2f}(sec) ;", "CALL {ROUTINE} ;",
                       ("DO[{output}]=ON ;", "WAIT DI[{input}]=ON ;", "DO[{output}]=OFF ;"))


def write_tp(program: Program, name: str) -> dict[str, str]:
    """``{name.ls: text}``; ``name`` is the TP program name."""
    require_six_axes(program, "tp")
    prog = name.upper()
    all_steps = steps(program)
    comments = []
    note = [] if program.controller is not None else [J2_J3_NOTE]
    for line in [*header_lines(program, "degrees (J1..J6)"), *note]:
        comments += textwrap.wrap(line.replace(";", ","), 30)  # ';' would end the statement
    body = [f"! {c} ;" for c in comments]
    uf = 0 if program.base is None else program.base.number
    ut = 1 if program.tool is None else program.tool.number
    if program.base is not None:  # the frames' values are in the header: enter them on the controller
        body.append(f"UFRAME_NUM={uf} ;")
    if program.tool is not None:
        body.append(f"UTOOL_NUM={ut} ;")
    if program.payload is not None:
        body.append(f"PAYLOAD[{program.payload.number}] ;")
    positions = {}
    for step in all_steps:
        if step.name not in positions:
            positions[step.name] = (len(positions) + 1, step)
        k = positions[step.name][0]
        what = {"home": "home", "via": "via point"}.get(step.kind, f"pose {step.pose}")
        body.append(f"J P[{k}:{what}] 100% FINE ;")
        if step.kind == "pose":
            body.append(f"! measure pose {step.pose} ;")
            body += MEASURE.compute_lines(program, step.pose)
    lines = [f"/PROG  {prog}", "/ATTR", "COMMENT\t\t= \"calib_oed\";", "DEFAULT_GROUP\t= 1,*,*,*,*;",
             "/MN"]
    lines += [f"{i:4d}:  {text}" for i, text in enumerate(body, start=1)]
    lines.append("/POS")
    for k, step in positions.values():
        j = degrees(step.q)
        lines += [f"P[{k}]{{", "   GP1:", f"\tUF : {uf}, UT : {ut},",
                  f"\tJ1= {j[0]} deg,\tJ2= {j[1]} deg,\tJ3= {j[2]} deg,",
                  f"\tJ4= {j[3]} deg,\tJ5= {j[4]} deg,\tJ6= {j[5]} deg", "};"]
    lines.append("/END")
    return {f"{name}.ls": "\n".join(lines) + "\n"}
