"""A CSV of the ordered program: every target with its joint angles in degrees and radians.

Columns: ``step, kind, pose, dwell_s``, then ``<joint>_deg`` (joint values in
degrees: the controller's if the scene has a ``controller:`` block, else the
URDF's, as the header says) and ``<joint>_rad`` (the same in radians), one row
per target (home, via point, measurement pose); ``#`` lines carry the header.
"""

from __future__ import annotations

import numpy as np

from calib_oed.program.format_common import DEG_DECIMALS, header_lines, steps
from calib_oed.program.records import Program

#: Radians are written with 10 decimals: the CSV is also the exact record of the program.
CSV_RAD_DECIMALS = 10


def write_csv(program: Program, name: str) -> dict[str, str]:
    """``{name.csv: text}``."""
    lines = [f"# {line}" for line in header_lines(program, "degrees (_deg) and radians (_rad)")]
    cols = ["step", "kind", "pose", "dwell_s"]
    cols += [f"{j}_deg" for j in program.joint_names] + [f"{j}_rad" for j in program.joint_names]
    lines.append(",".join(cols))
    for k, step in enumerate(steps(program), start=1):
        dwell = program.dwell if step.kind == "pose" else 0.0
        row = [str(k), step.kind, "" if step.pose is None else str(step.pose), f"{dwell:.2f}"]
        row += [f"{v:.{DEG_DECIMALS}f}" for v in np.rad2deg(step.q)]
        row += [f"{v:.{CSV_RAD_DECIMALS}f}" for v in step.q]
        lines.append(",".join(row))
    return {f"{name}.csv": "\n".join(lines) + "\n"}
