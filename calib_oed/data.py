r"""Measured data from a laser-tracker session: a CSV file format, read and written.

A measurement file holds, per row, the joint configuration :math:`q` the robot
was commanded to (or reported) and what the tracker measured there: the
position of one reflector in the **tracker frame** :math:`T` (what the
instrument reports, and what :class:`~calib_oed.measurements.TrackerPosition`
models), optionally a 6-DoF probe's orientation (as
:class:`~calib_oed.measurements.PoseMeasurement` models) and a per-row standard
deviation. :func:`read_measurements` returns a :class:`MeasurementSet` (SI,
[m, rad]); :meth:`MeasurementSet.blocks` turns it into the
:class:`~calib_oed.observations.ObservationBlock` list the estimator consumes.

File format, version 1 (also in ``docs/data_format.md``)::

    # calib_oed measurements v1
    # units: length=mm angle=deg
    # robot: kr16
    joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6,reflector,x,y,z,sigma
    10.0,-80.0,95.0,0.0,30.0,0.0,smr0,1234.5678,-210.25,455.0,0.01

- UTF-8 text (a leading byte-order mark is ignored), one record per line
  (``\n``, ``\r\n`` or ``\r``); line numbers in error messages count every
  line from 1. Fields are separated by commas and read with :mod:`csv`
  (double quotes allowed; a quoted field must not span lines). Spaces around
  fields are ignored.
- Blank lines are ignored. A line whose first non-blank character is ``#``
  is a comment. Three comments are directives, recognised (keyword case
  ignored) only **before** the column header; after it they are an error:

  - ``# calib_oed measurements v1``: format version; optional, written by
    :func:`write_measurements`; any version other than 1 is an error.
  - ``# units: length=<m|mm> angle=<rad|deg>``: the file's units, both keys
    required, separated by spaces or commas. The keyword arguments
    ``length_unit=`` and ``angle_unit=`` of :func:`read_measurements` override
    it or stand in for it; without either the file is rejected.
  - ``# robot: <name>``: informative only (not checked).

- The first other line is the **column header**. Columns, in any order, each
  at most once:

  ===============  ========  ==========================================================
  column           unit      meaning
  ===============  ========  ==========================================================
  <joint name>     A or L    one column per robot joint, URDF names (``Robot.joint_names``);
                             revolute joints in the angle unit A, prismatic in the length unit L
  ``reflector``    --        optional: a name from ``reflector_names`` or a 0-based index
                             into it (names first); without the column every row is reflector 0
  ``x, y, z``      L         measured reflector centre in the tracker frame
  ``rx, ry, rz``   A         optional, all three or none: rotation vector
                             :math:`\log_3 R_{T,P}` of the probe in the tracker frame
                             (``pin.log3``, norm at most 180 deg); present, every row
                             is a 6-D pose measurement
  ``sigma``        L         optional: standard deviation of each position coordinate
                             of the row, > 0
  ===============  ========  ==========================================================

  Any other column is an error.
- Every following non-comment line is a data row with exactly as many fields
  as the header. Numbers are Python floats (``1.5``, ``-2e-3``); empty fields,
  NaN and infinities are errors. Joint values must lie within the robot's
  limits (``Robot.lower``, ``Robot.upper``, tolerance 1e-9 in SI) unless
  ``check_limits=False`` (checked once the units are known). At least one
  data row is required.

Nothing is half-read: :func:`read_measurements` checks the whole file and
raises one :class:`~calib_oed.exceptions.MeasurementFileError` listing every
problem with its line number (the header's for header problems, ``None`` for
the file as a whole).

This module owns the format (its constants and this specification), the
:class:`MeasurementSet` record, :func:`read_measurements` and the writer
:func:`write_measurements`; the parser behind :func:`read_measurements` is in
:mod:`calib_oed.data_reader`.
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from calib_oed.exceptions import (
    ExportError,
    NonFiniteError,
    ShapeError,
    UnknownJointError,
)
from calib_oed.io_utils import atomic_write_text
from calib_oed.measurements.pose import DEFAULT_SIGMA_ANGLE, PoseMeasurement
from calib_oed.measurements.position import DEFAULT_SIGMA, TrackerPosition
from calib_oed.observations import ObservationBlock
from calib_oed.robot import Robot
from calib_oed.scene import ANGLE_UNITS, LENGTH_UNITS

FORMAT_VERSION = 1
#: Tolerance on the joint limits [rad or m]: absorbs the rounding of unit conversions.
LIMIT_TOL = 1e-9
POSITION_COLUMNS = ("x", "y", "z")
ROTATION_COLUMNS = ("rx", "ry", "rz")
REFLECTOR_COLUMN = "reflector"
SIGMA_COLUMN = "sigma"

_VERSION_RE = re.compile(r"#\s*calib_oed\s+measurements\b\s*(.*)$", re.IGNORECASE)
_DIRECTIVE_RE = re.compile(r"#\s*(units|robot)\s*:(.*)$", re.IGNORECASE)


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class MeasurementSet:
    """Measured rows of one session, SI throughout; arrays are read-only.

    Attributes:
        joint_names: The robot's joints, base to tip (columns of ``q``).
        q: Configurations, (n, nq) [rad, or m for prismatic joints].
        reflector: Reflector index of each row, (n,) int, 0-based.
        positions: Measured reflector centres in the tracker frame, (n, 3) [m].
        rotations: Measured probe rotation vectors :math:`\\log_3 R_{T,P}`, (n, 3)
            [rad], or ``None`` for position-only data.
        sigma: Standard deviation of each position coordinate per row, (n,) [m],
            or ``None`` to use the measurement model's.
        source: Where the rows came from (file name, ``"<string>"``, ``"<arrays>"``).
        lines: 1-based line number of each row in ``source`` (for arrays: the row
            number), (n,) int.
    """

    joint_names: tuple[str, ...]
    q: np.ndarray
    reflector: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray | None = None
    sigma: np.ndarray | None = None
    source: str = "<arrays>"
    lines: np.ndarray | None = None

    def __post_init__(self):
        names = tuple(str(j) for j in self.joint_names)
        q = np.array(self.q, dtype=float)
        if q.ndim != 2 or q.shape[0] < 1 or q.shape[1] != len(names):
            raise ShapeError("q", f"(n, {len(names)}) with n >= 1", q.shape)
        n = q.shape[0]
        positions = _finite(self.positions, "positions", (n, 3))
        rotations = None if self.rotations is None else _finite(self.rotations, "rotations", (n, 3))
        _finite(q, "q", q.shape)
        refl = np.asarray(self.reflector)
        if refl.shape != (n,):
            raise ShapeError("reflector", f"({n},)", refl.shape)
        if refl.dtype.kind not in "iuf" or np.any(np.mod(refl, 1) != 0):
            raise ValueError(f"reflector: expected integer indices, got {refl}")
        refl = refl.astype(np.int64)
        if np.any(refl < 0):
            raise ValueError(f"reflector: indices must be >= 0, got rows "
                             f"{np.flatnonzero(refl < 0).tolist()}")
        sigma = None
        if self.sigma is not None:
            sigma = np.asarray(self.sigma, dtype=float)
            sigma = _finite(np.full(n, sigma) if sigma.ndim == 0 else sigma, "sigma", (n,))
            if np.any(sigma <= 0):
                raise ValueError(f"sigma: every standard deviation must be > 0, rows "
                                 f"{np.flatnonzero(sigma <= 0).tolist()} are not")
        lines = np.arange(1, n + 1) if self.lines is None else np.asarray(self.lines, np.int64)
        if lines.shape != (n,):
            raise ShapeError("lines", f"({n},)", lines.shape)
        for name, value in (("joint_names", names), ("q", q), ("reflector", refl),
                            ("positions", positions), ("rotations", rotations),
                            ("sigma", sigma), ("lines", lines)):
            object.__setattr__(self, name, value if value is None or name == "joint_names"
                               else _frozen(value))

    @classmethod
    def from_arrays(
        cls,
        robot: Robot,
        q: np.ndarray,
        positions: np.ndarray,
        reflector: np.ndarray | int | None = None,
        sigma: np.ndarray | float | None = None,
        rotations: np.ndarray | None = None,
        source: str = "<arrays>",
    ) -> MeasurementSet:
        """A set from SI arrays: ``q`` (n, nq) in ``robot``'s joint order, ``positions`` (n, 3) [m].

        ``reflector`` (n,) or a scalar (default 0), ``sigma`` (n,) or a scalar [m],
        ``rotations`` (n, 3) [rad]. Joint limits are not checked here.

        Raises:
            ShapeError, NonFiniteError: arrays of the wrong shape or not finite.
            ValueError: negative reflector index, non-positive sigma.
        """
        q = robot.check_configurations(q)
        n = q.shape[0]
        refl = np.broadcast_to(np.asarray(0 if reflector is None else reflector), (n,))
        return cls(robot.joint_names, q, refl, np.array(positions, float, ndmin=2),
                   None if rotations is None else np.array(rotations, float, ndmin=2),
                   sigma, source)

    @property
    def n(self) -> int:
        """Number of rows."""
        return self.q.shape[0]

    @property
    def reflectors(self) -> tuple[int, ...]:
        """The reflector indices present, ascending (the order of :meth:`blocks`)."""
        return tuple(int(j) for j in np.unique(self.reflector))

    def blocks(
        self,
        sigma: float | np.ndarray = DEFAULT_SIGMA,
        sigma_angle: float | np.ndarray = DEFAULT_SIGMA_ANGLE,
    ) -> list[ObservationBlock]:
        """One observation block per reflector present, in :attr:`reflectors` order.

        Position rows give ``TrackerPosition(j, sigma)`` blocks, pose rows
        ``PoseMeasurement(j, sigma, sigma_angle)`` blocks with values
        ``(x, y, z, rx, ry, rz)``. Each block keeps the rows of its reflector in
        file order (their lines: ``self.lines[self.reflector == j]``). The
        per-row :attr:`sigma`, when present, replaces ``sigma`` on the position
        components; ``sigma_angle`` always applies to the rotation components.

        Args:
            sigma: Position noise per tracker axis [m], scalar or (3,).
            sigma_angle: Rotation noise per axis [rad], scalar or (3,) (pose rows only).
        """
        out = []
        for j in self.reflectors:
            rows = self.reflector == j
            if self.rotations is None:
                model = TrackerPosition(j, sigma)
                values = self.positions[rows]
            else:
                model = PoseMeasurement(j, sigma, sigma_angle)
                values = np.hstack([self.positions[rows], self.rotations[rows]])
            row_sigma = None
            if self.sigma is not None:
                row_sigma = np.tile(model.sigma, (int(rows.sum()), 1))
                row_sigma[:, :3] = self.sigma[rows, None]
            out.append(ObservationBlock(model, self.q[rows], values, row_sigma))
        return out


def _finite(value: Any, what: str, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.shape != tuple(shape):
        raise ShapeError(what, str(tuple(shape)), arr.shape)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(arr)).tolist())
    return arr


# ----------------------------------------------------------------------------- reading


def read_measurements(
    source: str | os.PathLike | IO[str],
    robot: Robot,
    reflector_names: Sequence[str] = ("smr0",),
    *,
    length_unit: str | None = None,
    angle_unit: str | None = None,
    check_limits: bool = True,
) -> MeasurementSet:
    """Read a measurement file (format in the module docstring) into SI arrays.

    Args:
        source: A path, or an open text stream (e.g. ``io.StringIO(text)``).
        robot: The measured robot; its joint names are the joint columns.
        reflector_names: Names of the reflectors, index ``j`` = reflector ``j``
            of the parameter space.
        length_unit: ``"m"`` or ``"mm"``; overrides the file's ``# units:`` line.
        angle_unit: ``"rad"`` or ``"deg"``; overrides the file's ``# units:`` line.
        check_limits: Reject joint values outside ``robot.lower``/``robot.upper``.

    Raises:
        MeasurementFileError: the file cannot be read or has any problem; the
            error's ``problems`` lists all of them with their line numbers.
    """
    # Imported here: data_reader imports this module (the record, the format constants).
    from calib_oed.data_reader import _read_text, _Reader

    names = _reflector_names(reflector_names)
    text, where = _read_text(source)
    return _Reader(robot, names, where, check_limits).read(text, length_unit, angle_unit)


def _reflector_names(names: Sequence[str]) -> tuple[str, ...]:
    if isinstance(names, str):
        names = (names,)
    out = tuple(str(n).strip() for n in names)
    if not out or any(not n for n in out) or len(set(out)) != len(out):
        raise ValueError(f"reflector_names: expected distinct non-empty names, got {names!r}")
    return out


# ----------------------------------------------------------------------------- writing


def write_measurements(
    path: str | os.PathLike,
    data: MeasurementSet | Mapping[str, Any],
    robot: Robot,
    reflector_names: Sequence[str] = ("smr0",),
    *,
    length_unit: str = "mm",
    angle_unit: str = "deg",
    comment: str | None = None,
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
    prismatic = [j.shortname().startswith("JointModelP") for j in robot.model.joints[1:]]
    order = [mset.joint_names.index(j) for j in robot.joint_names]
    q = mset.q[:, order] / np.where(prismatic, length, angle)

    out = io.StringIO()
    out.write(f"# calib_oed measurements v{FORMAT_VERSION}\n")
    out.write(f"# units: length={length_unit} angle={angle_unit}\n")
    out.write(f"# robot: {robot.name}\n")
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
