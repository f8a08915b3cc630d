r"""Reading a measurement file: :func:`read_measurements` and the parser behind it.

Owns turning the text of a file in the format of :mod:`calib_oed.io.measurement_format` (the
format is specified there and in ``docs/data_format.md``) into a
:class:`~calib_oed.measurement.dataset.MeasurementSet`: decoding the source
(:func:`_read_text`), parsing the fields (:func:`_parse_float`) and one pass
over the lines (:class:`_Reader`) that checks directives, units, the column
header and every row against the robot, collecting every problem before
raising one :class:`~calib_oed.exceptions.MeasurementFileError`. The format
constants are in :mod:`calib_oed.io.measurement_format`, the writer in
:mod:`calib_oed.io.measurement_writer`.
"""

from __future__ import annotations

import csv
import difflib
import math
import os
import re
import warnings
from collections.abc import Sequence
from typing import IO, NoReturn

import numpy as np

from calib_oed.exceptions import CalibOedNote, InputFileError, MeasurementFileError
from calib_oed.io.measurement_format import (
    _DIRECTIVE_RE,
    _VERSION_RE,
    FORMAT_VERSION,
    LIMIT_TOL,
    MAX_SIGMA,
    MAX_TRACKER_RANGE,
    POSITION_COLUMNS,
    REFLECTOR_COLUMN,
    ROTATION_COLUMNS,
    SIGMA_COLUMN,
    _reflector_names,
)
from calib_oed.io.repeats import describe_repeats, repeated_rows
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.robot import Robot
from calib_oed.scene.yaml_file import read_text_file
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS

# The rotation vector of pin.log3 has norm <= pi; allow for rounding in the file.
_MAX_ROTATION = math.pi + 1e-9


def _read_text(source) -> tuple[str, str]:
    if hasattr(source, "read"):
        where = str(getattr(source, "name", "<string>"))
        text = source.read()
        if isinstance(text, bytes):
            try:
                text = text.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise MeasurementFileError(where, [(None, f"not UTF-8 text ({exc})")]) from exc
    else:
        where = os.fspath(source)
        try:
            text = read_text_file(where, "measurement file")
        except InputFileError as exc:
            raise MeasurementFileError(where, [(None, exc.problem)]) from exc
    return text.removeprefix("\ufeff"), where


def _parse_float(text: str) -> float | str:
    """The value of a field, or a message saying why it is not a finite number."""
    text = text.strip()
    if not text:
        return "is empty"
    try:
        value = float(text)
    except ValueError:
        return f"is not a number: {text!r}"
    if math.isnan(value):
        return "is NaN"
    if math.isinf(value):
        return f"is infinite ({text})"
    return value


class _Reader:
    """One pass over a file's lines, collecting every problem."""

    def __init__(self, robot: Robot, reflector_names: tuple[str, ...], where: str,
                 check_limits: bool, controller: ControllerConvention | None = None):
        self.robot = robot
        self.controller = controller
        self.joints_controller = False  # the file says '# joints: controller'
        self.joints_line: int | None = None
        self.reflector_names = reflector_names
        self.where = where
        self.check_limits = check_limits
        self.problems: list[tuple[int | None, str]] = []
        self.units: dict[str, str] = {}
        self.units_bad: set[str] = set()  # keys of the units line with an invalid value
        self.units_line: int | None = None
        self.prismatic = robot.prismatic.tolist()

    def problem(self, line: int | None, message: str) -> None:
        self.problems.append((line, message))

    def read(self, text: str, length_unit: str | None, angle_unit: str | None) -> MeasurementSet:
        header: tuple[int, list[str]] | None = None
        data: list[tuple[int, list[str]]] = []
        for number, raw in enumerate(re.split(r"\r\n|\r|\n", text), start=1):
            line = raw.strip()
            if not line:
                continue
            if line.startswith("#"):
                directive = _VERSION_RE.match(line) or _DIRECTIVE_RE.match(line)
                if directive and header is not None:
                    self.problem(number, f"directive {line!r} must come before the column "
                                 f"header (line {header[0]})")
                elif directive and directive.re is _VERSION_RE:
                    self.version(number, directive.group(1).strip())
                elif directive and directive.group(1).lower() == "robot":
                    self.robot_directive(number, directive.group(2).strip())
                elif directive and directive.group(1).lower() == "joints":
                    self.joints_directive(number, directive.group(2).strip())
                elif directive and directive.group(1).lower() == "units":
                    if self.units_line is not None:
                        self.problem(number, f"second '# units:' line (the first is line "
                                     f"{self.units_line})")
                    else:
                        self.units_line = number
                        self.units_directive(number, directive.group(2))
                continue
            try:
                fields = next(csv.reader([line], skipinitialspace=True))
            except csv.Error as exc:
                self.problem(number, f"cannot split the line into fields ({exc})")
                continue
            if header is None:
                header = (number, [f.strip() for f in fields])
            else:
                data.append((number, fields))
        if header is None:
            self.problem(None, "no column header and no data rows (the file is empty or "
                         "holds only comments)")
            self.fail()
        scales = self.resolve_units(length_unit, angle_unit)
        self.header_line = header[0]
        columns = self.columns(*header)
        if columns is not None and not data:
            self.problem(header[0], "no data rows after the column header")
        rows = [self.row(number, fields, len(header[1]), columns, scales)
                for number, fields in data]
        if self.problems or columns is None:
            self.fail()
        return self.build(data, rows, columns, scales)

    def fail(self) -> NoReturn:
        problems = sorted(self.problems, key=lambda p: (p[0] is not None, p[0] or 0))
        raise MeasurementFileError(self.where, problems)

    # -- directives and units

    def version(self, number: int, text: str) -> None:
        if text.lower() != f"v{FORMAT_VERSION}":
            self.problem(number, f"unsupported format version {text!r}; this calib_oed reads "
                         f"'# calib_oed measurements v{FORMAT_VERSION}'")

    def robot_directive(self, number: int, text: str) -> None:
        """``# robot: <name>``: the file must be of the robot it is read for."""
        if text and text.lower() != self.robot.name.lower():  # nothing else is worth reading
            self.problems = [(number, f"the file is of robot {text!r}, the scene's robot is "
                              f"{self.robot.name!r}: give this robot's measurements (or correct the "
                              "'# robot:' line)")]
            self.fail()

    def joints_directive(self, number: int, text: str) -> None:
        """``# joints: urdf`` or ``# joints: controller [<name>]``."""
        words = text.split()
        if self.joints_line is not None:
            self.problem(number, f"second '# joints:' line (the first is line {self.joints_line})")
            return
        self.joints_line = number
        if words == ["urdf"]:
            return
        if not words or words[0].lower() != "controller" or len(words) > 2:
            self.problem(number, f"joints: cannot read {text!r}; expected 'urdf' or "
                         "'controller [<name>]'")
        elif self.controller is None:
            self.problem(number, "the joint values are in controller convention but no "
                         "controller convention is given: add a 'controller:' block to the "
                         "scene (docs/scenes.md) or pass controller=")
        elif len(words) == 2 and words[1] != self.controller.name:
            self.problem(number, f"joints: the file is in the convention of controller "
                         f"{words[1]!r}, the scene's block is {self.controller.name!r}")
        else:
            self.joints_controller = True

    def model_q(self, values: dict, scale: np.ndarray) -> np.ndarray:
        """URDF joint values [rad, m] of a row's joint columns (file units, either convention)."""
        raw = np.array([values[j] for j in self.robot.joint_names]) * scale
        return self.controller.to_model(raw) if self.joints_controller else raw

    def units_directive(self, number: int, text: str) -> None:
        valid = {"length": LENGTH_UNITS, "angle": ANGLE_UNITS}
        for token in re.sub(r"\s*=\s*", "=", text).replace(",", " ").split():
            key, sep, value = token.partition("=")
            key, value = key.strip().lower(), value.strip()
            if not sep or key not in valid:
                self.problem(number, f"units: cannot read {token!r}; expected "
                             "'length=<m|mm> angle=<rad|deg>'")
            elif value not in valid[key]:
                self.units_bad.add(key)
                self.problem(number, f"units: unknown {key} unit {value!r}; valid {key} units "
                             f"are {', '.join(map(repr, valid[key]))}")
            elif key in self.units:
                self.problem(number, f"units: {key} is given twice")
            else:
                self.units[key] = value

    def resolve_units(self, length_unit, angle_unit) -> tuple[float, float] | None:
        """(length, angle) scales to SI, or None when they are unknown (problems noted)."""
        tables = {"length": LENGTH_UNITS, "angle": ANGLE_UNITS}
        missing = []
        for key, flag in (("length", length_unit), ("angle", angle_unit)):
            if flag is None:
                if key not in self.units:
                    missing.append(key)
            elif flag in tables[key] and self.units.get(key, flag) != flag:
                self.problem(self.units_line, f"--{key}-unit {flag} ({key}_unit={flag!r}) contradicts the "
                             f"file's '# units:' line ({key}={self.units[key]}): the option is for a file "
                             "that states no units; leave it out, or fix the line if the file is wrong")
            elif flag in tables[key]:
                self.units[key] = flag
            else:
                self.problem(None, f"{key}_unit={flag!r} is not a {key} unit; valid {key} units "
                             f"are {', '.join(map(repr, tables[key]))}")
        missing = [k for k in missing if k not in self.units_bad]  # reported with the line
        if missing:
            where = (f"add {' '.join(f'{k}=...' for k in missing)} to the '# units:' line "
                     f"(line {self.units_line})" if self.units_line is not None else
                     "add the line '# units: length=mm angle=deg' (with your units) before "
                     "the column header")
            self.problem(None, f"the {' and '.join(missing)} unit"
                         f"{'s are' if len(missing) > 1 else ' is'} not given: {where}, or pass "
                         f"{' and '.join(f'--{k}-unit' for k in missing)} on the command line "
                         f"({', '.join(f'{k}_unit=...' for k in missing)} in Python); "
                         + "; ".join(f"valid {k} units are {', '.join(map(repr, tables[k]))}"
                                     for k in missing))
        if any(k not in self.units for k in tables):
            return None
        return LENGTH_UNITS[self.units["length"]], ANGLE_UNITS[self.units["angle"]]

    def unit_of(self, prismatic: bool) -> str:
        return self.units["length" if prismatic else "angle"]

    # -- header

    def columns(self, number: int, header: list[str]) -> dict[str, int] | None:
        """Column name -> field index for every recognised column; None if unusable."""
        joints = self.robot.joint_names
        valid = (*joints, REFLECTOR_COLUMN, *POSITION_COLUMNS, *ROTATION_COLUMNS, SIGMA_COLUMN)
        if all(isinstance(_parse_float(f), float) for f in header):
            self.problem(number, "expected the column header, got a row of numbers; the "
                         f"first line that is not a comment names the columns: {', '.join(valid)}")
            return None
        if not set(joints) & set(header) and len(header) >= len(joints):  # another robot's file
            self.problem(number, f"none of the robot {self.robot.name}'s joint columns "
                         f"({', '.join(joints)}) is in the header: a file of another robot?")
            return None
        columns: dict[str, int] = {}
        for i, name in enumerate(header):
            if not name:
                self.problem(number, f"column {i + 1} of the header has no name")
            elif name in columns:
                self.problem(number, f"duplicate column {name!r} (columns {columns[name] + 1} "
                             f"and {i + 1})")
            elif name in valid:
                columns[name] = i
            else:
                hint = difflib.get_close_matches(name, valid, n=1)
                also = f" (did you mean {hint[0]!r}?)" if hint else ""
                sep = " (fields must be separated by commas)" if ";" in name or "\t" in name else ""
                self.problem(number, f"unknown column {name!r}{also}{sep}; valid columns are: "
                             f"{', '.join(valid)} (joint columns: the robot "
                             f"{self.robot.name}'s joints)")
        missing = [j for j in joints if j not in columns]
        if missing:
            self.problem(number, f"missing joint column(s) {', '.join(map(repr, missing))}; "
                         f"the robot {self.robot.name} needs one column per joint: "
                         f"{', '.join(joints)}")
        for group, required in ((POSITION_COLUMNS, True), (ROTATION_COLUMNS, False)):
            absent = [c for c in group if c not in columns]
            if absent and (required or len(absent) < len(group)):
                self.problem(number, f"missing column(s) {', '.join(absent)}: give "
                             f"{'all of ' if not required else ''}{', '.join(group)}"
                             f"{'' if required else ' or none of them'}")
        return columns

    # -- rows

    def row(self, number: int, fields: list[str], width: int, columns, scales):
        """Parsed values {column: float or reflector index}, or None; problems noted."""
        if len(fields) != width:
            self.problem(number, f"expected {width} comma-separated fields as in the column "
                         f"header (line {self.header_line}), got {len(fields)}")
            return None
        if columns is None:
            return None
        values: dict[str, float | int] = {}
        messages = []
        for name, i in columns.items():
            if name == REFLECTOR_COLUMN:
                j = self.reflector(fields[i])
                if isinstance(j, str):
                    messages.append(j)
                else:
                    values[name] = j
                continue
            value = _parse_float(fields[i])
            if isinstance(value, str):
                messages.append(f"{name} {value}")
            else:
                values[name] = value
        if scales is not None:
            messages += self.check_values(values, scales)
        if messages:
            self.problem(number, "; ".join(messages))
            return None
        return values

    def reflector(self, text: str) -> int | str:
        text = text.strip()
        names = self.reflector_names
        if text in names:
            return names.index(text)
        if re.fullmatch(r"\d+", text) and int(text) < len(names):
            return int(text)
        indices = "index 0" if len(names) == 1 else f"indices 0..{len(names) - 1}"
        return (f"unknown reflector {text!r}; valid reflectors are "
                f"{', '.join(map(repr, names))} or their {indices}")

    def check_values(self, values: dict, scales: tuple[float, float]) -> list[str]:
        length, angle = scales
        messages = []
        robot = self.robot
        if self.check_limits and all(name in values for name in robot.joint_names):
            q = self.model_q(values, np.where(self.prismatic, length, angle))
            ctrl = " (URDF value, from the controller values)" if self.joints_controller else ""
            for k, name in enumerate(robot.joint_names):
                s = length if self.prismatic[k] else angle
                lo, hi, unit = robot.lower[k], robot.upper[k], self.unit_of(self.prismatic[k])
                if not lo - LIMIT_TOL <= q[k] <= hi + LIMIT_TOL:
                    messages.append(f"{name} = {q[k] / s:.6g} {unit}{ctrl} is outside its "
                                    f"limits [{lo / s:.6g}, {hi / s:.6g}] {unit}")
        # beyond the range even if the unit were 1000 times too large (that mistake, mm read
        # as m, the registration check names with its evidence)
        far = [c for c in POSITION_COLUMNS if c in values and abs(values[c]) * length > 1e3 * MAX_TRACKER_RANGE]
        if far:
            messages.append(f"{far[0]} = {values[far[0]]:.6g} {self.units['length']} is beyond any "
                            f"laser tracker's range ({MAX_TRACKER_RANGE:g} m) in any length unit: "
                            "check the value")
        if SIGMA_COLUMN in values and values[SIGMA_COLUMN] <= 0:
            messages.append(f"sigma = {values[SIGMA_COLUMN]:.6g} {self.units['length']} must be > 0")
        elif SIGMA_COLUMN in values and values[SIGMA_COLUMN] * length > MAX_SIGMA:
            messages.append(f"sigma = {values[SIGMA_COLUMN]:.6g} {self.units['length']} must be at "
                            f"most {MAX_SIGMA * 1e3:g} mm (a tracker measures to micrometres)")
        if all(c in values for c in ROTATION_COLUMNS):
            norm = math.hypot(*(values[c] for c in ROTATION_COLUMNS)) * angle
            if norm > _MAX_ROTATION:
                messages.append(f"rotation vector (rx, ry, rz) has norm {norm / angle:.6g} "
                                f"{self.units['angle']} > {math.pi / angle:.6g} "
                                f"{self.units['angle']}; give pin.log3 of the orientation")
        return messages

    def build(self, data, rows, columns, scales) -> MeasurementSet:
        length, angle = scales
        scale = np.where(self.prismatic, length, angle)
        q = np.array([self.model_q(r, scale) for r in rows])
        positions = np.array([[r[c] for c in POSITION_COLUMNS] for r in rows]) * length
        rotations = None
        if ROTATION_COLUMNS[0] in columns:
            rotations = np.array([[r[c] for c in ROTATION_COLUMNS] for r in rows]) * angle
        sigma = None
        if SIGMA_COLUMN in columns:
            sigma = np.array([r[SIGMA_COLUMN] for r in rows]) * length
        reflector = np.array([r.get(REFLECTOR_COLUMN, 0) for r in rows], dtype=np.int64)
        self.note_repeats([number for number, _ in data],
                          np.column_stack([q, reflector, positions] + ([] if rotations is None else [rotations])))
        return MeasurementSet(self.robot.joint_names, q, reflector, positions, rotations, sigma,
                              self.where, np.array([number for number, _ in data]))

    def note_repeats(self, lines: list[int], table: np.ndarray) -> None:
        """A :class:`CalibOedNote` for rows identical to an earlier one (configuration,
        reflector and measured values): a copied line rather than a repeated measurement."""
        repeats = repeated_rows(lines, table)
        if repeats:
            warnings.warn(CalibOedNote(
                f"{self.where}: {len(repeats)} row(s) identical to an earlier row, measured values "
                f"included ({describe_repeats(repeats)}): copied lines? Each counts "
                "as a measurement"), stacklevel=4)


def read_measurements(
    source: str | os.PathLike | IO[str],
    robot: Robot,
    reflector_names: Sequence[str] = ("smr0",),
    *,
    length_unit: str | None = None,
    angle_unit: str | None = None,
    check_limits: bool = True,
    controller: ControllerConvention | None = None,
) -> MeasurementSet:
    """Read a measurement file (format in the module docstring) into SI arrays.

    Args:
        source: A path, or an open text stream (e.g. ``io.StringIO(text)``).
        robot: The measured robot; its joint names are the joint columns.
        reflector_names: Names of the reflectors, index ``j`` = reflector ``j``
            of the parameter space.
        length_unit: ``"m"`` or ``"mm"``, for a file whose ``# units:`` line gives none (one
            that contradicts the line is a problem: which of the two is wrong is not known).
        angle_unit: ``"rad"`` or ``"deg"``, likewise.
        check_limits: Reject joint values outside ``robot.lower``/``robot.upper``.
        controller: The scene's controller convention; used only when the file
            says ``# joints: controller`` (an error without it).

    Raises:
        MeasurementFileError: the file cannot be read or has any problem; the
            error's ``problems`` lists all of them with their line numbers.
    """
    names = _reflector_names(reflector_names)
    text, where = _read_text(source)
    return _Reader(robot, names, where, check_limits, controller).read(text, length_unit, angle_unit)
