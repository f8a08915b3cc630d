r"""Scene file blocks ``cell:`` and ``feasibility:``: the obstacles and the feasibility settings.

Read by :class:`calib_oed.scene.reader.FieldReader` (same validation style: errors name the
dotted key and the valid choices) into the records of
:mod:`calib_oed.feasibility.shapes`, in SI [m, rad]. Lengths in the file are in
its length unit, angles in its angle unit. Schema: ``docs/scenes.md``.

A half-space keeps the free side :math:`n^\top x \ge c` as written in the file;
the normal need not be unit length (both :math:`n` and :math:`c` are divided by
:math:`\lVert n \rVert`). The shorthands ``x_min: v`` (:math:`x \ge v`) and
``x_max: v`` (:math:`x \le v`), and likewise for y and z, give axis-aligned planes.

Solid obstacles: ``boxes`` (``center``, ``size`` = side lengths, ``rpy``),
``cylinders`` (``center``, ``radius``, ``length`` along the local z axis,
``rpy``), ``spheres`` (``center``, ``radius``; a capsule with ``a == b``) and
``meshes`` (``file``, STL/OBJ/... read by coal's assimp loader, relative to the
scene file; its coordinates times ``scale`` (a number or x, y, z) are in the
scene's length unit, then rotated by ``rpy`` and moved by ``xyz``; checked as
their convex hull). ``rpy`` is :math:`R_{W,O} = R_z(y)R_y(p)R_x(r)`, as for the
tracker. Every obstacle takes ``ignore_links``: robot links never checked
against it (``[base_link]`` for the floor the base stands on).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import coal
import numpy as np
import pinocchio as pin

from calib_oed.exceptions import UnknownLinkError
from calib_oed.feasibility.shapes import (
    LINK_FITS,
    Box,
    Capsule,
    Cell,
    Cylinder,
    FeasibilitySettings,
    HalfSpace,
    Margins,
    MeshObstacle,
)
from calib_oed.feasibility.window import JOINT_WINDOWS

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
                    "margins", "excluded_pairs", "robot_capsules", "prune", "link_fit",
                    "joint_window")
_XYZ = "x, y, z"
CELL_KEYS = ("capsules", "halfspaces", "boxes", "cylinders", "spheres", "meshes")
_CELL = "the cell's obstacles (" + ", ".join(CELL_KEYS) + ")"


def robot_links(robot: Robot) -> list[str]:
    """Names of the robot's links: the body frames of its (reduced) Pinocchio model."""
    return list(dict.fromkeys(f.name for f in robot.model.frames if f.type == pin.FrameType.BODY))


def read_cell(reader: FieldReader, value: Any, robot: Robot | None = None) -> Cell:
    """The ``cell:`` block: world-fixed obstacles [m] (module docstring); ``ignore_links``
    are checked against ``robot``'s links when it is given."""
    spec = reader.mapping(value, "cell", (), CELL_KEYS)
    names: set[str] = set()
    links = robot_links(robot) if robot is not None else None
    out: dict[str, list] = {k: [] for k in CELL_KEYS}
    for kind in CELL_KEYS:
        for i, item in enumerate(_list(reader, spec.get(kind, []), f"cell.{kind}")):
            key = f"cell.{kind}[{i}]"
            if kind == "halfspaces":
                out[kind].append(_halfspace(reader, item, key, names, links))
                continue
            item = reader.mapping(item, key, ("name", *_REQUIRED[kind]), ("ignore_links", *_OPTIONAL[kind]))
            name = _unique(reader, item, key, names, _CELL)
            ignore = _ignore(reader, item, key, links)
            out[kind].append(_SOLID_READERS[kind](reader, item, key, name, ignore))
    return Cell(capsules=tuple(out["capsules"] + out["spheres"]), halfspaces=tuple(out["halfspaces"]),
                boxes=tuple(out["boxes"]), cylinders=tuple(out["cylinders"]), meshes=tuple(out["meshes"]))


def reflector_normal(reader: FieldReader, value: Any, i: int) -> np.ndarray:
    """``reflectors[i].normal``: the reflector's axis in the tool frame, normalised."""
    key = f"reflectors[{i}].normal"
    normal = reader.vector(value, key, 3, what="nx, ny, nz")
    norm = float(np.linalg.norm(normal))
    if norm < 1e-12:
        raise reader.fail(key, f"must be non-zero (the reflector's axis in the tool frame), got {value!r}")
    return normal / norm


_REQUIRED = {"capsules": ("a", "b", "radius"), "boxes": ("center", "size"),
             "cylinders": ("center", "radius", "length"), "spheres": ("center", "radius"),
             "meshes": ("file",)}
_OPTIONAL = {"capsules": (), "boxes": ("rpy",), "cylinders": ("rpy",), "spheres": (),
             "meshes": ("scale", "xyz", "rpy")}


def _ignore(reader: FieldReader, item: dict, key: str, links: list[str] | None) -> tuple[str, ...]:
    value = item.get("ignore_links", [])
    if not isinstance(value, list):
        raise reader.fail(f"{key}.ignore_links", f"expected a list of link names, got {value!r}")
    if links is None:
        return tuple(reader.string(v, f"{key}.ignore_links[{j}]") for j, v in enumerate(value))
    return tuple(_link(reader, v, f"{key}.ignore_links[{j}]", links) for j, v in enumerate(value))


def _rotation(reader: FieldReader, item: dict, key: str) -> np.ndarray:
    if "rpy" not in item:
        return np.eye(3)
    rpy = reader.vector(item["rpy"], f"{key}.rpy", 3, reader.angle, what="roll, pitch, yaw")
    return pin.rpy.rpyToMatrix(*rpy)


def _length(reader: FieldReader, item: dict, key: str, name: str) -> float:
    return reader.number(item[name], f"{key}.{name}", reader.length, positive=True)


def _read_capsule(reader, item, key, name, ignore):
    return replace(_capsule(reader, item, key, None, name), ignore_links=ignore)


def _read_sphere(reader, item, key, name, ignore):
    c = reader.vector(item["center"], f"{key}.center", 3, reader.length, what=_XYZ)
    return Capsule(c, c, _length(reader, item, key, "radius"), None, name, ignore)


def _read_box(reader, item, key, name, ignore):
    size = reader.vector(item["size"], f"{key}.size", 3, reader.length, what="side lengths x, y, z")
    if np.any(size <= 0):
        raise reader.fail(f"{key}.size", f"expected side lengths > 0, got {item['size']!r}")
    return Box(reader.vector(item["center"], f"{key}.center", 3, reader.length, what=_XYZ), size,
               _rotation(reader, item, key), name, ignore)


def _read_cylinder(reader, item, key, name, ignore):
    return Cylinder(reader.vector(item["center"], f"{key}.center", 3, reader.length, what=_XYZ),
                    _length(reader, item, key, "radius"), _length(reader, item, key, "length"),
                    _rotation(reader, item, key), name, ignore)


def _read_mesh(reader, item, key, name, ignore):
    path = Path(reader.string(item["file"], f"{key}.file"))
    if not path.is_absolute():
        path = (Path(reader.source).parent if reader.source else Path.cwd()) / path
    if not path.is_file():
        raise reader.fail(f"{key}.file", f"mesh file not found: {path} (a path relative to the scene file)")
    scale = (reader.vector3_or_scalar(item["scale"], f"{key}.scale", 1.0) if "scale" in item
             else np.ones(3))
    if np.any(scale <= 0):
        raise reader.fail(f"{key}.scale", f"expected a scale > 0 (a number or x, y, z), got {item['scale']!r}")
    try:
        bvh = coal.MeshLoader().load(str(path), np.asarray(scale, dtype=float))
    except ValueError as exc:
        raise reader.fail(f"{key}.file", f"cannot read the mesh {path}: {str(exc).splitlines()[-1]}") from exc
    vertices = np.array([bvh.vertex(i) for i in range(bvh.num_vertices)]).reshape(-1, 3) * reader.length
    xyz = (reader.vector(item["xyz"], f"{key}.xyz", 3, reader.length, what=_XYZ) if "xyz" in item
           else np.zeros(3))
    try:
        return MeshObstacle(vertices @ _rotation(reader, item, key).T + xyz, name, ignore, str(path))
    except ValueError as exc:
        raise reader.fail(f"{key}.file", str(exc)) from exc


_SOLID_READERS = {"capsules": _read_capsule, "spheres": _read_sphere, "boxes": _read_box,
                  "cylinders": _read_cylinder, "meshes": _read_mesh}


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
        link_fit=reader.string(spec.get("link_fit", default.link_fit), "feasibility.link_fit",
                               LINK_FITS),
        joint_window=reader.string(spec.get("joint_window", default.joint_window),
                                   "feasibility.joint_window", JOINT_WINDOWS),
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


def _halfspace(reader: FieldReader, item: Any, key: str, names: set[str],
               links: list[str] | None = None) -> HalfSpace:
    item = reader.mapping(item, key, ("name",), ("normal", "offset", *HALFSPACE_SHORTHANDS, "ignore_links"))
    name = _unique(reader, item, key, names, _CELL)
    ignore = _ignore(reader, item, key, links)
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
        return HalfSpace(np.array(normal), sign * value, name, ignore)
    for k in ("normal", "offset"):
        if k not in item:
            raise reader.fail(f"{key}.{k}", "missing required key; a half-space given by its "
                              "plane requires: normal, offset")
    normal = reader.vector(item["normal"], f"{key}.normal", 3, what="nx, ny, nz")
    norm = float(np.linalg.norm(normal))
    if norm < 1e-12:
        raise reader.fail(f"{key}.normal", f"must be non-zero, got {item['normal']!r}")
    offset = reader.number(item["offset"], f"{key}.offset", reader.length)
    return HalfSpace(normal / norm, offset / norm, name, ignore)


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
