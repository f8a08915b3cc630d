r"""The scene key of the joint-space model-error prior: ``robot.model_error`` with ``kind: joint``,
and the same prior taken from an earlier identification (``from:``, ``calib-oed design --prior-from``).

**Keys** (``docs/scenes.md``, "The joint-space prior"), each one number for every joint or a list
of one per joint, in the units their names say (not the file's ``units:``)::

    robot:
      model_error:
        kind: joint
        once_arcsec: 21.2        # RMS of the once-per-revolution transmission error
        twice_arcsec: 10.6       # RMS of the twice-per-revolution one
        smooth_arcsec: 0         # smooth own-angle part (none by default), and its length scale:
        length_deg: 60
        motor_arcsec: 4.12       # motor-side part (once and twice per motor revolution), and its length:
        motor_length_mrad: 15
        gain: 5.0e-5             # standard deviation of the gain (scale) errors [rad/rad]
        stiffness_knm_per_rad: [150, 150, 100, 30, 30, 20]   # or compliance_urad_per_nm
        scale: 1.0               # every amplitude times this
        from: identification.json   # optional: start from an identification, keys above override

A key not given keeps its default for the arm's size class
(:meth:`~calib_oed.measurement.joint_prior.JointErrorPrior.default_for`).

**From an identification** (:func:`spec_from_identification`, the JSON ``calib-oed identify
--json`` writes): the fitted model-error kernel (``model_error.fitted``) gives the length
scales (``length_scales_deg``; a joint the fit ignored keeps its default length and gets no smooth
part), the smooth part's RMS at the measured points (``sigma_mm``) and, if the fit has them, the
once- and twice-per-revolution amplitudes per joint (``harmonic_mm``; a fit without them sets both
to zero: its smooth part holds that variance); the identified compliances ``joint{i}.c`` and gains
``joint{i}.gain`` (``p``, SI) give :math:`\gamma_k = |c_k|`, :math:`\nu_k = |g_k|` where identified.
Amplitudes at the points become joint angles by each joint's lever arm when the criterion is made
(:mod:`calib_oed.calibration.joint_prior_choice`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib_oed.exceptions import IdentificationFileError
from calib_oed.measurement.joint_prior import ARCSEC
from calib_oed.scene.fields import FieldReader
from calib_oed.scene.records import JointErrorSpec

#: Keys of ``robot.model_error`` with ``kind: joint``: name -> (part, factor to SI, > 0 required).
JOINT_KEYS = {
    "once_arcsec": ("once", ARCSEC, False),
    "twice_arcsec": ("twice", ARCSEC, False),
    "smooth_arcsec": ("smooth", ARCSEC, False),
    "length_deg": ("length", np.pi / 180.0, True),
    "motor_arcsec": ("motor", ARCSEC, False),
    "motor_length_mrad": ("motor_length", 1e-3, True),
    "gain": ("gain", 1.0, False),
    "compliance_urad_per_nm": ("compliance", 1e-6, False),
    "stiffness_knm_per_rad": ("compliance", 1e3, True),  # inverted below
}
_OTHER = ("scale", "from")


def read_joint_error(reader: FieldReader, spec: dict, nq: int, key: str = "robot.model_error") -> JointErrorSpec:
    """``robot.model_error`` with ``kind: joint`` (module docstring) for an arm of ``nq`` joints.

    Raises:
        SceneError: naming the key and what is valid (through ``reader.fail``).
    """
    if spec.get("kind") != "joint":
        raise reader.fail(f"{key}.kind", f"expected 'joint' (the joint-space prior), got {spec.get('kind')!r}; "
                          "without kind, robot.model_error is the isotropic prior {sigma, length_scales}")
    spec = reader.mapping(spec, key, ("kind",), tuple(JOINT_KEYS) + _OTHER)
    if "compliance_urad_per_nm" in spec and "stiffness_knm_per_rad" in spec:
        raise reader.fail(f"{key}.stiffness_knm_per_rad", "give compliance_urad_per_nm or "
                          "stiffness_knm_per_rad, not both")
    base = JointErrorSpec(source="scene")
    if "from" in spec:
        path = _path(reader, spec["from"])
        try:
            base = spec_from_identification(load_identification(path), nq, str(path))
        except IdentificationFileError as exc:
            raise reader.fail(f"{key}.from", str(exc)) from None
    values = dict(base.values)
    for name, (part, factor, positive) in JOINT_KEYS.items():
        if name not in spec:
            continue
        where = f"{key}.{name}"
        raw = spec[name] if isinstance(spec[name], list) else [spec[name]] * nq
        if len(raw) != nq:
            raise reader.fail(where, f"expected one number or {nq} (one per joint), got {len(raw)}")
        arr = np.array([reader.number(v, f"{where}[{i}]", positive=positive, nonnegative=True)
                        for i, v in enumerate(raw)])
        values[part] = 1.0 / (arr * factor) if name == "stiffness_knm_per_rad" else arr * factor
    at_point = {k: v for k, v in base.at_point.items() if k not in values}
    scale = reader.number(spec.get("scale", 1.0), f"{key}.scale", positive=True)
    source = "scene" if "from" not in spec else f"scene, from {base.source}"
    return JointErrorSpec(values, at_point, scale, source)


def _path(reader: FieldReader, value) -> Path:
    path = Path(reader.string(value, "robot.model_error.from")).expanduser()
    if not path.is_absolute():
        path = (Path(reader.source).parent if reader.source else Path.cwd()) / path
    return path


def load_identification(path) -> dict:
    """The JSON ``calib-oed identify --json`` wrote, as a dict.

    Raises:
        IdentificationFileError: unreadable, not JSON, or not a mapping.
    """
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise IdentificationFileError(f"cannot read {path} as JSON ({exc}); give the "
                                      "identification.json `calib-oed identify` wrote") from None
    if not isinstance(data, dict):
        raise IdentificationFileError(f"{path} is not an identification JSON (expected a mapping)")
    return data


def spec_from_identification(data: dict, nq: int, source: str = "identification") -> JointErrorSpec:
    """The joint prior's parts an identification JSON determines (module docstring).

    Raises:
        IdentificationFileError: no fitted model error, or values of the wrong size or sign.
    """
    fitted = (data.get("model_error") or {}).get("fitted") if isinstance(data.get("model_error"), dict) else None
    if not isinstance(fitted, dict) or "sigma_mm" not in fitted or "length_scales_deg" not in fitted:
        raise IdentificationFileError(f"{source} has no model_error.fitted (sigma_mm, length_scales_deg); "
                                      "give the identification.json of `calib-oed identify` (this version or later)")
    try:
        sigma = float(fitted["sigma_mm"]) * 1e-3
        ell = np.array([np.inf if v is None else float(v) for v in np.atleast_1d(fitted["length_scales_deg"])])
        harmonic = np.asarray(fitted.get("harmonic_mm", []), dtype=float) * 1e-3
    except (TypeError, ValueError) as exc:
        raise IdentificationFileError(f"{source}: model_error.fitted holds a value that is not a number ({exc})") from None
    if ell.size != nq or not np.isfinite(sigma) or sigma < 0 or np.any(ell <= 0):
        raise IdentificationFileError(f"{source}: model_error.fitted needs sigma_mm >= 0 and {nq} length "
                                      f"scales > 0 (one per joint of this robot), got {ell.size}")
    finite = np.isfinite(ell)
    values = {"length": np.where(finite, np.radians(np.where(finite, ell, 1.0)), np.nan)}
    at_point = {"smooth": np.where(finite, sigma, 0.0)}
    if harmonic.size:
        if harmonic.shape != (nq, 2) or np.any(harmonic < 0):
            raise IdentificationFileError(f"{source}: model_error.fitted.harmonic_mm needs {nq} pairs "
                                          f"(once, twice per revolution) >= 0, got shape {harmonic.shape}")
        at_point["once"], at_point["twice"] = harmonic[:, 0].copy(), harmonic[:, 1].copy()
    else:  # the fit put the transmission errors into its smooth part
        values["once"] = values["twice"] = np.zeros(nq)
    p = data.get("p") if isinstance(data.get("p"), dict) else {}
    for part, suffix in (("compliance", "c"), ("gain", "gain")):
        found = {i: p.get(f"joint{i + 1}.{suffix}") for i in range(nq)}
        if any(isinstance(v, (int, float)) and v != 0 for v in found.values()):
            values[part] = np.array([abs(float(v)) if isinstance(v, (int, float)) else np.nan
                                     for v in found.values()])
    return JointErrorSpec(values, at_point, 1.0, source)
