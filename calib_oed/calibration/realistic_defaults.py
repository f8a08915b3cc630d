r"""Magnitudes of the realistic simulator (:mod:`calib_oed.calibration.realistic`) and their sources.

Typical values per robot size class, chosen by the arm's mass in its URDF
(sum of the link inertials): **small** below 50 kg (collaborative arms with
harmonic drives, e.g. UR5: 17 kg in its URDF), **medium** 50-300 kg (KR 16
class: 168 kg), **large** from 300 kg (KR 300 / KR 500 class). Sources and
reasoning in ``docs/identification.md`` (the realistic simulator):

- joint stiffness [N·m/rad], J1..J6: large arms' main axes 1e6-5e6 (J2 the
  stiffest), wrists 2e5-5e5, the order identified on KUKA KR 240-class arms
  (Dumas et al., "Joint stiffness identification of six-revolute industrial
  serial robots", RCIM 27(4), 2011); small arms about 1e5 on the main axes;
  medium arms between (our interpolation). Each truth draws every joint's
  value log-normally about the typical one (spread 0.3 in log);
- gear ratios (motor turns per joint turn): 100-200 on the main axes and 50-100
  on the wrist of RV/cycloidal reducers; 100 for harmonic drives (typical values);
- periodic transmission error at the joint output: precision reducers are
  specified by an angular transmission error of about 1 arcmin peak to peak,
  so 30 arcsec (once) and 15 arcsec (twice per joint revolution); the motor's
  own harmonics and those of the input stage reach the output reduced, a few
  arcsec (5 and 3 arcsec); each truth draws every amplitude uniformly in
  [0.5, 1.5] times these, every phase uniformly;
- J2 balancer: heavy KUKA-class arms carry a spring balancer that takes about
  half of the arm's gravity torque on J2; collaborative arms have none;
- thermal drift (off by default): steel/cast arm, :math:`\alpha` = 11.7e-6 /K,
  2 K warming over the session;
- joint gain errors: a scale error of each joint's angle (gear ratio, encoder),
  normal with standard deviation 5e-5 (0.05 mrad per rad: 0.1 mrad over a 2 rad
  sweep; identified gains of real arms are of the order 1e-4, -0.5 % is implausible);
- tracker: range scale error normal with 2 ppm standard deviation (air
  refraction: 1 ppm per 1 K or per 3.7 hPa of error in the weather station);
  residual angle-encoder eccentricity 1.5 arcsec (7 µrad, about the 6 µm/m
  transverse MPE of a current tracker).

``level`` scales every unmodelled component together; 1 (the default) makes
the error left after the geometric fit 4-12 times the measurement noise on the
shipped scenes (RMS over 30 new poses of a 60-pose fit, 3 truths each: fms_kr16
6.9-11.2, ur5_table 4.4-5.9; ``tests/calibration/test_realistic.py`` holds them
to this band).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from calib_oed.exceptions import ParameterError
from calib_oed.model.compliance import NEST_MASS
from calib_oed.model.size_class import TYPICAL, SizeDefaults, per_joint, size_class_of
from calib_oed.scene.fields import FieldReader
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS

ARCSEC = np.pi / (180.0 * 3600.0)

@dataclass(frozen=True)
class RealisticSettings:
    """What the realistic truth contains and how large (the scene's ``realistic:`` block, SI).

    Attributes:
        level: Scale of every unmodelled component (>= 0; 0: today's geometric truth).
        geometric, compliance, transmission, balancer, thermal, tracker: Switches (``gains`` below).
        sigma_length: Geometric errors' standard deviation, lengths [m].
        sigma_angle: The same, angles [rad].
        stiffness: Joint stiffness (nv,) [N·m/rad] or None: the size class's.
        stiffness_spread: Log-normal spread of the drawn stiffness [1].
        payload_mass: Payload [kg]; None: the scene's ``robot.compliance.payload`` (else 0).
        payload_com: Its centre of mass in the tool frame (3,) [m]; with ``payload_mass``.
        nest_mass: Reflector nest(s) and stem on the tool [kg], at the reflectors' centroid.
        joint_cyclic: Transmission error amplitudes per joint revolution, once and twice [rad].
        motor_cyclic: Transmission error amplitudes per motor revolution at the joint [rad].
        gear_ratios: Motor turns per joint turn (nv,) or None: the size class's.
        balancer_fraction: Share of the J2 gravity torque the balancer carries or None: the size class's.
        balancer_rho, balancer_kappa: Balancer geometry and spring progression [1].
        thermal_alpha: Expansion coefficient [1/K]; ``thermal_delta_t``: warming over the session [K].
        tracker_scale_ppm: Standard deviation of the tracker's range scale error [ppm].
        encoder_eccentricity: Typical angle-encoder eccentricity of each axis [rad].
        gross_errors: Number of measurements with a gross error.
        gross_size: Size of each gross error [m].
        gains: Switch of the joint gain errors; ``sigma_gain``: their standard deviation [rad/rad].
    """

    level: float = 1.0
    geometric: bool = True
    compliance: bool = True
    transmission: bool = True
    balancer: bool = True
    thermal: bool = False
    tracker: bool = True
    gains: bool = True
    sigma_length: float = 0.5e-3
    sigma_angle: float = 0.5e-3
    stiffness: tuple[float, ...] | None = None
    stiffness_spread: float = 0.3
    payload_mass: float | None = None
    payload_com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    nest_mass: float = NEST_MASS
    joint_cyclic: tuple[float, float] = (30 * ARCSEC, 15 * ARCSEC)
    motor_cyclic: tuple[float, float] = (5 * ARCSEC, 3 * ARCSEC)
    gear_ratios: tuple[float, ...] | None = None
    balancer_fraction: float | None = None
    balancer_rho: float = 0.25
    balancer_kappa: float = 0.5
    thermal_alpha: float = 11.7e-6
    thermal_delta_t: float = 2.0
    tracker_scale_ppm: float = 2.0
    encoder_eccentricity: float = 1.5 * ARCSEC
    gross_errors: int = 0
    gross_size: float = 5e-3
    sigma_gain: float = 5e-5

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type == "bool":
                if not isinstance(v, (bool, np.bool_)):
                    raise ParameterError(f"realistic.{f.name} must be true or false, got {v!r}")
                continue
            if v is None:
                continue
            arr = np.asarray(v, dtype=float) if not isinstance(v, str) else np.array([np.nan])
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ParameterError(f"realistic.{f.name} must be finite and >= 0, got {v!r}")
            if f.name == "payload_com":
                continue
            if f.name in ("stiffness", "gear_ratios") and np.any(arr <= 0):
                raise ParameterError(f"realistic.{f.name} must be > 0 for every joint, got {v!r}")
        if int(self.gross_errors) != self.gross_errors:
            raise ParameterError(f"realistic.gross_errors must be a whole number >= 0, got {self.gross_errors!r}")
        if not 0 <= self.balancer_rho < 1:
            raise ParameterError(f"realistic.balancer_rho must lie in [0, 1), got {self.balancer_rho!r}")

    @staticmethod
    def size_class_of(arm_mass: float) -> str:
        """The size class of an arm of ``arm_mass`` [kg] (:mod:`calib_oed.model.size_class`)."""
        return size_class_of(arm_mass)

    def table(self, size: str, nv: int) -> SizeDefaults:
        """The typical values for ``nv`` joints, with this record's overrides."""
        d = TYPICAL[size]

        def given_or_typical(given, typical, what):
            if given is not None:
                arr = np.asarray(given, dtype=float)
                if arr.shape != (nv,):
                    raise ParameterError(f"realistic.{what}: one value per joint ({nv}), got {len(arr)}")
                return arr
            return per_joint(typical, nv)

        frac = d.balancer_fraction if self.balancer_fraction is None else float(self.balancer_fraction)
        return SizeDefaults(given_or_typical(self.stiffness, d.stiffness, "stiffness"),
                            given_or_typical(self.gear_ratios, d.gear_ratios, "gear_ratios"), frac)

    def payload_of(self, scene) -> tuple[float, np.ndarray]:
        """Payload mass [kg] and centre of mass (3,) [m]: this record's, else the scene's, else 0."""
        if self.payload_mass is not None:
            return float(self.payload_mass), np.asarray(self.payload_com, dtype=float)
        spec = getattr(scene, "compliance", None)
        if spec is not None:
            return float(spec.payload.payload_mass), np.asarray(spec.payload.payload_com, dtype=float)
        return 0.0, np.zeros(3)

    @classmethod
    def from_record(cls, record: dict) -> RealisticSettings:
        """The settings :meth:`describe` wrote (SI)."""
        names = {f.name: f for f in fields(cls)}
        unknown = sorted(set(record) - set(names))
        if unknown:
            raise ParameterError(f"realistic settings: unknown key(s) {', '.join(unknown)}; "
                                 f"valid keys: {', '.join(names)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in record.items()})

    def describe(self) -> dict:
        """Every setting by name (SI; tuples as lists), for the truth file."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, tuple):
                v = list(map(float, v))
            elif isinstance(v, (bool, np.bool_)):
                v = bool(v)
            elif v is not None:
                v = int(v) if f.name == "gross_errors" else float(v)
            out[f.name] = v
        return out


#: Keys of the scene's ``realistic:`` block (docs/scenes.md).
SCENE_KEYS = ("level", "geometric", "compliance", "transmission", "balancer", "thermal", "tracker", "gains",
              "sigma_length", "sigma_angle", "stiffness", "stiffness_spread", "payload", "nest_mass",
              "joint_cyclic_arcsec", "motor_cyclic_arcsec", "gear_ratios", "balancer_fraction",
              "balancer_rho", "balancer_kappa", "thermal_alpha", "thermal_delta_t", "tracker_scale_ppm",
              "encoder_eccentricity_arcsec", "gross_errors", "gross_size", "sigma_gain")


def realistic_settings_from_scene(scene) -> RealisticSettings:
    """The settings of a scene's optional ``realistic:`` block (defaults where absent).

    Lengths (``sigma_length``, ``gross_size``, ``payload.com``) in the file's length unit,
    ``sigma_angle`` in its angle unit; the other keys carry their unit in the name or are
    SI (stiffness N·m/rad, masses kg, ``thermal_alpha`` 1/K, ``thermal_delta_t`` K).

    Raises:
        SceneError: an unknown key or a bad value, naming the key.
    """
    block = getattr(scene, "realistic", None) or {}
    reader = FieldReader(str(scene.source) if scene.source else None)
    reader.length = LENGTH_UNITS[scene.units.get("length", "m")]
    reader.angle = ANGLE_UNITS[scene.units.get("angle", "rad")]
    spec = reader.mapping(block, "realistic", (), SCENE_KEYS)
    nv = scene.robot.model.nv
    values: dict = {}
    for key in ("geometric", "compliance", "transmission", "balancer", "thermal", "tracker", "gains"):
        if key in spec:
            if not isinstance(spec[key], bool):
                raise reader.fail(f"realistic.{key}", f"expected true or false, got {spec[key]!r}")
            values[key] = spec[key]
    scales = {"sigma_length": reader.length, "sigma_angle": reader.angle, "gross_size": reader.length,
              "encoder_eccentricity_arcsec": ARCSEC}
    for key in ("level", "sigma_length", "sigma_angle", "stiffness_spread", "nest_mass", "balancer_fraction",
                "balancer_rho", "balancer_kappa", "thermal_alpha", "thermal_delta_t", "tracker_scale_ppm",
                "encoder_eccentricity_arcsec", "gross_size", "sigma_gain"):
        if key in spec:
            values[key.removesuffix("_arcsec")] = reader.number(spec[key], f"realistic.{key}",
                                                                scales.get(key, 1.0), nonnegative=True)
    if "gross_errors" in spec:
        values["gross_errors"] = reader.integer(spec["gross_errors"], "realistic.gross_errors", 0)
    for key in ("stiffness", "gear_ratios"):
        if key in spec:
            values[key] = tuple(map(float, reader.vector(spec[key], f"realistic.{key}", nv, what="one per joint")))
    for key in ("joint_cyclic_arcsec", "motor_cyclic_arcsec"):
        if key in spec:
            values[key.removesuffix("_arcsec")] = tuple(map(float, reader.vector(
                spec[key], f"realistic.{key}", 2, ARCSEC, what="once, twice per revolution")))
    if "payload" in spec:
        load = reader.mapping(spec["payload"], "realistic.payload", ("mass",), ("com",))
        values["payload_mass"] = reader.number(load["mass"], "realistic.payload.mass", nonnegative=True)
        values["payload_com"] = tuple(map(float, reader.vector(load.get("com", [0, 0, 0]),
                                                               "realistic.payload.com", 3, reader.length)))
    return RealisticSettings(**values)
