r"""Parameter table files (YAML): write a :class:`~calib_oed.model.dh.ParameterTable`, read one back.

The format (``docs/parameter_tables.md``)::

    format: calib_oed parameter table 1
    robot: kr16
    convention: modified_dh          # classic_dh | modified_dh | hayati
    units: {length: m, angle: rad}   # or mm / deg (a vendor data sheet)
    tool_frame: tool0
    base: {xyz: [x, y, z], rpy: [r, p, y]}     # T_W,0
    tool: {xyz: [x, y, z], rpy: [r, p, y]}     # T_n,F
    joints:                                    # base to tip
      - {name: joint_a1, kind: dh, alpha: 0.0, a: 0.0, theta: 0.0, d: 0.0, beta: 0.0,
         lower: -3.2, upper: 3.2}
    residual: {position_m: 1e-15, rotation_rad: 1e-15}    # written, not read

``kind`` is ``dh`` or ``hayati`` (only in ``hayati`` tables; its ``d`` is 0); a missing
``beta`` or ``d`` is 0. Angles in ``rpy`` follow URDF (:math:`R = R_z R_y R_x`). The writer
uses SI and the shortest float text that round-trips (PyYAML's ``repr``), so a written
table reads back bit for bit; a file in mm and degrees is converted on reading.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

from calib_oed.exceptions import InputFileError, ParameterTableError
from calib_oed.io.atomic import atomic_write_text
from calib_oed.model.dh import CONVENTIONS, ParameterTable, Row
from calib_oed.scene.yaml_file import MAX_SMALL_YAML_BYTES, load_yaml, read_text_file

FORMAT = "calib_oed parameter table 1"
_LENGTH = {"m": 1.0, "mm": 1e-3}
_ANGLE = {"rad": 1.0, "deg": np.pi / 180.0}
_ROW_KEYS = ("alpha", "a", "theta", "d", "beta")


def _pose(v: tuple[float, ...]) -> dict:
    return {"xyz": list(v[:3]), "rpy": list(v[3:])}


def table_yaml_text(table: ParameterTable) -> str:
    """The YAML text of ``table`` (SI)."""
    data = {
        "format": FORMAT, "robot": table.robot, "convention": table.convention,
        "units": {"length": "m", "angle": "rad"}, "tool_frame": table.tool_frame,
        "base": _pose(table.base), "tool": _pose(table.tool),
        "joints": [{"name": r.joint, "kind": r.kind,
                    **{k: float(getattr(r, k)) + 0.0 for k in (*_ROW_KEYS, "lower", "upper")}}
                   for r in table.rows],
    }
    if table.residual_m is not None:
        data["residual"] = {"position_m": table.residual_m, "rotation_rad": table.residual_rad}
    head = (f"# calib_oed parameter table ({table.convention}); T_W,F(q) = base * prod A_i(q_i) * tool,\n"
            "# theta_i = q_i + theta (q the URDF joint value); see docs/parameter_tables.md\n")
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)


def write_parameter_table(path: str | os.PathLike, table: ParameterTable) -> Path:
    """Write ``table`` to ``path`` (YAML, atomic)."""
    return atomic_write_text(path, table_yaml_text(table))


def _number(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ParameterTableError(f"{where}: {value!r} is not a finite number")
    return float(value)


def _read_pose(where: str, data, length: float, angle: float) -> tuple[float, ...]:
    if not isinstance(data, dict) or set(data) - {"xyz", "rpy"}:
        raise ParameterTableError(f"{where}: give a mapping with keys xyz and rpy (3 numbers each)")
    out = []
    for key, unit in (("xyz", length), ("rpy", angle)):
        v = data.get(key, [0.0, 0.0, 0.0])
        if not isinstance(v, list) or len(v) != 3:
            raise ParameterTableError(f"{where}.{key}: give 3 numbers, got {v!r}")
        out.append(np.array([_number(f"{where}.{key}", x) for x in v]) * unit)
    return tuple(float(x) for x in (*out[0], *out[1]))


def parse_parameter_table(text: str, where: str = "<table>") -> ParameterTable:
    """A table from YAML text (module docstring). Raises :class:`ParameterTableError` naming the field."""
    try:
        data = load_yaml(text, where)
    except yaml.YAMLError as exc:
        raise ParameterTableError(f"{where}: not valid YAML ({exc})") from exc
    except InputFileError as exc:        # a duplicate key, an alias bomb
        raise ParameterTableError(str(exc)) from exc
    if not isinstance(data, dict):
        raise ParameterTableError(f"{where}: expected a mapping with convention, base, tool and joints")
    convention = data.get("convention")
    if convention not in CONVENTIONS:
        raise ParameterTableError(f"{where}: convention {convention!r}; valid: {', '.join(CONVENTIONS)}")
    units = data.get("units") or {}
    lu, au = units.get("length", "m"), units.get("angle", "rad")
    if lu not in _LENGTH or au not in _ANGLE:
        raise ParameterTableError(f"{where}: units {units!r}; valid: length m or mm, angle rad or deg")
    length, angle = _LENGTH[lu], _ANGLE[au]
    joints = data.get("joints")
    if not isinstance(joints, list) or not joints:
        raise ParameterTableError(f"{where}: joints: give one row per joint, base to tip")
    rows = []
    for k, j in enumerate(joints):
        w = f"{where}: joints[{k}]"
        if not isinstance(j, dict) or "name" not in j:
            raise ParameterTableError(f"{w}: give a mapping with name, alpha, a, theta, d (or beta), lower, upper")
        kind = j.get("kind", "dh")
        if kind not in ("dh", "hayati") or (kind == "hayati" and convention != "hayati"):
            raise ParameterTableError(f"{w}: kind {kind!r}; valid: dh, or hayati in a hayati table")
        unknown = set(j) - {"name", "kind", "lower", "upper", *_ROW_KEYS}
        if unknown:
            raise ParameterTableError(f"{w}: unknown keys {sorted(unknown)}; valid: name, kind, "
                                      f"{', '.join(_ROW_KEYS)}, lower, upper")
        v = {key: _number(f"{w}.{key}", j.get(key, 0.0)) for key in _ROW_KEYS}
        if kind == "hayati" and v["d"] != 0.0:
            raise ParameterTableError(f"{w}: a Hayati row has beta instead of d; d must be 0")
        lower = _number(f"{w}.lower", j.get("lower", -np.pi / angle)) * angle
        upper = _number(f"{w}.upper", j.get("upper", np.pi / angle)) * angle
        if not lower < upper:
            raise ParameterTableError(f"{w}: lower {lower:g} rad is not below upper {upper:g} rad")
        rows.append(Row(str(j["name"]), kind, v["alpha"] * angle, v["a"] * length, v["theta"] * angle,
                        v["d"] * length, v["beta"] * angle, lower, upper))
    names = [r.joint for r in rows]
    if len(set(names)) != len(names):
        raise ParameterTableError(f"{where}: joint names repeat: {names}")
    return ParameterTable(convention, str(data.get("robot", "robot")), str(data.get("tool_frame", "tool0")),
                          _read_pose(f"{where}: base", data.get("base", {}), length, angle),
                          _read_pose(f"{where}: tool", data.get("tool", {}), length, angle), tuple(rows))


def read_parameter_table(path: str | os.PathLike) -> ParameterTable:
    """Read a table file (YAML), within the bounds of :func:`calib_oed.scene.yaml_file.read_text_file`."""
    path = Path(path)
    try:
        text = read_text_file(path, "parameter table", MAX_SMALL_YAML_BYTES)
    except InputFileError as exc:
        raise ParameterTableError(f"cannot read the parameter table {exc}") from exc
    return parse_parameter_table(text, str(path))


__all__ = ["FORMAT", "parse_parameter_table", "read_parameter_table", "table_yaml_text",
           "write_parameter_table"]
