r"""Validation of a calibration on measurements it was not identified from.

What a metrology engineer runs after exporting a calibration (RoboDK calls it
validation): measure the robot at a separate set of configurations, predict
each measurement with the *exported* files (calibrated URDF and sensor YAML),
and compare. The same prediction with the nominal model (the scene's URDF,
tracker pose and reflector offsets) shows the improvement.

For a measurement row :math:`k` with reflector :math:`j` the residual is

.. math::
    r_k = \eta_k - T_{W,T}^{-1}\,\big(T_{W,E}(q_k)\,c_j\big) \quad [\mathrm{m}],

in the tracker frame, and the position error is :math:`\|r_k\|` [mm in
reports]; 6-D probe rows also have a rotation residual
:math:`\log_3(R_{\mathrm{pred}}^\top R_{\mathrm{meas}})` [mrad]. With a perfect
model the errors are measurement noise alone: their RMS is then the *noise
floor* :math:`\sqrt{\mathrm{mean}_k\,\mathrm{tr}\,\Sigma_k}`, which the report
shows next to the measured RMS: :math:`\sqrt{\sum_a \sigma_a^2}` with the isotropic
``tracker.sigma`` (3 axes), and with the scene's tracker error model and the robot's
repeatability (``scene.position_noise()``, position data) the covariance
:math:`\Sigma_k` of each row at its measured position, :math:`\sigma_r^2 +
2\sigma_t^2 + 3\rho^2` (:func:`~calib_oed.calibration.crossval.noise_floor`).

A calibration identified with joint compliance modelled keeps the
compliances in the sensor YAML (a URDF has no place for them); the
calibrated prediction then evaluates the calibrated URDF at the deflected
configuration :math:`q + c \circ \tau_g(q)` under the payload written there
(:mod:`calib_oed.model.compliance`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from calib_oed.calibration.crossval import noise_floor
from calib_oed.calibration.sensor_file import (
    read_sensor_compliance,
    read_sensor_gains,
    read_sensor_yaml,
)
from calib_oed.exceptions import ExportError, MeasurementFileError, ParameterError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.parameters import ParameterSpace
from calib_oed.model.robot import load_robot
from calib_oed.scene.records import Scene

MM_PER_M = 1e3
MRAD_PER_RAD = 1e3


@dataclass(frozen=True)
class ErrorStatistics:
    """Per-row error statistics of one model on the validation set.

    Attributes:
        model: ``"nominal"`` or ``"calibrated"``.
        position_mm: :math:`\\|r_k\\|` per row [mm], (n,).
        rotation_mrad: Rotation error per row [mrad], (n,), or None for position data.
    """

    model: str
    position_mm: np.ndarray
    rotation_mrad: np.ndarray | None = None

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.position_mm**2)))

    def to_dict(self) -> dict:
        p = self.position_mm
        out = {"model": self.model, "mean_mm": float(p.mean()), "std_mm": float(p.std(ddof=1)) if p.size > 1
               else 0.0, "rms_mm": self.rms_mm, "max_mm": float(p.max()), "max_row": int(p.argmax())}
        if self.rotation_mrad is not None:
            r = self.rotation_mrad
            out.update(rotation_rms_mrad=float(np.sqrt(np.mean(r**2))), rotation_max_mrad=float(r.max()))
        return out


@dataclass(frozen=True)
class ValidationResult:
    """Nominal and calibrated models against a validation measurement set.

    Attributes:
        nominal: Errors of the scene's nominal model.
        calibrated: Errors of the calibrated files.
        noise_floor_mm: RMS position error a perfect model would show:
            :math:`\\sqrt{\\mathrm{mean}_k\\,\\mathrm{tr}\\,\\Sigma_k}` [mm] (module docstring).
        source: The measurement file.
        files: The calibrated URDF and sensor YAML used.
    """

    nominal: ErrorStatistics
    calibrated: ErrorStatistics
    noise_floor_mm: float
    source: str
    files: dict[str, str]

    @property
    def n(self) -> int:
        return int(self.calibrated.position_mm.size)

    def check(self) -> float:
        """RMS of the calibrated position errors over the noise floor (1 = noise only)."""
        return self.calibrated.rms_mm / self.noise_floor_mm

    def to_dict(self) -> dict:
        return {"source": self.source, "files": dict(self.files), "n": self.n,
                "noise_floor_mm": self.noise_floor_mm, "nominal": self.nominal.to_dict(),
                "calibrated": self.calibrated.to_dict(), "rms_over_noise_floor": self.check()}

    def summary(self) -> str:
        lines = [f"validation on {self.n} measurements of {self.source} "
                 f"(position error |measured - predicted| per measurement, mm):",
                 f"  {'model':12s} {'mean':>9s} {'std':>9s} {'RMS':>9s} {'max':>9s}"]
        for stats in (self.nominal, self.calibrated):
            d = stats.to_dict()
            lines.append(f"  {stats.model:12s} {d['mean_mm']:9.4f} {d['std_mm']:9.4f} "
                         f"{d['rms_mm']:9.4f} {d['max_mm']:9.4f}")
            if stats.rotation_mrad is not None:
                lines.append(f"  {'':12s} rotation RMS {d['rotation_rms_mrad']:.4f} mrad, "
                             f"max {d['rotation_max_mrad']:.4f} mrad")
        lines.append(f"  noise floor (a perfect model): RMS {self.noise_floor_mm:.4f} mm; calibrated "
                     f"RMS / noise floor = {self.check():.2f}")
        return "\n".join(lines)


def find_calibration_files(path: str | os.PathLike, robot_name: str) -> dict[str, Path]:
    """The calibrated URDF and sensor YAML of ``calib-oed identify -o DIR``.

    ``path`` is that folder (``<robot>_calibrated.urdf`` and ``<robot>_sensor.yaml``,
    or the only ``*.urdf`` and ``*_sensor.yaml`` in it) or the URDF itself, with
    the sensor YAML next to it.

    Raises:
        ExportError: the files are not there (the message lists what was found).
    """
    path = Path(path)
    if not path.exists():
        raise ExportError(f"calibration {path} does not exist; give the folder "
                          "`calib-oed identify -o DIR` wrote, or its calibrated URDF")
    folder = path if path.is_dir() else path.parent

    def pick(explicit: Path, pattern: str, what: str) -> Path:
        if explicit.is_file():
            return explicit
        found = sorted(folder.glob(pattern))
        if len(found) == 1:
            return found[0]
        raise ExportError(f"no unique {what} in {folder} (looked for {explicit.name} or {pattern}; "
                          f"found {[f.name for f in found] or 'none'}); give the folder "
                          "`calib-oed identify -o DIR` wrote")

    urdf = path if path.is_file() else pick(folder / f"{robot_name}_calibrated.urdf", "*.urdf",
                                            "calibrated URDF")
    sensor = pick(folder / f"{robot_name}_sensor.yaml", "*_sensor.yaml", "sensor YAML")
    return {"urdf": urdf, "sensor": sensor}


def _errors(space: ParameterSpace, mset: MeasurementSet, blocks, model: str, p=None) -> ErrorStatistics:
    position = np.empty(mset.n)
    rotation = None if mset.rotations is None else np.empty(mset.n)
    for j, block in zip(mset.reflectors, blocks, strict=True):
        rows = np.flatnonzero(mset.reflector == j)
        state = evaluate_setup(space, p, block.q, regressor=False, jacobian=False)
        predicted = block.model.compute_values(state)
        position[rows] = np.linalg.norm(block.values[:, :3] - predicted[:, :3], axis=1) * MM_PER_M
        if rotation is not None:
            rotation[rows] = [np.linalg.norm(pin.log3(pin.exp3(a).T @ pin.exp3(b))) * MRAD_PER_RAD
                              for a, b in zip(predicted[:, 3:], block.values[:, 3:], strict=True)]
    return ErrorStatistics(model, position, rotation)


def validate_calibration(scene: Scene, calibration: str | os.PathLike, mset: MeasurementSet) -> ValidationResult:
    """Errors of the nominal model and of the exported calibration on ``mset``.

    Args:
        scene: The cell the data were measured in (robot, tracker, reflectors, noise).
        calibration: The folder ``calib-oed identify -o DIR`` wrote, or its URDF.
        mset: Validation measurements (not used for the identification).

    Raises:
        ExportError: calibration files missing or unreadable.
        MeasurementFileError: the data's reflectors are not the calibration's.
    """
    robot = scene.robot
    files = find_calibration_files(calibration, robot.name)
    calibrated = load_robot(str(files["urdf"]), tool_frame=robot.tool_frame,
                            lock_joints=robot.locked_joints or None, package_dirs=robot.package_dirs)
    if tuple(calibrated.joint_names) != tuple(robot.joint_names):
        raise ExportError(f"{files['urdf']}: joints {list(calibrated.joint_names)} are not the scene "
                          f"robot's {list(robot.joint_names)}")
    tracker, offsets = read_sensor_yaml(files["sensor"])
    compliance = read_sensor_compliance(files["sensor"], robot.joint_names)
    gains = read_sensor_gains(files["sensor"], robot.joint_names)
    if len(offsets) != len(scene.reflectors) or max(mset.reflectors) >= len(offsets):
        raise MeasurementFileError(mset.source, [(None, f"the data use reflectors {list(mset.reflectors)}, "
                                                        f"the calibration has {len(offsets)}")],
                                   kind="measurement file")
    blocks = mset.blocks(error_model=scene.error_model())
    nominal_space = ParameterSpace(robot, scene.tracker.placement(),
                                   np.array([r.offset for r in scene.reflectors]))
    calibrated_space = ParameterSpace(calibrated, tracker, offsets,
                                      compliance=None if compliance is None else compliance[0],
                                      joint_gains=None if gains is None else gains[0])
    p_calibrated = None
    if compliance is not None or gains is not None:  # deflection and gains on top of the URDF
        p_calibrated = calibrated_space.zeros()
        if compliance is not None:
            p_calibrated[calibrated_space.compliance_slice] = compliance[1]
        if gains is not None:
            p_calibrated[calibrated_space.gain_slice] = gains[1]
    floor = noise_floor(mset, blocks)
    return ValidationResult(
        nominal=_errors(nominal_space, mset, blocks, "nominal"),
        calibrated=_errors(calibrated_space, mset, blocks, "calibrated", p_calibrated),
        noise_floor_mm=floor * MM_PER_M,
        source=mset.source,
        files={k: str(v) for k, v in files.items()},
    )


#: The default verdict threshold is this many times the identified residual scale times the noise floor.
DEFAULT_RMS_FACTOR = 2.0


@dataclass(frozen=True)
class Verdict:
    """Pass or fail of a validation: calibrated RMS against a threshold [mm].

    Attributes:
        passed: ``rms_mm <= threshold_mm``.
        basis: Where the threshold comes from (``--max-rms``, or the identified scale).
    """

    passed: bool
    rms_mm: float
    threshold_mm: float
    basis: str

    def line(self) -> str:
        word = "PASS" if self.passed else "FAIL"
        return (f"verdict: {word}: calibrated RMS {self.rms_mm:.4f} mm "
                f"{'<=' if self.passed else '>'} {self.threshold_mm:.4f} mm ({self.basis})")

    def to_dict(self) -> dict:
        return {"passed": self.passed, "rms_mm": self.rms_mm, "threshold_mm": self.threshold_mm,
                "basis": self.basis}


def identified_sigma0(files: dict) -> float | None:
    """sigma0 of the identification that wrote the calibration (``identification.json`` beside
    the URDF, key ``fit.sigma0``, else ``sigma0``), or None when not recorded."""
    path = Path(files["urdf"]).parent / "identification.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    value = (data.get("fit") or {}).get("sigma0", data.get("sigma0"))
    return float(value) if isinstance(value, (int, float)) and np.isfinite(value) else None


def judge(result: ValidationResult, max_rms_mm: float | None = None, sigma0: float | None = None,
          factor: float = DEFAULT_RMS_FACTOR) -> Verdict:
    """The verdict: ``max_rms_mm`` if given, else ``factor`` x max(sigma0, 1) x noise floor.

    The calibrated RMS on new poses of a calibration whose residual scale was
    :math:`\\hat\\sigma_0` is about :math:`\\hat\\sigma_0` times the noise floor (plus the
    estimation error, a few per cent for a well-conditioned design), so twice that
    fails only a calibration that does not carry over to the validation poses.

    Raises:
        ParameterError: a non-positive ``max_rms_mm``.
    """
    if max_rms_mm is not None:
        if not (np.isfinite(max_rms_mm) and max_rms_mm > 0):
            raise ParameterError(f"--max-rms must be a positive length in mm, got {max_rms_mm:g}")
        threshold, basis = float(max_rms_mm), "--max-rms"
    else:
        s = 1.0 if sigma0 is None else max(float(sigma0), 1.0)
        threshold = factor * s * result.noise_floor_mm
        basis = (f"{factor:g} x max(sigma0, 1) x noise floor, sigma0 = {sigma0:.3f} from the "
                 "identification" if sigma0 is not None else
                 f"{factor:g} x noise floor: no identified sigma0 found beside the URDF")
    rms = result.calibrated.rms_mm
    return Verdict(bool(rms <= threshold), rms, threshold, basis)
