"""Design files: one measurement configuration per row, header = URDF joint names.

A plain CSV every robot controller tool can read (docs/data_format.md)::

    # calib_oed design v1
    # units: angle=rad length=m
    joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6
    0.1234,-1.2,...

Lines starting with ``#`` are comments, except the ``# units:`` line: the
unit of the revolute joints, ``angle=rad`` or ``angle=deg``, and of the
prismatic joints, ``length=m`` or ``length=mm``. Without it a design file is
in rad and m (the files of calib_oed versions before the units line). Columns
may come in any order; every joint of the robot must be present, nothing else.
A ``# joints: controller <name>`` line (before the header) says the values
are controller joint values (the scene's ``controller:`` block,
:mod:`calib_oed.model.controller`, :math:`q = A c + b`); written on request
(``controller=``, ``calib-oed design --controller``) and mapped back to URDF
joints on reading (an error without the block). Repeated rows are allowed (a pose measured twice) and reported as a
:class:`~calib_oed.exceptions.CalibOedNote`.
"""

from __future__ import annotations

import csv
import io
import os
import re
import warnings
from pathlib import Path

import numpy as np
import yaml

from calib_oed.exceptions import CalibOedNote, InputFileError, MeasurementFileError
from calib_oed.io.atomic import atomic_write_text
from calib_oed.io.repeats import describe_repeats, repeated_rows
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.robot import Robot
from calib_oed.scene.yaml_file import MAX_YAML_BYTES, load_yaml_file, read_text_file
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS

_UNITS_RE = re.compile(r"#\s*units\s*:(.*)$", re.IGNORECASE)
_JOINTS_RE = re.compile(r"#\s*joints\s*:(.*)$", re.IGNORECASE)
_DEFAULT_UNITS = {"angle": "rad", "length": "m"}


def _to_si(robot: Robot, units: dict[str, str]) -> np.ndarray:
    """Per-joint factor from the file's units to SI (rad, m), shape (nq,)."""
    return np.where(robot.prismatic, LENGTH_UNITS[units["length"]], ANGLE_UNITS[units["angle"]])


def write_design_csv(path: str | os.PathLike, robot: Robot, q: np.ndarray, comment: str | None = None,
                     angle_unit: str = "rad",
                     controller: ControllerConvention | None = None) -> Path:
    """Write configurations ``q`` (n, nq) [rad, m] atomically, revolute joints in ``angle_unit``.

    The ``# units:`` line states the units; prismatic joints are written in m.
    With ``controller`` the values are controller values
    :math:`c = A^{-1}(q - b)`, stated by a ``# joints: controller <name>`` line.

    Raises:
        MeasurementFileError: ``angle_unit`` is not one of ``ANGLE_UNITS``.
    """
    if angle_unit not in ANGLE_UNITS:
        raise MeasurementFileError(str(path), [(None, f"angle unit {angle_unit!r}; valid angle units are "
                                                      f"{', '.join(map(repr, ANGLE_UNITS))}")],
                                   kind="design file")
    q = robot.check_configurations(q, "design")
    units = {"angle": angle_unit, "length": "m"}
    values = (q if controller is None else controller.to_controller(q)) / _to_si(robot, units)
    buf = io.StringIO()
    buf.write("# calib_oed design v1\n")
    buf.write(f"# units: angle={units['angle']} length={units['length']}\n")
    if controller is not None:
        buf.write(f"# joints: controller {controller.name}\n# {controller.describe()}\n")
    if comment:
        for line in comment.splitlines():
            buf.write(f"# {line}\n")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(robot.joint_names)
    for row in values:
        writer.writerow([repr(float(v)) for v in row])
    return atomic_write_text(path, buf.getvalue())


def _units_line(number: int, text: str, problems: list) -> dict[str, str]:
    valid = {"angle": ANGLE_UNITS, "length": LENGTH_UNITS}
    units: dict[str, str] = {}
    for token in re.sub(r"\s*=\s*", "=", text).replace(",", " ").split():
        key, sep, value = token.partition("=")
        key, value = key.strip().lower(), value.strip()
        if not sep or key not in valid:
            problems.append((number, f"units: cannot read {token!r}; expected 'angle=<rad|deg> length=<m|mm>'"))
        elif value not in valid[key]:
            problems.append((number, f"units: unknown {key} unit {value!r}; valid {key} units are "
                                     f"{', '.join(map(repr, valid[key]))}"))
        elif key in units:
            problems.append((number, f"units: {key} is given twice"))
        else:
            units[key] = value
    return units


def read_design_csv(path: str | os.PathLike, robot: Robot, check_limits: bool = True,
                    controller: ControllerConvention | None = None) -> np.ndarray:
    """Read a design file; returns (n, nq) [rad, m] in the robot's joint order.

    Warns:
        CalibOedNote: rows that repeat an earlier row (allowed: a pose measured twice).

    Raises:
        MeasurementFileError: missing/unknown/duplicate joint columns, a bad units
            line, bad numbers, out-of-limit values (with line numbers); nothing is half-read.
    """
    source = str(path)
    try:
        text = read_text_file(path, "design file")
    except InputFileError as exc:
        raise MeasurementFileError(source, [(None, exc.problem)],
                                   kind="design file") from exc
    problems: list[tuple[int | None, str]] = []
    header, header_line, rows = None, None, []
    units, units_line, ctrl = dict(_DEFAULT_UNITS), None, None
    for number, line in enumerate(text.splitlines(), start=1):
        directive = _UNITS_RE.match(line.strip())
        if directive:
            if units_line is not None:
                problems.append((number, f"second '# units:' line (the first is line {units_line})"))
            elif header is not None:
                problems.append((number, "the '# units:' line must come before the column header"))
            else:
                units_line = number
                units.update(_units_line(number, directive.group(1), problems))
            continue
        joints = _JOINTS_RE.match(line.strip())
        if joints and header is None:
            ctrl = _joints_line(number, joints.group(1).split(), controller, problems)
            continue
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
    another = bool(unknown) and not set(names) & set(header)  # the joints of another robot
    if another:
        problems.append((header_line, f"unknown column(s) {unknown}, none of the robot {robot.name}'s "
                         f"joints {names}: a design of another robot?"))
    elif unknown:
        problems.append((header_line, f"unknown column(s) {unknown}; the robot's joints are {names}"))
    if missing and not another:
        problems.append((header_line, f"missing joint column(s) {missing}"))
    if dupes:
        problems.append((header_line, f"duplicate column(s) {dupes}"))
    if problems:
        raise MeasurementFileError(source, problems, kind="design file")
    order = [header.index(n) for n in names]
    scale = _to_si(robot, units)
    shown = np.where(robot.prismatic, units["length"], units["angle"])
    q = np.empty((len(rows), len(names)))
    for k, (number, fields) in enumerate(rows):
        if len(fields) != len(header):
            problems.append((number, f"{len(fields)} fields, expected {len(header)}"))
            continue
        try:
            vals = np.array([float(fields[i]) for i in order]) * scale
        except ValueError:
            problems.append((number, "a value is not a number"))
            continue
        if not np.all(np.isfinite(vals)):
            problems.append((number, "NaN or infinite value"))
            continue
        if ctrl is not None:
            vals = ctrl.to_model(vals)
        if check_limits:
            bad = np.flatnonzero((vals < robot.lower - 1e-9) | (vals > robot.upper + 1e-9))
            for i in bad:
                problems.append((number, f"{names[i]} = {vals[i] / scale[i]:.6g} {shown[i]} outside the "
                                         f"limits [{robot.lower[i] / scale[i]:.6g}, "
                                         f"{robot.upper[i] / scale[i]:.6g}] {shown[i]}"
                                         + ("" if units_line else " (no '# units:' line: read as rad and m; in degrees? "
                                                                 "add '# units: angle=deg')")))
        q[k] = vals
    if not rows:
        problems.append((header_line, "no configurations after the header"))
    if problems:
        raise MeasurementFileError(source, problems, kind="design file")
    _note_repeats(source, [number for number, _ in rows], q)
    return q


def read_design_file(path: str | os.PathLike, robot: Robot, check_limits: bool = True,
                     controller=None) -> np.ndarray:
    """Configurations (n, nq) [rad] of a design file, in ``robot``'s joint order.

    Accepts what :func:`calib_oed.oed.result.write_design` writes: ``design.yaml`` (its
    ``joint_names`` and ``configurations_rad``) or a design CSV (header = joint
    names, rad), recognised by the suffix (``.yaml``/``.yml``, else CSV). A CSV in
    controller joint values (``# joints: controller <name>``) is mapped to URDF joints
    with ``controller``, the scene's :class:`~calib_oed.model.controller.ControllerConvention`.

    Raises:
        MeasurementFileError: unreadable file, not a calib_oed design, joint
            names that are not the robot's, bad or out-of-limit values.
    """
    path = Path(path)
    if path.is_dir():
        raise MeasurementFileError(str(path), [(None, "is a folder; give its design.yaml or design.csv")],
                                   kind="design file")
    if path.suffix.lower() not in (".yaml", ".yml"):
        return read_design_csv(path, robot, check_limits=check_limits, controller=controller)
    source = str(path)

    def fail(message: str) -> MeasurementFileError:
        return MeasurementFileError(source, [(None, message)], kind="design file")

    try:
        data = load_yaml_file(path, "design file", MAX_YAML_BYTES)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise fail(f"cannot read the design YAML ({exc})") from exc
    if not isinstance(data, dict) or not str(data.get("format", "")).startswith("calib_oed design"):
        raise fail("not a calib_oed design YAML (expected 'format: calib_oed design v1', "
                   "'joint_names' and 'configurations_rad', as `calib-oed design -o DIR` writes)")
    if "robot" in data and str(data["robot"]).lower() != robot.name.lower():
        raise fail(f"a design of robot {data['robot']!r}, not of this scene's robot {robot.name!r}")
    names = data.get("joint_names")
    rows = data.get("configurations_rad")
    if not isinstance(names, list) or sorted(map(str, names)) != sorted(robot.joint_names):
        raise fail(f"joint_names {names} are not the robot's joints {list(robot.joint_names)}")
    try:
        q = np.array(rows, dtype=float)
    except (TypeError, ValueError) as exc:
        raise fail(f"configurations_rad is not a table of numbers ({exc})") from exc
    if q.ndim != 2 or q.shape[0] < 1 or q.shape[1] != len(names):
        raise fail(f"configurations_rad must be n >= 1 rows of {len(names)} values, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise fail("configurations_rad holds NaN or infinite values")
    q = q[:, [list(map(str, names)).index(j) for j in robot.joint_names]]
    if check_limits:
        bad = np.argwhere((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))
        if bad.size:
            raise MeasurementFileError(source, [
                (None, f"pose {k}: {robot.joint_names[i]} = {q[k, i]:.6g} outside the limits "
                       f"[{robot.lower[i]:.6g}, {robot.upper[i]:.6g}] (rad, or m if prismatic)")
                for k, i in bad], kind="design file")
    return q


def _joints_line(number: int, words: list[str], controller, problems: list):
    """The convention of a ``# joints: urdf | controller <name>`` line (None: URDF)."""
    if words == ["urdf"]:
        return None
    if not words or words[0].lower() != "controller" or len(words) > 2:
        problems.append((number, f"joints: cannot read {' '.join(words)!r}; expected 'urdf' or "
                                 "'controller <name>'"))
    elif controller is None:
        problems.append((number, "the values are in controller convention but no controller "
                                 "convention is given: add a 'controller:' block to the scene "
                                 "(docs/scenes.md)"))
    elif len(words) == 2 and words[1] != controller.name:
        problems.append((number, f"joints: file in the convention of controller {words[1]!r}, "
                                 f"the scene's block is {controller.name!r}"))
    else:
        return controller
    return None


def _note_repeats(source: str, lines: list[int], q: np.ndarray) -> None:
    """A note naming the rows that repeat an earlier row exactly."""
    repeats = repeated_rows(lines, q)
    if repeats:
        warnings.warn(CalibOedNote(
            f"{source}: {len(repeats)} row(s) repeat an earlier row ({describe_repeats(repeats)}); "
            "each is measured as often as it appears"), stacklevel=3)
