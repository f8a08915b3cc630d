r"""Scene file blocks ``cell:`` and ``feasibility:``: the obstacles and the feasibility settings.

Read by :class:`calib_oed.scene.reader.FieldReader` (same validation style: errors name the
dotted key and the valid choices) into the records of
:mod:`calib_oed.feasibility.shapes`, in SI [m, rad]. Lengths in the file are in
its length unit, angles in its angle unit. Schema: ``docs/scenes.md``.

A half-space keeps the free side :math:`n^\top x \ge c` as written in the file;
the normal need not be unit length (both :math:`n` and :math:`c` are divided by
:math:`\lVert n \rVert`). The shorthands ``x_min: v`` (:math:`x \ge v`) and
``x_max: v`` (:math:`x \le v`), and likewise for y and z, give axis-aligned planes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import UnknownLinkError
from calib_oed.feasibility.shapes import Capsule, Cell, FeasibilitySettings, HalfSpace, Margins

if TYPE_CHECKING:
    from calib_oed.model.robot import Robot
    from calib_oed.scene.fields import FieldReader

#: Half-space shorthands: key -> (unit normal into the free side, sign of the offset).
#: ``x_min: v`` is x >= v (n = +e_x, c = v); ``x_max: v`` is -x >= -v (n = -e_x, c = -v).
HALFSPACE_SHORTHANDS: dict[str, tuple[tuple[float, float, float], float]] = {
    "x_min": ((1.0, 0.0, 0.0), 1.0), "x_max": ((-1.0, 0.0, 0.0), -1.0),
    "y_min": ((0.0, 1.0, 0.0), 1.0), "y_max": ((0.0, -1.0, 0.0), -1.0),
    "z_min": ((0.0, 0.0, 1.0), 1.0), "z_max": ((0.0, 0.0, -1.0), -1.0),
}  # fmt: skip
FEASIBILITY_KEYS = ("incidence_limit", "beam_radius", "reflector_radius", "capsule_margin",
                    "margins", "excluded_pairs", "robot_capsules", "prune")
_XYZ = "x, y, z"
_CELL = "cell.capsules and cell.halfspaces together"


def robot_links(robot: Robot) -> list[str]:
    """Names of the robot's links: the body frames of its (reduced) Pinocchio model."""
    return list(dict.fromkeys(f.name for f in robot.model.frames if f.type == pin.FrameType.BODY))


def read_cell(reader: FieldReader, value: Any) -> Cell:
    """The ``cell:`` block: world-fixed obstacle capsules and free half-spaces [m]."""
    spec = reader.mapping(value, "cell", (), ("capsules", "halfspaces"))
    names: set[str] = set()
    capsules = []
    for i, item in enumerate(_list(reader, spec.get("capsules", []), "cell.capsules")):
        key = f"cell.capsules[{i}]"
        item = reader.mapping(item, key, ("name", "a", "b", "radius"))
        name = _unique(reader, item, key, names, _CELL)
        capsules.append(_capsule(reader, item, key, None, name))
    halfspaces = [
        _halfspace(reader, item, f"cell.halfspaces[{i}]", names)
        for i, item in enumerate(_list(reader, spec.get("halfspaces", []), "cell.halfspaces"))
    ]
    return Cell(capsules=tuple(capsules), halfspaces=tuple(halfspaces))


def read_feasibility(reader: FieldReader, value: Any, robot: Robot) -> FeasibilitySettings:
    """The ``feasibility:`` block; absent keys take the defaults of :class:`FeasibilitySettings`."""
    spec = reader.mapping(value, "feasibility", (), FEASIBILITY_KEYS)
    default = FeasibilitySettings()
    key = "feasibility.incidence_limit"
    if "incidence_limit" in spec:
        limit = reader.number(spec["incidence_limit"], key, reader.angle)
        if not 0.0 < limit < math.pi / 2:
            raise reader.fail(key, f"expected an angle in (0, {_angle(reader, math.pi / 2)}) "
                              f"{reader.units['angle']}, got {spec['incidence_limit']!r}")
    else:
        limit = default.incidence_limit

    def length(name: str, fallback: float, positive: bool) -> float:
        if name not in spec:
            return fallback
        return reader.number(spec[name], f"feasibility.{name}", reader.length,
                             positive=positive, nonnegative=not positive)

    links = robot_links(robot)
    prune = reader.mapping(spec.get("prune", {}), "feasibility.prune", (),
                           ("samples", "seed", "distance"))
    return FeasibilitySettings(
        incidence_limit=limit,
        beam_radius=length("beam_radius", default.beam_radius, positive=True),
        reflector_radius=length("reflector_radius", default.reflector_radius, positive=True),
        capsule_margin=length("capsule_margin", default.capsule_margin, positive=False),
        margins=_margins(reader, spec.get("margins", {}), limit, robot),
        excluded_pairs=_excluded_pairs(reader, spec.get("excluded_pairs", []), links),
        robot_capsules=(_robot_capsules(reader, spec["robot_capsules"], links)
                        if "robot_capsules" in spec else None),
        prune_samples=reader.integer(prune.get("samples", default.prune_samples),
                                     "feasibility.prune.samples", 1),
        prune_seed=reader.integer(prune.get("seed", default.prune_seed),
                                  "feasibility.prune.seed", 0),
        prune_distance=(reader.number(prune["distance"], "feasibility.prune.distance",
                                      reader.length, positive=True)
                        if "distance" in prune else default.prune_distance),
    )


def _list(reader: FieldReader, value: Any, key: str) -> list:
    if not isinstance(value, list):
        raise reader.fail(key, f"expected a list, got {value!r}")
    return value


def _unique(reader: FieldReader, item: dict, key: str, seen: set[str], within: str) -> str:
    name = reader.string(item["name"], f"{key}.name")
    if name in seen:
        raise reader.fail(f"{key}.name", f"duplicate name {name!r}; names are unique within "
                          f"{within}")
    seen.add(name)
    return name


def _capsule(reader: FieldReader, item: dict, key: str, frame: str | None, name: str) -> Capsule:
    return Capsule(
        a=reader.vector(item["a"], f"{key}.a", 3, reader.length, what=_XYZ),
        b=reader.vector(item["b"], f"{key}.b", 3, reader.length, what=_XYZ),
        radius=reader.number(item["radius"], f"{key}.radius", reader.length, positive=True),
        frame=frame,
        name=name,
    )


def _halfspace(reader: FieldReader, item: Any, key: str, names: set[str]) -> HalfSpace:
    item = reader.mapping(item, key, ("name",), ("normal", "offset", *HALFSPACE_SHORTHANDS))
    name = _unique(reader, item, key, names, _CELL)
    short = [k for k in HALFSPACE_SHORTHANDS if k in item]
    plane = [k for k in ("normal", "offset") if k in item]
    if len(short) + bool(plane) != 1:
        given = ", ".join(plane + short) or "neither"
        raise reader.fail(key, "expected either 'normal' and 'offset' (free side "
                          f"normal . x >= offset) or exactly one of "
                          f"{', '.join(HALFSPACE_SHORTHANDS)}; got {given}")
    if short:
        normal, sign = HALFSPACE_SHORTHANDS[short[0]]
        value = reader.number(item[short[0]], f"{key}.{short[0]}", reader.length)
        return HalfSpace(np.array(normal), sign * value, name)
    for k in ("normal", "offset"):
        if k not in item:
            raise reader.fail(f"{key}.{k}", "missing required key; a half-space given by its "
                              "plane requires: normal, offset")
    normal = reader.vector(item["normal"], f"{key}.normal", 3, what="nx, ny, nz")
    norm = float(np.linalg.norm(normal))
    if norm < 1e-12:
        raise reader.fail(f"{key}.normal", f"must be non-zero, got {item['normal']!r}")
    offset = reader.number(item["offset"], f"{key}.offset", reader.length)
    return HalfSpace(normal / norm, offset / norm, name)


def _margins(reader: FieldReader, value: Any, incidence_limit: float, robot: Robot) -> Margins:
    spec = reader.mapping(value, "feasibility.margins", (), ("clearance", "incidence", "joint"))
    default = Margins()
    scale = {"clearance": reader.length, "incidence": reader.angle, "joint": reader.angle}
    m = {k: (reader.number(spec[k], f"feasibility.margins.{k}", s, nonnegative=True)
             if k in spec else getattr(default, k)) for k, s in scale.items()}
    unit = reader.units["angle"]
    if not m["incidence"] < incidence_limit:
        raise reader.fail("feasibility.margins.incidence", f"must be below the incidence limit "
                          f"({_angle(reader, incidence_limit)} {unit}), got "
                          f"{_angle(reader, m['incidence'])} {unit}")
    ranges = np.asarray(robot.upper) - np.asarray(robot.lower)
    j = int(np.argmin(ranges))
    if not 2.0 * m["joint"] < ranges[j]:
        raise reader.fail("feasibility.margins.joint", f"{_angle(reader, m['joint'])} {unit} "
                          f"on both sides leaves nothing of the range of {robot.joint_names[j]} "
                          f"({_angle(reader, ranges[j])} {unit})")
    return Margins(**m)


def _excluded_pairs(reader: FieldReader, value: Any, links: list[str]) -> tuple[tuple[str, str], ...]:
    pairs: list[tuple[str, str]] = []
    for i, pair in enumerate(_list(reader, value, "feasibility.excluded_pairs")):
        key = f"feasibility.excluded_pairs[{i}]"
        if not isinstance(pair, list) or len(pair) != 2:
            raise reader.fail(key, f"expected a pair of link names [link_a, link_b], got {pair!r}")
        a, b = (_link(reader, v, f"{key}[{k}]", links) for k, v in enumerate(pair))
        if a == b:
            raise reader.fail(key, f"a link is never checked against itself, got [{a}, {b}]")
        if (a, b) in pairs or (b, a) in pairs:
            raise reader.fail(key, f"duplicate pair [{a}, {b}]")
        pairs.append((a, b))
    return tuple(pairs)


def _robot_capsules(reader: FieldReader, value: Any, links: list[str]) -> tuple[Capsule, ...]:
    key = "feasibility.robot_capsules"
    if not isinstance(value, list) or not value:
        raise reader.fail(key, "expected a non-empty list of capsules {link, a, b, radius, "
                          f"name (optional)}}, got {value!r}; omit the key to fit capsules to "
                          "the URDF collision geometry")
    capsules, names, per_link = [], set(), dict.fromkeys(links, 0)
    for i, item in enumerate(value):
        item = reader.mapping(item, f"{key}[{i}]", ("link", "a", "b", "radius"), ("name",))
        link = _link(reader, item["link"], f"{key}[{i}].link", links)
        item.setdefault("name", f"{link}#{per_link[link]}")
        per_link[link] += 1
        name = _unique(reader, item, f"{key}[{i}]", names, key)
        capsules.append(_capsule(reader, item, f"{key}[{i}]", link, name))
    return tuple(capsules)


def _link(reader: FieldReader, value: Any, key: str, links: list[str]) -> str:
    if not isinstance(value, str) or value not in links:
        raise reader.fail(key, str(UnknownLinkError(value, links)))
    return value


def _angle(reader: FieldReader, value: float) -> str:
    """An SI angle [rad] in the file's angle unit, as text."""
    return f"{value / reader.angle:.6g}"
