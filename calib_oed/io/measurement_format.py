r"""Measured data from a laser-tracker session: a CSV file format, read and written.

A measurement file holds, per row, the joint configuration :math:`q` the robot
was commanded to (or reported) and what the tracker measured there: the
position of one reflector in the **tracker frame** :math:`T` (what the
instrument reports, and what :class:`~calib_oed.measurement.TrackerPosition`
models), optionally a 6-DoF probe's orientation (as
:class:`~calib_oed.measurement.PoseMeasurement` models) and a per-row standard
deviation. :func:`~calib_oed.io.measurement_reader.read_measurements` returns a :class:`~calib_oed.measurement.dataset.MeasurementSet` (SI,
[m, rad]); :meth:`~calib_oed.measurement.dataset.MeasurementSet.blocks` turns it into the
:class:`~calib_oed.measurement.observations.ObservationBlock` list the estimator consumes.

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
    ``length_unit=`` and ``angle_unit=`` of :func:`read_measurements` (``--length-unit``,
    ``--angle-unit``) stand in for a missing line or key; one that contradicts the line is
    an error; without either the file is rejected.
  - ``# robot: <name>``: the robot measured; when given, it must be the name of the
    robot the file is read for (case ignored).
  - ``# joints: controller [<name>]``: the joint columns hold **controller**
    values (signs, offsets, scales, couplings of the scene's ``controller:``
    block, :mod:`calib_oed.model.controller`), in the file's angle unit; the
    reader maps them to URDF joints, :math:`q = A c + b`, before checking
    limits. ``<name>``, if given, must be the block's name. ``# joints: urdf``
    (the default) says URDF joint values. A file never silently takes the
    scene's block: without the directive the values are URDF angles.

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

This module owns the format: this specification and its constants. The
reader is :func:`calib_oed.io.measurement_reader.read_measurements`, the
writer :func:`calib_oed.io.measurement_writer.write_measurements`, the record
both speak :class:`calib_oed.measurement.dataset.MeasurementSet`.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

FORMAT_VERSION = 1
#: Tolerance on the joint limits [rad or m]: absorbs the rounding of unit conversions.
LIMIT_TOL = 1e-9
POSITION_COLUMNS = ("x", "y", "z")
ROTATION_COLUMNS = ("rx", "ry", "rz")
REFLECTOR_COLUMN = "reflector"
SIGMA_COLUMN = "sigma"
#: Farthest a laser tracker measures [m] (the longest-range trackers reach 160 m): a
#: coordinate beyond it is a wrong number or unit.
MAX_TRACKER_RANGE = 160.0
#: Largest per-row sigma accepted [m]; a tracker's is micrometres.
MAX_SIGMA = 0.01

_VERSION_RE = re.compile(r"#\s*calib_oed\s+measurements\b\s*(.*)$", re.IGNORECASE)
_DIRECTIVE_RE = re.compile(r"#\s*(units|robot|joints)\s*:(.*)$", re.IGNORECASE)


def _reflector_names(names: Sequence[str]) -> tuple[str, ...]:
    if isinstance(names, str):
        names = (names,)
    out = tuple(str(n).strip() for n in names)
    if not out or any(not n for n in out) or len(set(out)) != len(out):
        raise ValueError(f"reflector_names: expected distinct non-empty names, got {names!r}")
    return out
