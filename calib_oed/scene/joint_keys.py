"""Scene keys for the optional joint parameters: ``robot.compliance``, ``robot.joint_gains``
and the model-error prior ``robot.model_error``.

Both sit under ``robot:`` and are read after the robot (they need its joint
count) and, for the couplings, the ``controller:`` block. Units follow the
file's ``units:`` (lengths of centres of mass); masses are in kg.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib_oed.exceptions import ParameterError, ShapeError
from calib_oed.measurement.discrepancy import KERNELS, DiscrepancyPrior, linear_joints_of
from calib_oed.model.compliance import Compliance
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.joint_map import JointGains
from calib_oed.scene.fields import FieldReader
from calib_oed.scene.records import ComplianceSpec

#: The heaviest payload of any industrial robot is about 2.3 t (FANUC M-2000iA/2300).
MAX_PAYLOAD_KG = 2500.0


def read_compliance(reader: FieldReader, value, n: int) -> ComplianceSpec:
    """``robot.compliance: {enabled, payload: {mass, com}, links}`` for a robot with ``n`` joints.

    ``links`` says where the arm's own weight comes from: ``urdf`` (default: the
    URDF's inertias), ``none`` (the payload alone: no link weighs anything) or a
    list of ``n`` entries ``{mass: kg, com: [x, y, z]}``, one per joint, base to
    tip: the link moved by that joint as a point mass at ``com`` in the joint's
    frame (file length units; default the joint origin). A scene list replaces
    the URDF's inertias (use it when the URDF has none).
    """
    key = "robot.compliance"
    spec = reader.mapping(value, key, (), ("enabled", "payload", "links"))
    enabled = spec.get("enabled", True)
    if not isinstance(enabled, bool):
        raise reader.fail(f"{key}.enabled", f"expected true or false, got {enabled!r}")
    load = reader.mapping(spec.get("payload", {}), f"{key}.payload", (), ("mass", "com"))
    mass = reader.number(load.get("mass", 0.0), f"{key}.payload.mass", nonnegative=True)
    if mass > MAX_PAYLOAD_KG:
        raise reader.fail(f"{key}.payload.mass", f"{mass:g} kg: no industrial robot carries more than "
                          f"{MAX_PAYLOAD_KG:g} kg (grams typed as kg?); give the payload in kg")
    com = reader.vector(load.get("com", [0, 0, 0]), f"{key}.payload.com", 3, reader.length)
    links = spec.get("links", "urdf")
    masses = coms = None
    if links == "none":
        masses = np.zeros(n)
    elif isinstance(links, list):
        if len(links) != n:
            raise reader.fail(f"{key}.links", f"expected {n} entries (one per joint, base to tip), "
                              f"got {len(links)}")
        masses, coms = np.zeros(n), np.zeros((n, 3))
        for i, entry in enumerate(links):
            where = f"{key}.links[{i}]"
            entry = reader.mapping(entry, where, ("mass",), ("com",))
            masses[i] = reader.number(entry["mass"], f"{where}.mass", nonnegative=True)
            coms[i] = reader.vector(entry.get("com", [0, 0, 0]), f"{where}.com", 3, reader.length)
    elif links != "urdf":
        raise reader.fail(f"{key}.links", "expected 'urdf' (the URDF's inertias), 'none' (the payload "
                          f"alone) or a list of {n} entries {{mass: kg, com: [x, y, z]}}, got {links!r}")
    return ComplianceSpec(enabled, Compliance(mass, com, link_masses=masses, link_coms=coms))


def read_joint_gains(reader: FieldReader, value, n: int,
                     controller: ControllerConvention | None) -> JointGains | None:
    """``robot.joint_gains: {enabled, joints, couplings}``; None when disabled.

    ``joints``: ``all`` (default) or a list of joint numbers 1..n with a gain
    each; ``couplings``: false (default) or true, one ratio per coupling of the
    scene's ``controller:`` block (which must then list some). ``true`` alone is
    short for ``{}`` (every joint's gain, no couplings).
    """
    key = "robot.joint_gains"
    if value is True:
        value = {}
    spec = reader.mapping(value, key, (), ("enabled", "joints", "couplings"))
    enabled = spec.get("enabled", True)
    if not isinstance(enabled, bool):
        raise reader.fail(f"{key}.enabled", f"expected true or false, got {enabled!r}")
    joints = spec.get("joints", "all")
    if joints == "all":
        joints = list(range(1, n + 1))
    elif not isinstance(joints, list) or any(
            isinstance(i, bool) or not isinstance(i, int) or not 1 <= i <= n for i in joints):
        raise reader.fail(f"{key}.joints", f"expected 'all' or a list of joint numbers 1..{n}, "
                          f"got {joints!r}")
    couplings = spec.get("couplings", False)
    if not isinstance(couplings, bool):
        raise reader.fail(f"{key}.couplings", f"expected true or false, got {couplings!r}")
    pairs = ()
    if couplings:
        if controller is None or not controller.couplings:
            raise reader.fail(f"{key}.couplings", "true needs a controller: block with couplings "
                              "(e.g. {joint: 3, from: 2, ratio: 1} for FANUC's J2/J3); this scene has "
                              + ("none" if controller is None else "a controller without couplings"))
        pairs = tuple((c.joint, c.source) for c in controller.couplings)
    if not joints and not pairs:
        raise reader.fail(key, "expected at least one joint or couplings: true")
    return JointGains(tuple(joints), pairs) if enabled else None


def read_model_error(reader: FieldReader, value, robot) -> DiscrepancyPrior:
    """``robot.model_error``: the model-error prior (:mod:`calib_oed.measurement.discrepancy`).

    ``{sigma, length_scales, kernel, sigma_white}`` in the file's units (``sigma`` and the
    white part ``sigma_white`` lengths per Cartesian axis; ``length_scales`` one angle per joint, a length for a prismatic
    joint, or one number for all; ``.inf`` ignores a joint), or
    ``{from: identification.json}``: the hyperparameters an earlier
    ``calib-oed identify --json`` fitted (its ``model_error``), path relative to the scene.
    """
    key = "robot.model_error"
    spec = reader.mapping(value, key, (), ("sigma", "length_scales", "kernel", "sigma_white", "from"))
    if "from" in spec:
        if set(spec) != {"from"}:
            raise reader.fail(key, "give either 'from' (an identification JSON) or sigma and "
                              f"length_scales, not both (got {sorted(spec)})")
        return _model_error_from_file(reader, spec["from"], robot.nq)
    for k in ("sigma", "length_scales"):
        if k not in spec:
            raise reader.fail(f"{key}.{k}", "missing; robot.model_error needs sigma and "
                              "length_scales, or from: <identification JSON>")
    sigma = reader.number(spec["sigma"], f"{key}.sigma", reader.length, nonnegative=True)
    prismatic = [j.shortname().startswith("JointModelP") for j in robot.model.joints[1:]]
    scale = np.where(prismatic, reader.length, reader.angle)
    ell = spec["length_scales"]
    raw = ell if isinstance(ell, list) else [ell] * robot.nq
    if len(raw) != robot.nq:
        raise reader.fail(f"{key}.length_scales", f"expected one number or {robot.nq} (one per "
                          f"joint: {', '.join(robot.joint_names)}), got {len(raw)}")
    values = []
    for i, v in enumerate(raw):
        if isinstance(v, (int, float)) and not isinstance(v, bool) and v == np.inf:
            values.append(np.inf)
        else:
            values.append(reader.number(v, f"{key}.length_scales[{i}]", scale[i], positive=True))
    if all(np.isinf(values)):
        raise reader.fail(f"{key}.length_scales", "at least one joint needs a finite length scale")
    kernel = reader.string(spec.get("kernel", "matern52"), f"{key}.kernel", KERNELS)
    white = reader.number(spec.get("sigma_white", 0.0), f"{key}.sigma_white", reader.length,
                          nonnegative=True)
    return DiscrepancyPrior(sigma, tuple(values), kernel, "scene", white, linear_joints_of(robot))


def _model_error_from_file(reader: FieldReader, value, nq: int) -> DiscrepancyPrior:
    key = "robot.model_error.from"
    path = Path(reader.string(value, key)).expanduser()
    if not path.is_absolute():
        path = (Path(reader.source).parent if reader.source else Path.cwd()) / path
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise reader.fail(key, f"cannot read {path} as JSON ({exc}); give the file "
                          "`calib-oed identify --json` wrote") from exc
    found = data.get("model_error") if isinstance(data, dict) else None
    if not isinstance(found, dict) or "fitted" not in found:
        raise reader.fail(key, f"{path} has no model_error.fitted; give the JSON of "
                          "`calib-oed identify --json` (this version or later)")
    try:
        return DiscrepancyPrior.from_dict(found["fitted"], nq, source=str(path))
    except (ParameterError, ShapeError) as exc:
        raise reader.fail(key, f"{path}: {exc}") from exc
