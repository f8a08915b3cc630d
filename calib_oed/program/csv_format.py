"""A CSV of the ordered program: every target with its joint angles in degrees and radians.

Columns: ``step, kind, pose, dwell_s``, then ``<joint>_deg`` (joint values in
degrees: the controller's if the scene has a ``controller:`` block, else the
URDF's, as the header says) and ``<joint>_rad`` (the same in radians), one row
per target (home, via point, measurement pose); ``#`` lines carry the header.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.program.format_common import CONTROLLER_VALUES, DEG_DECIMALS, header_lines, steps
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


class ProgramTargets(NamedTuple):
    """The targets of a program CSV, read back (:func:`read_program_csv`).

    Attributes:
        kinds: ``"home"``, ``"via"`` or ``"pose"`` per target, in program order.
        poses: Pose number (1-based design row) of each target, 0 for home and via points.
        q: URDF joint values [rad], (k, nq) (controller values mapped back).
        dwell: Dwell per target [s], (k,).
        path: The file read.
    """

    kinds: tuple[str, ...]
    poses: np.ndarray
    q: np.ndarray
    dwell: np.ndarray
    path: Path


def find_program_csv(where: str | os.PathLike) -> Path:
    """The program CSV ``where`` names: the file itself, or the one ``*.csv`` in a folder."""
    path = Path(where)
    if path.is_dir():
        found = sorted(path.glob("*.csv"))
        if len(found) != 1:
            raise ProgramError("program", str(path), f"{len(found)} CSV files in the folder: the viewer "
                               "reads the program's CSV (write it with `calib-oed program SCENE DESIGN "
                               "--format csv -o DIR`; the controller formats are not read back), or "
                               "give the CSV file itself", [p.name for p in found])
        return found[0]
    if not path.is_file():
        raise ProgramError("program", str(path), "no such file or folder")
    return path


def read_program_csv(where: str | os.PathLike, joint_names, controller=None) -> ProgramTargets:
    """Read a program CSV written by :func:`write_csv` (a file, or a folder holding one).

    Args:
        where: The CSV, or the folder ``calib-oed program ... --format csv -o DIR`` wrote.
        joint_names: The robot's joints; the file's ``<joint>_rad`` columns must be these.
        controller: The scene's :class:`~calib_oed.model.controller.ControllerConvention`;
            required when the file holds controller values (its header says so), which are
            mapped back to URDF angles :math:`q = A c + b`.

    Raises:
        ProgramError: not a program CSV, other joints, a bad value, or controller values
            without a controller block in the scene.
    """
    path = find_program_csv(where)
    lines = path.read_text(encoding="utf-8").splitlines()
    header = [ln for ln in lines if ln.startswith("#")]
    rows = [ln.split(",") for ln in lines if ln.strip() and not ln.startswith("#")]
    names = list(joint_names)
    want = ["step", "kind", "pose", "dwell_s"] + [f"{j}_deg" for j in names] + [f"{j}_rad" for j in names]
    if not rows or rows[0] != want:
        raise ProgramError("program", str(path), "not a program CSV of this robot: expected the "
                           f"columns {','.join(want)}; the file has "
                           f"{','.join(rows[0]) if rows else 'no rows'}")
    body = rows[1:]
    try:
        kinds = tuple(r[1] for r in body)
        poses = np.array([int(r[2]) if r[2] else 0 for r in body], dtype=int)
        dwell = np.array([float(r[3]) for r in body])
        q = np.array([[float(x) for x in r[4 + len(names):]] for r in body]).reshape(len(body), len(names))
    except (ValueError, IndexError) as exc:
        raise ProgramError("program", str(path), f"a row cannot be read ({exc})") from exc
    bad = sorted(set(kinds) - {"home", "via", "pose"})
    if bad or len(body) < 2 or not np.all(np.isfinite(q)):
        raise ProgramError("program", str(path), "rows must be home, via or pose targets with finite "
                           f"joint values (at least two){': unknown kinds ' + str(bad) if bad else ''}")
    if any(CONTROLLER_VALUES in ln for ln in header):
        if controller is None:
            raise ProgramError("program", str(path), "the file holds controller joint values but the "
                               "scene has no controller: block to map them back to URDF angles")
        q = controller.to_model(q)
    return ProgramTargets(kinds, poses, q, dwell, path)
