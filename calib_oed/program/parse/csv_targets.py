r"""A CSV of targets: the project's program CSV (joints), or Cartesian targets.

Rows after the header (the first line not starting with ``#``; ``#`` lines are comments)
are targets, in order. Joint targets: the robot's joints as columns ``<joint>_rad`` and/or
``<joint>_deg`` (:mod:`calib_oed.program.csv_format` writes both; both are rewritten, from
the same compensated joints, read from the radians when both are there). Cartesian targets: columns ``x_mm, y_mm, z_mm, rx_deg,
ry_deg, rz_deg`` (fixed XYZ angles, :math:`R = R_z(rz)R_y(ry)R_x(rx)`). A ``name`` or
``step`` column names the target. Comments are ``#`` lines after the row.
"""

from __future__ import annotations

import math

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse.poses import from_euler_mm_deg, in_order, to_euler_mm_deg
from calib_oed.program.parse.scan import Number
from calib_oed.program.parse.targets import Language, ParsedProgram, Target

POSE_COLUMNS = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")


LANGUAGE = Language("csv", "rad", *in_order(from_euler_mm_deg, to_euler_mm_deg), lambda text: f"# {text}", (10, 4, 6))


def _cells(line: str, offset: int) -> list[Number]:
    out, start = [], offset
    for cell in line.split(","):
        stripped = cell.strip()
        lead = len(cell) - len(cell.lstrip())
        out.append(Number(start + lead, start + lead + len(stripped), stripped))
        start += len(cell) + 1
    return out


#: Largest difference [deg] between a joint's ``_deg`` cell and its ``_rad`` cell: the writer's rounding
#: is 5e-5 deg; a hand edit of one column only is far above it.
DEG_RAD_TOL = 1e-3


def _agree(file: str, i: int, joint_names, nums) -> None:
    n = len(joint_names)
    for name, rad, deg in zip(joint_names, nums[:n], nums[n:], strict=True):
        if abs(math.degrees(rad.value) - deg.value) > DEG_RAD_TOL:
            raise ProgramError("program", file, f"line {i + 1}: {name}_deg {deg.text} and {name}_rad {rad.text} "
                               f"(= {math.degrees(rad.value):.4f} deg) disagree: edit both columns, or delete "
                               "one of them")


def parse(texts: dict[str, str], joint_names) -> ParsedProgram:
    """Targets of CSV files ``{name.csv: text}`` for a robot with ``joint_names``."""
    targets = []
    for file, text in texts.items():
        header, offset = None, 0
        for i, raw in enumerate(text.splitlines(keepends=True)):
            line = raw.rstrip("\r\n")
            start, offset = offset, offset + len(raw)
            if not line.strip() or line.startswith("#"):
                continue
            if header is None:
                header = [c.strip() for c in line.split(",")]
                rad = [f"{j}_rad" for j in joint_names]
                deg = [f"{j}_deg" for j in joint_names]
                groups = [(cols, unit) for cols, unit in ((rad, "rad"), (deg, "deg")) if set(cols) <= set(header)]
                pose = set(POSE_COLUMNS) <= set(header)
                if not groups and not pose:
                    raise ProgramError("program", file, "a target CSV needs the columns "
                                       f"{','.join(rad)} (or _deg), or {','.join(POSE_COLUMNS)}; it has "
                                       f"{','.join(header)}")
                name_col = next((header.index(c) for c in ("name", "step") if c in header), None)
                continue
            cells = _cells(line, start)
            if len(cells) != len(header):
                raise ProgramError("program", file, f"line {i + 1}: {len(cells)} cells, the header has {len(header)}")
            name = cells[name_col].text if name_col is not None else f"{file} line {i + 1}"
            try:
                if pose:
                    nums = tuple(cells[header.index(c)] for c in POSE_COLUMNS)
                    [n.value for n in nums]
                    targets.append(Target(name, "pose", file, i, nums))
                if groups:
                    nums = tuple(cells[header.index(c)] for cols, _ in groups for c in cols)
                    [n.value for n in nums]
                    if len(groups) == 2:  # both written from the same joints: an edit of one is refused
                        _agree(file, i, joint_names, nums)
                    unit = "+".join(u for _, u in groups)
                    targets.append(Target(name, "joint", file, i, nums, unit=unit, commented=not pose))
            except ValueError as exc:
                raise ProgramError("program", file, f"line {i + 1}: a target value is not a number ({exc})") from exc
    return ParsedProgram(LANGUAGE, dict(texts), tuple(targets))
