"""Universal Robots URScript: ``movej([q1, .., q6], a=.., v=..)`` in radians (URScript's unit).

``t`` is the move's estimated time [s] (its slowest joint at the timing's limits;
``movej`` then ignores ``a`` and ``v``), so the cycle time estimate is what runs;
``a`` and ``v`` are the smallest joint limits, the fallback of a move without a
time (the first). Each measurement pose is followed by ``sleep(dwell)`` and a
comment naming it.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from calib_oed.program.format_common import (
    RAD_DECIMALS,
    MeasureWords,
    header_lines,
    require_six_axes,
    steps,
)
from calib_oed.program.records import Program


def _declarations(program: Program) -> list[str]:
    """``set_tcp`` and ``set_payload`` from the scene's program block [m, rad (rotation vector), kg].
    A base frame does not change ``movej`` (joint targets): the header names it only."""
    out = []
    if program.tool is not None:
        rv = pin.log3(pin.rpy.rpyToMatrix(*np.asarray(program.tool.rpy, float)))
        values = ", ".join(f"{v:.6f}" for v in [*np.asarray(program.tool.xyz, float), *rv])
        out.append(f"  set_tcp(p[{values}])")
    if program.payload is not None:
        c = ", ".join(f"{v:.6f}" for v in np.asarray(program.payload.com, float))
        out.append(f"  set_payload({program.payload.mass:.3f}, [{c}])")
    return out


#: The lines at a measurement pose (:class:`~calib_oed.program.format_common.MeasureWords`).
MEASURE = MeasureWords("  sleep({dwell:.2f})  # measure pose {pose}", "  {routine}()  # measure pose {pose}",
                       ("  set_standard_digital_out({output}, True)  # measure pose {pose}",
                        "  while not get_standard_digital_in({input}):", "    sync()", "  end",
                        "  set_standard_digital_out({output}, False)"))


def write_urscript(program: Program, name: str) -> dict[str, str]:
    """``{name.script: text}``; ``movej``'s ``v`` [rad/s] and ``a`` [rad/s²] are the smallest
    joint limits of the program's timing (URScript's defaults 1.05 and 1.4 if it has none)."""
    require_six_axes(program, "urscript")
    velocity = 1.05 if program.velocity is None else float(min(program.velocity))
    acceleration = 1.4 if program.acceleration is None else float(min(program.acceleration))
    lines = [f"# {line}" for line in header_lines(program, "radians (URScript's unit)")]
    lines.append(f"def {name}():")
    lines += _declarations(program)
    for step in steps(program):
        values = ", ".join(f"{v:.{RAD_DECIMALS}f}" for v in step.q)
        what = {"home": "home", "via": "via point (no measurement)"}.get(step.kind, f"pose {step.pose}")
        lines.append(f"  # {what}")
        timed = f", t={step.time:.3f}" if step.time and step.time >= 1e-3 else ""
        lines.append(f"  movej([{values}], a={acceleration:.4f}, v={velocity:.4f}{timed})")
        if step.kind == "pose":
            lines += MEASURE.compute_lines(program, step.pose)
    lines.append("end")
    lines.append(f"{name}()")
    return {f"{name}.script": "\n".join(lines) + "\n"}
