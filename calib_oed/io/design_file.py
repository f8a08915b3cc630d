"""Design files: one measurement configuration per row, header = URDF joint names, radians.

A plain CSV every robot controller tool can read::

    # calib_oed design v1: configurations in rad (prismatic joints in m)
    joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6
    0.1234,-1.2,...

Lines starting with ``#`` are comments. Columns may come in any order; every
joint of the robot must be present, nothing else.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from calib_oed.exceptions import MeasurementFileError
from calib_oed.io.atomic import atomic_write_text
from calib_oed.model.robot import Robot


def write_design_csv(path: str | os.PathLike, robot: Robot, q: np.ndarray, comment: str | None = None) -> Path:
    """Write configurations ``q`` (n, nq) [rad] atomically."""
    q = robot.check_configurations(q, "design")
    buf = io.StringIO()
    buf.write("# calib_oed design v1: configurations in rad (prismatic joints in m)\n")
    if comment:
        for line in comment.splitlines():
            buf.write(f"# {line}\n")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(robot.joint_names)
    for row in q:
        writer.writerow([repr(float(v)) for v in row])
    return atomic_write_text(path, buf.getvalue())


def read_design_csv(path: str | os.PathLike, robot: Robot, check_limits: bool = True) -> np.ndarray:
    """Read a design file; returns (n, nq) [rad] in the robot's joint order.

    Raises:
        MeasurementFileError: missing/unknown/duplicate joint columns, bad numbers,
            out-of-limit values (with line numbers); nothing is half-read.
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise MeasurementFileError(source, [(None, f"cannot read the design file ({exc})")],
                                   kind="design file") from exc
    problems: list[tuple[int | None, str]] = []
    header, header_line, rows = None, None, []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = next(csv.reader([line]))
        if header is None:
            header, header_line = [f.strip() for f in fields], number
            continue
        rows.append((number, fields))
    if header is None:
        raise MeasurementFileError(source, [(None, "no header line with the joint names")], kind="design file")
    names = list(robot.joint_names)
    unknown = [h for h in header if h not in names]
    missing = [n for n in names if n not in header]
    dupes = sorted({h for h in header if header.count(h) > 1})
    if unknown:
        problems.append((header_line, f"unknown column(s) {unknown}; the robot's joints are {names}"))
    if missing:
        problems.append((header_line, f"missing joint column(s) {missing}"))
    if dupes:
        problems.append((header_line, f"duplicate column(s) {dupes}"))
    if problems:
        raise MeasurementFileError(source, problems, kind="design file")
    order = [header.index(n) for n in names]
    q = np.empty((len(rows), len(names)))
    for k, (number, fields) in enumerate(rows):
        if len(fields) != len(header):
            problems.append((number, f"{len(fields)} fields, expected {len(header)}"))
            continue
        try:
            vals = np.array([float(fields[i]) for i in order])
        except ValueError:
            problems.append((number, "a value is not a number"))
            continue
        if not np.all(np.isfinite(vals)):
            problems.append((number, "NaN or infinite value"))
            continue
        if check_limits:
            bad = np.flatnonzero((vals < robot.lower - 1e-9) | (vals > robot.upper + 1e-9))
            for i in bad:
                problems.append((number, f"{names[i]} = {vals[i]:.6g} outside the limits "
                                         f"[{robot.lower[i]:.6g}, {robot.upper[i]:.6g}] (rad, or m if prismatic)"))
        q[k] = vals
    if not rows:
        problems.append((header_line, "no configurations after the header"))
    if problems:
        raise MeasurementFileError(source, problems, kind="design file")
    return q
