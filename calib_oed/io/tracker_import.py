r"""Laser-tracker exports into a :class:`~calib_oed.measurement.dataset.MeasurementSet`
(``calib-oed import``; the layouts are specified in ``docs/data_format.md#tracker-exports``).

Two layouts, as tracker software and measurement scripts write them:

- ``poses`` (:func:`read_pose_array`): a headerless numeric table, one row per robot
  pose: the joint values, then the x, y, z of every SMR of the pose side by side (a
  measurement script's log). ``columns`` names every column (a joint name, ``<smr>.x``,
  ``.y``, ``.z``, or ``skip``); by default the joints in the robot's order, then the
  triplets of ``smrs`` (default: the scene's reflectors in order). An SMR whose three
  fields are empty or ``NaN`` was not seen at that pose (a broken beam): that
  measurement is left out and counted, the pose's other SMRs are kept. With
  ``controller`` (the scene's block unless ``--joints urdf``) the joint values
  are the controller's, mapped to URDF joints :math:`q = A c + b`.
- ``points`` (:func:`read_point_export`): one measured point per row under a header
  (or without one, SpatialAnalyzer's ASCII export: ``Collection Group Target x y z``),
  the point export of tracker software: a target id, ``X``, ``Y``, ``Z`` and
  optionally ``U95``, temperature, pressure, a time stamp and, for a 6-DoF probe, its
  orientation as a unit quaternion ``Q0..Q3`` (scalar first; also ``Qw, Qx, Qy, Qz``).
  Header names are matched case-insensitively with a unit in brackets allowed
  (``X [mm]``; the unit then must agree with ``length_unit``); ``columns`` maps a role
  to another header name (``{"target": "Point Name"}``). The joint values come from the
  design the robot ran: the target id names the pose (1-based row of the design) and
  the SMR, read with ``target_pattern`` (groups ``pose`` and ``smr``); ``smrs`` maps the
  file's SMR ids to the scene's reflector names.

Both read comma, semicolon, tab or blank separated fields (detected from the first data
line); with semicolons or tabs a decimal comma (``1234,56``) is read as a point.
``U95`` is the expanded uncertainty of each coordinate at coverage factor
:math:`k = 2` (GUM, as ISO 10360-10 states a tracker's MPE), so each measurement gets
:math:`\sigma = U_{95}/2` per axis, its covariance :math:`\sigma^2 I_3` in the fit.
Nothing is half-read: every problem is collected with its line and raised as one
:class:`~calib_oed.exceptions.MeasurementFileError`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import MeasurementFileError
from calib_oed.io.export_fields import data_lines as _data_lines
from calib_oed.io.export_fields import number as _number
from calib_oed.io.export_fields import splitter as _splitter
from calib_oed.io.export_fields import text as _text
from calib_oed.io.measurement_format import MAX_SIGMA, MAX_TRACKER_RANGE
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.robot import Robot
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS

__all__ = ["DEFAULT_TARGET_PATTERN", "LAYOUTS", "POINT_ROLES", "TrackerImport", "detect_layout", "read_point_export",
           "read_pose_array", "read_tracker_export"]

LAYOUTS = ("poses", "points")
#: A target id such as ``P001_SMR-A``, ``pose12-smr0`` or ``12/A``: the first number is the pose,
#: what follows the separator the SMR.
DEFAULT_TARGET_PATTERN = r"^\D*(?P<pose>\d+)[\s_\-/.:]+(?P<smr>\S.*)$"
#: Roles of a point export's columns and the header names recognised for them.
POINT_ROLES: dict[str, tuple[str, ...]] = {
    "target": ("target", "target id", "targetid", "point", "point name", "point id", "pointname",
               "name", "id"),
    "x": ("x",), "y": ("y",), "z": ("z",),
    "u95": ("u95", "uncertainty", "u95 uncertainty", "uncertainty u95"),
    "temperature": ("temperature", "temp", "air temperature"),
    "pressure": ("pressure", "air pressure"),
    "time": ("time", "timestamp", "time stamp", "date/time", "datetime"),
    "qw": ("q0", "qw"), "qx": ("q1", "qx"), "qy": ("q2", "qy"), "qz": ("q3", "qz"),
}
#: Plausible air temperature [°C] and pressure [hPa] where a tracker works.
_TEMPERATURE_C, _PRESSURE_HPA = (-30.0, 60.0), (500.0, 1100.0)
_UNIT_SUFFIX = re.compile(r"^(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")


@dataclass(frozen=True)
class TrackerImport:
    """What an import read: the measurements (SI), and what the report says about them.

    Attributes:
        mset: The measurements, one row per SMR seen at a pose.
        layout: ``"poses"`` or ``"points"``.
        poses: Poses in the file.
        skipped: SMRs not seen at a pose (empty fields: a broken beam), left out.
        temperature_c, pressure_hpa: (min, max) of the file's air temperature [°C] and
            pressure [hPa], or None when the file has no such column.
    """

    mset: MeasurementSet
    layout: str
    poses: int
    skipped: int = 0
    temperature_c: tuple[float, float] | None = None
    pressure_hpa: tuple[float, float] | None = None

    def summary(self) -> str:
        m = self.mset
        text = (f"{len(m.q)} measurements of {len(m.reflectors)} SMR(s) at {self.poses} poses "
                f"({self.layout} layout)")
        if self.skipped:
            text += f"; {self.skipped} SMR(s) not seen at a pose, left out"
        if m.sigma is not None:
            text += (f"; sigma = U95/2 from {m.sigma.min() * 1e3:.4g} to {m.sigma.max() * 1e3:.4g} mm "
                     "per axis")
        for what, rng, unit in (("air temperature", self.temperature_c, "°C"),
                                ("pressure", self.pressure_hpa, "hPa")):
            if rng is not None:
                text += f"; {what} {rng[0]:.5g} to {rng[1]:.5g} {unit}"
        return text


class _Problems:
    def __init__(self, where: str):
        self.where, self.items = where, []

    def add(self, line: int | None, message: str) -> None:
        self.items.append((line, message))

    def raise_if_any(self) -> None:
        if self.items:
            raise MeasurementFileError(self.where, sorted(self.items, key=lambda p: p[0] or 0),
                                       kind="tracker export")


def _unit_scale(unit: str, table: Mapping[str, float], what: str) -> float:
    if unit not in table:
        raise MeasurementFileError("<arguments>", [(None, f"unknown {what} unit {unit!r}; valid "
                                                    f"{what} units: {', '.join(table)}")], kind="tracker export")
    return table[unit]


def _check_point(p: np.ndarray, length_unit: str, line: int, problems: _Problems) -> bool:
    if np.max(np.abs(p)) > MAX_TRACKER_RANGE:
        problems.add(line, f"a coordinate of {np.max(np.abs(p)) / LENGTH_UNITS[length_unit]:.6g} "
                     f"{length_unit} is beyond any laser tracker's range ({MAX_TRACKER_RANGE:g} m): "
                     "check the value and the length unit")
        return False
    return True


def read_pose_array(source, robot: Robot, reflector_names: Sequence[str], *,
                    smrs: Sequence[str] | None = None, columns: Sequence[str] | None = None,
                    length_unit: str = "mm", angle_unit: str = "deg",
                    controller: ControllerConvention | None = None) -> TrackerImport:
    """A headerless table, one row per pose: joint values, then each SMR's x, y, z.

    Args:
        source: The file.
        robot: The robot; its joint names name the joint columns.
        reflector_names: The scene's reflectors (index = the parameter space's).
        smrs: Scene reflector names of the file's triplets, in file order (default: all of
            ``reflector_names``).
        columns: A name for every column (joint names, ``<smr>.x|y|z``, ``skip``); default
            the joints, then the triplets of ``smrs``.
        length_unit, angle_unit: The file's units (prismatic joints in ``length_unit``).
        controller: The joint values are this controller's (mapped to URDF joints);
            None: they are URDF joint values.

    Raises:
        MeasurementFileError: every problem with its line.
    """
    text, where = _text(source)
    problems = _Problems(where)
    length = _unit_scale(length_unit, LENGTH_UNITS, "length")
    angle = _unit_scale(angle_unit, ANGLE_UNITS, "angle")
    names = list(reflector_names)
    smrs = list(names if smrs is None else smrs)
    unknown = [s for s in smrs if s not in names]
    if unknown or len(set(smrs)) != len(smrs):
        problems.add(None, f"smrs {smrs}: give distinct names of the scene's reflectors {names}")
        problems.raise_if_any()
    joints = list(robot.joint_names)
    columns = list(columns) if columns else joints + [f"{s}.{c}" for s in smrs for c in "xyz"]
    valid = set(joints) | {f"{s}.{c}" for s in names for c in "xyz"} | {"skip"}
    bad = [c for c in columns if c not in valid]
    missing = [c for c in joints + [f"{s}.{c}" for s in smrs for c in "xyz"] if c not in columns]
    taken = [c for c in columns if c != "skip" and columns.count(c) > 1]
    if bad or missing or taken:
        problems.add(None, f"columns: {'unknown ' + ', '.join(bad) + '; ' if bad else ''}"
                     f"{'missing ' + ', '.join(missing) + '; ' if missing else ''}"
                     f"{'twice ' + ', '.join(sorted(set(taken))) + '; ' if taken else ''}"
                     f"name every column: the joints {', '.join(joints)}, <smr>.x/.y/.z of the "
                     f"reflectors {', '.join(names)}, or skip")
        problems.raise_if_any()
    lines = _data_lines(text)
    if not lines:
        problems.add(None, "no data rows (the file is empty or holds only comments)")
        problems.raise_if_any()
    split, decimal_comma = _splitter(lines[0][1])
    scale = np.where(robot.prismatic, length, angle)
    q_rows, refl, pos, skipped = [], [], [], 0
    for number, line in lines:
        fields = split(line)
        if len(fields) != len(columns):
            problems.add(number, f"expected {len(columns)} fields ({', '.join(columns)}), got "
                         f"{len(fields)}")
            continue
        values = {c: _number(f, decimal_comma) for c, f in zip(columns, fields, strict=True) if c != "skip"}
        errors = [f"{c} {v}" for c, v in values.items() if isinstance(v, str)]
        errors += [f"{j} is missing" for j in joints if values[j] is None]
        if errors:
            problems.add(number, "; ".join(errors))
            continue
        q = np.array([values[j] for j in joints]) * scale
        q = q if controller is None else controller.to_model(q)
        outside = [f"{j} = {q[k] / scale[k]:.6g}{' (URDF, from the controller values)' if controller else ''} "
                   "outside its limits" for k, j in enumerate(joints)
                   if not robot.lower[k] - 1e-9 <= q[k] <= robot.upper[k] + 1e-9]
        if outside:
            problems.add(number, "; ".join(outside))
            continue
        for s in smrs:
            xyz = [values[f"{s}.{c}"] for c in "xyz"]
            if all(v is None for v in xyz):
                skipped += 1
                continue
            if any(v is None for v in xyz):
                problems.add(number, f"{s}: only some of x, y, z are given")
                continue
            p = np.array(xyz) * length
            if _check_point(p, length_unit, number, problems):
                q_rows.append(q)
                refl.append(names.index(s))
                pos.append(p)
    problems.raise_if_any()
    if not pos:
        problems.add(None, "no SMR was measured at any pose")
        problems.raise_if_any()
    mset = MeasurementSet.from_arrays(robot, np.array(q_rows), np.array(pos), reflector=np.array(refl),
                                      source=where)
    return TrackerImport(mset, "poses", len(lines), skipped)


def _header_roles(header: list[str], columns: Mapping[str, str], problems: _Problems, line: int):
    """Role -> (field index, unit in the header or None)."""
    stripped = []
    for h in header:
        m = _UNIT_SUFFIX.match(h.strip().strip('"'))
        name = (m.group("name") if m else h).strip().strip('"').lower()
        stripped.append((name, m.group("unit").strip() if m else None))
    roles: dict[str, tuple[int, str | None]] = {}
    unknown_roles = [r for r in columns if r not in POINT_ROLES]
    if unknown_roles:
        problems.add(None, f"columns: unknown role(s) {', '.join(unknown_roles)}; roles are "
                     f"{', '.join(POINT_ROLES)}")
        return roles
    for role, names in POINT_ROLES.items():
        wanted = (columns[role].strip().lower(),) if role in columns else names
        hits = [i for i, (name, _) in enumerate(stripped) if name in wanted]
        if len(hits) > 1:
            problems.add(line, f"columns {', '.join(header[i] for i in hits)} all read as {role}; "
                         f"name the one to use (columns={{'{role}': ...}})")
        elif hits:
            roles[role] = (hits[0], stripped[hits[0]][1])
        elif role in columns:
            problems.add(line, f"no column {columns[role]!r} for {role}; the header is {', '.join(header)}")
    for role in ("target", "x", "y", "z"):
        if role not in roles and role not in columns:
            problems.add(line, f"no {role} column (recognised names: {', '.join(POINT_ROLES[role])}; "
                         f"or map one with columns={{'{role}': '<header name>'}}); the header is "
                         f"{', '.join(header)}")
    quat = [r for r in ("qw", "qx", "qy", "qz") if r in roles]
    if quat and len(quat) != 4:
        problems.add(line, "a 6-DoF probe needs all of Q0..Q3 (scalar first), got "
                     f"{', '.join(header[roles[r][0]] for r in quat)}")
    return roles


#: The columns of SpatialAnalyzer's ASCII point export ("Collection Group target" names, then
#: Cartesian x, y, z); further columns (tolerance, uncertainties, time stamp, as the export's
#: options add them) are ``column7``, ``column8``, ... for ``columns`` (``{"u95": "column7"}``).
SA_ASCII_COLUMNS = ("Collection", "Group", "Target", "X", "Y", "Z")


def _is_sa_ascii(first: list[str], decimal_comma: bool) -> bool:
    """Whether the first data line is a point of SpatialAnalyzer's headerless ASCII export:
    three names, then three numbers."""
    return (len(first) >= 6 and all(isinstance(_number(f, decimal_comma), float) for f in first[3:6])
            and not isinstance(_number(first[2], decimal_comma), float))


def read_point_export(source, robot: Robot, reflector_names: Sequence[str], design_q: np.ndarray, *,
                      smrs: Mapping[str, str] | None = None, columns: Mapping[str, str] | None = None,
                      target_pattern: str = DEFAULT_TARGET_PATTERN,
                      length_unit: str = "mm") -> TrackerImport:
    """One point per row under a header (a tracker's point export); joint values from the design.

    Args:
        source: The file.
        robot: The robot.
        reflector_names: The scene's reflectors.
        design_q: The design the robot ran, (n, nq) [SI]; pose ``k`` of a target id is row ``k - 1``.
        smrs: The file's SMR ids -> scene reflector names (default: the ids are the names).
        columns: Role -> header name, for headers the defaults do not recognise.
        target_pattern: A regular expression with groups ``pose`` and ``smr`` for the target id.
        length_unit: The unit of X, Y, Z and U95 (a unit in the header must agree).

    Raises:
        MeasurementFileError: every problem with its line.
    """
    text, where = _text(source)
    problems = _Problems(where)
    length = _unit_scale(length_unit, LENGTH_UNITS, "length")
    names = list(reflector_names)
    smrs = dict(smrs) if smrs else {n: n for n in names}
    wrong = {k: v for k, v in smrs.items() if v not in names}
    if wrong:
        problems.add(None, f"smrs: {wrong} map to no reflector of the scene; its reflectors are {names}")
    try:
        pattern = re.compile(target_pattern)
    except re.error as exc:
        problems.add(None, f"target pattern {target_pattern!r} is not a regular expression ({exc})")
        problems.raise_if_any()
    if not {"pose", "smr"} <= set(pattern.groupindex):
        problems.add(None, f"target pattern {target_pattern!r} needs the groups (?P<pose>...) and (?P<smr>...)")
    problems.raise_if_any()
    lines = _data_lines(text)
    if len(lines) < 2:
        problems.add(None, "expected a header line and at least one point")
        problems.raise_if_any()
    split, decimal_comma = _splitter(lines[0][1])
    header = split(lines[0][1])
    headerless = _is_sa_ascii(header, decimal_comma)
    if headerless:  # SpatialAnalyzer's ASCII point export: no header, the first line is a point
        header = [*SA_ASCII_COLUMNS, *(f"column{k}" for k in range(len(SA_ASCII_COLUMNS) + 1, len(header) + 1))]
        lines = [(None, ""), *lines]
    roles = _header_roles(header, columns or {}, problems, lines[0][0])
    for role in ("x", "y", "z", "u95"):
        unit = roles.get(role, (0, None))[1]
        if unit is not None and unit != length_unit:
            problems.add(lines[0][0], f"column {header[roles[role][0]]!r} is in {unit!r}, the import's "
                         f"length unit is {length_unit!r}: pass length_unit={unit!r} (--length-unit)")
    problems.raise_if_any()
    six_dof = "qw" in roles
    rows: dict[str, list] = {k: [] for k in ("q", "refl", "pos", "rot", "sigma", "T", "P")}
    seen: dict[tuple[int, int], int] = {}
    for number, line in lines[1:]:
        fields = split(line)
        if len(fields) != len(header):
            problems.add(number, f"expected {len(header)} fields as in the header, got {len(fields)}")
            continue
        target = fields[roles["target"][0]].strip().strip('"')
        if headerless and "target" not in (columns or {}):  # the pose may be the group: "P001 A"
            target = f"{fields[1].strip().strip(chr(34))} {target}"
        match = pattern.match(target)
        if not match:
            problems.add(number, f"target id {target!r} does not match the target pattern "
                         f"{pattern.pattern!r} (groups pose and smr)")
            continue
        pose, smr = int(match.group("pose")), match.group("smr").strip()
        messages = []
        if not 1 <= pose <= len(design_q):
            messages.append(f"pose {pose} of target {target!r} is not a row of the design (1..{len(design_q)})")
        if smr not in smrs:
            messages.append(f"SMR {smr!r} of target {target!r} is not one of {', '.join(map(repr, smrs))}")
        values = {r: _number(fields[i], decimal_comma) for r, (i, _) in roles.items()
                  if r not in ("target", "time")}
        messages += [f"{header[roles[r][0]]} {v}" for r, v in values.items() if isinstance(v, str)]
        messages += [f"{header[roles[r][0]]} is missing" for r in ("x", "y", "z", "qw", "qx", "qy", "qz")
                     if r in values and values[r] is None]
        if messages:
            problems.add(number, "; ".join(messages))
            continue
        key = (pose, names.index(smrs[smr]))
        if key in seen:
            problems.add(number, f"pose {pose}, SMR {smr!r} measured twice (also line {seen[key]})")
            continue
        seen[key] = number
        p = np.array([values[c] for c in "xyz"]) * length
        if not _check_point(p, length_unit, number, problems):
            continue
        if values.get("u95") is not None:
            sigma = values["u95"] * length / 2.0  # U95 at k = 2: sigma per axis
            if not 0 < sigma <= MAX_SIGMA:
                problems.add(number, f"U95 = {values['u95']:.6g} {length_unit} must be > 0 and at most "
                             f"{2 * MAX_SIGMA / length:g} {length_unit}")
                continue
            rows["sigma"].append(sigma)
        for role, rng, key2, unit in (("temperature", _TEMPERATURE_C, "T", "°C"),
                                      ("pressure", _PRESSURE_HPA, "P", "hPa")):
            v = values.get(role)
            if v is not None and not rng[0] <= v <= rng[1]:
                problems.add(number, f"{role} {v:g} {unit} is outside {rng[0]:g}..{rng[1]:g} {unit} "
                             "(a tracker's air sensor in °C and hPa)")
            elif v is not None:
                rows[key2].append(v)
        if six_dof:
            quat = np.array([values[r] for r in ("qw", "qx", "qy", "qz")])
            if abs(np.linalg.norm(quat) - 1.0) > 1e-3:
                problems.add(number, f"quaternion Q0..Q3 has norm {np.linalg.norm(quat):.6g}, not 1")
                continue
            w, x, y, z = quat / np.linalg.norm(quat)
            rows["rot"].append(pin.log3(pin.Quaternion(w, x, y, z).toRotationMatrix()))
        rows["q"].append(design_q[pose - 1])
        rows["refl"].append(key[1])
        rows["pos"].append(p)
    if "u95" in roles and len(rows["sigma"]) != len(rows["pos"]):
        problems.add(None, "U95 is missing on some points: give it on every point or on none")
    problems.raise_if_any()
    mset = MeasurementSet.from_arrays(robot, np.array(rows["q"]), np.array(rows["pos"]),
                                      reflector=np.array(rows["refl"]),
                                      sigma=np.array(rows["sigma"]) if rows["sigma"] else None,
                                      rotations=np.array(rows["rot"]) if six_dof else None, source=where)
    span = {k: (min(v), max(v)) if v else None for k, v in (("T", rows["T"]), ("P", rows["P"]))}
    return TrackerImport(mset, "points", len({k[0] for k in seen}), 0, span["T"], span["P"])


def detect_layout(source) -> str:
    """``"poses"`` when the first data line is all numbers, else ``"points"`` (a header)."""
    lines = _data_lines(_text(source)[0])
    if not lines:
        return "poses"
    split, decimal_comma = _splitter(lines[0][1])
    return "poses" if all(not isinstance(_number(f, decimal_comma), str) for f in split(lines[0][1])) \
        else "points"


def read_tracker_export(source, robot: Robot, reflector_names: Sequence[str], *, layout: str = "auto",
                        design_q: np.ndarray | None = None, **options) -> TrackerImport:
    """:func:`read_pose_array` or :func:`read_point_export`; ``layout="auto"``: a first data line
    of numbers is a pose array, one with names a point export (which needs ``design_q``)."""
    layout = detect_layout(source) if layout == "auto" else layout
    if layout not in LAYOUTS:
        raise MeasurementFileError(os.fspath(source), [(None, f"unknown layout {layout!r}; valid "
                                                        f"layouts: {', '.join(LAYOUTS)}")], kind="tracker export")
    if layout == "poses":
        return read_pose_array(source, robot, reflector_names, **options)
    if design_q is None:
        raise MeasurementFileError(os.fspath(source), [(None, (
            "a point export holds no joint values: give the design the robot ran (--design), "
            "its rows in pose order"))], kind="tracker export")
    return read_point_export(source, robot, reflector_names, design_q, **options)
