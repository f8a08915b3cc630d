"""Writing measurement files (format: :mod:`calib_oed.io.measurement_format`), atomically."""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from calib_oed.exceptions import ExportError, ShapeError, UnknownJointError
from calib_oed.io.atomic import atomic_write_text
from calib_oed.io.measurement_format import (
    _DIRECTIVE_RE,
    _VERSION_RE,
    FORMAT_VERSION,
    POSITION_COLUMNS,
    REFLECTOR_COLUMN,
    ROTATION_COLUMNS,
    SIGMA_COLUMN,
    _reflector_names,
)
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.robot import Robot
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS


def write_measurements(
    path: str | os.PathLike,
    data: MeasurementSet | Mapping[str, Any],
    robot: Robot,
    reflector_names: Sequence[str] = ("smr0",),
    *,
    length_unit: str = "mm",
    angle_unit: str = "deg",
    comment: str | None = None,
    controller: ControllerConvention | None = None,
) -> Path:
    """Write measurements in the file format of this module, atomically.

    Every number is written with ``repr`` (the shortest text that reads back
    to the same float in the file's units), so reading the file back gives the
    SI values to within the rounding of one unit conversion each way.

    Args:
        path: The file to write (replaced if it exists).
        data: A :class:`MeasurementSet`, or a mapping of
            :meth:`MeasurementSet.from_arrays` keyword arguments
            (``q``, ``positions``, optional ``reflector``, ``sigma``, ``rotations``).
        robot: The robot; its joint names are the joint columns.
        reflector_names: Names written in the ``reflector`` column.
        length_unit: ``"m"`` or ``"mm"``.
        angle_unit: ``"rad"`` or ``"deg"``.
        comment: Free text written as ``#`` lines before the column header.
        controller: Write controller joint values :math:`c = A^{-1}(q - b)`
            (in ``angle_unit``) under a ``# joints: controller <name>`` line.

    Returns:
        The path written.

    Raises:
        ExportError: invalid unit, reflector index without a name, a comment
            line that reads as a directive, or the folder is not writable.
        UnknownJointError, ShapeError: the set's joints are not the robot's.
    """
    names = _reflector_names(reflector_names)
    mset = data if isinstance(data, MeasurementSet) else MeasurementSet.from_arrays(robot, **data)
    for name in mset.joint_names:
        if name not in robot.joint_names:
            raise UnknownJointError(name, robot.joint_names)
    if len(mset.joint_names) != robot.nq:
        raise ShapeError("q", f"(n, {robot.nq}) for the joints {robot.joint_names}",
                         mset.q.shape)
    for key, unit, table in (("length", length_unit, LENGTH_UNITS),
                             ("angle", angle_unit, ANGLE_UNITS)):
        if unit not in table:
            raise ExportError(f"{key}_unit={unit!r}: valid {key} units are "
                              f"{', '.join(map(repr, table))}")
    if mset.reflector.max() >= len(names):
        raise ExportError(f"reflector index {int(mset.reflector.max())} has no name; "
                          f"reflector_names gives {len(names)}: {', '.join(names)}")
    length, angle = LENGTH_UNITS[length_unit], ANGLE_UNITS[angle_unit]
    prismatic = robot.prismatic
    order = [mset.joint_names.index(j) for j in robot.joint_names]
    q = mset.q[:, order]
    q = (q if controller is None else controller.to_controller(q)) / np.where(prismatic, length, angle)

    out = io.StringIO()
    out.write(f"# calib_oed measurements v{FORMAT_VERSION}\n")
    out.write(f"# units: length={length_unit} angle={angle_unit}\n")
    out.write(f"# robot: {robot.name}\n")
    if controller is not None:
        out.write(f"# joints: controller {controller.name}\n# {controller.describe()}\n")
    for line in (comment or "").splitlines():
        text = f"# {line}".rstrip()
        if _VERSION_RE.match(text) or _DIRECTIVE_RE.match(text):
            raise ExportError(f"comment line {line!r} would be read as a directive; reword it")
        out.write(text + "\n")
    header = [*robot.joint_names, REFLECTOR_COLUMN, *POSITION_COLUMNS]
    blocks = [q, mset.positions / length]
    if mset.rotations is not None:
        header += ROTATION_COLUMNS
        blocks.append(mset.rotations / angle)
    if mset.sigma is not None:
        header.append(SIGMA_COLUMN)
        blocks.append(mset.sigma[:, None] / length)
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    numbers = np.hstack(blocks)
    nq = robot.nq
    for k in range(mset.n):
        text = [repr(float(v)) for v in numbers[k]]
        writer.writerow([*text[:nq], names[mset.reflector[k]], *text[nq:]])
    return atomic_write_text(path, out.getvalue())
