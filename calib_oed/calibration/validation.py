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

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from calib_oed.calibration.crossval import noise_floor
from calib_oed.calibration.joint_prior_choice import fitted_model_error
from calib_oed.calibration.pose_prediction import (
    RowPrediction,
    predict_rows,
    read_record,
    region_threshold_of,
)
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.sensor_file import (
    read_sensor_compliance,
    read_sensor_gains,
    read_sensor_yaml,
    sensor_robot,
)
from calib_oed.calibration.trust import compensate
from calib_oed.calibration.verdict import read_identification
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
        predicted: The predicted error per row (:mod:`calib_oed.calibration.pose_prediction`),
            or None when ``identification.json`` does not record what it needs.
    """

    nominal: ErrorStatistics
    calibrated: ErrorStatistics
    noise_floor_mm: float
    source: str
    files: dict[str, str]
    predicted: RowPrediction | None = None

    @property
    def n(self) -> int:
        return int(self.calibrated.position_mm.size)

    def check(self) -> float:
        """RMS of the calibrated position errors over the noise floor (1 = noise only)."""
        return self.calibrated.rms_mm / self.noise_floor_mm

    def to_dict(self) -> dict:
        return {"source": self.source, "files": dict(self.files), "n": self.n,
                "noise_floor_mm": self.noise_floor_mm, "nominal": self.nominal.to_dict(),
                "calibrated": self.calibrated.to_dict(), "rms_over_noise_floor": self.check(),
                "inside_95_percent_regions": None if self.predicted is None
                else int(self.predicted.inside.sum()),
                "predicted_rms_mm": None if self.predicted is None else self.predicted.total_rms_mm}

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
        if self.predicted is not None:
            lines.append("  " + self.predicted.line())
        return "\n".join(lines)


def find_calibration_files(path: str | os.PathLike, robot_name: str) -> dict[str, Path]:
    """The calibrated URDF and sensor YAML of ``calib-oed identify -o DIR``.

    ``path`` is that folder (``<robot>_calibrated.urdf`` and ``<robot>_sensor.yaml``,
    or the only ``*.urdf`` and ``*_sensor.yaml`` in it) or the URDF itself, with
    the sensor YAML next to it.

    Raises:
        ExportError: the files are not there (the message lists what was found), or they are
            another robot's (the sensor file's ``robot``).
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
    identified = sensor_robot(sensor)
    if identified is not None and identified != robot_name:
        raise ExportError(f"{path}: a calibration of robot {identified!r}, not of this scene's robot "
                          f"{robot_name!r}; give the folder `calib-oed identify -o DIR` wrote for this scene")
    return {"urdf": urdf, "sensor": sensor}


def _errors(space: ParameterSpace, mset: MeasurementSet, blocks, model: str, p=None,
            offset=None) -> tuple[ErrorStatistics, np.ndarray]:
    """The statistics and the position residual per row, (n, 3) [m]."""
    residual = np.empty((mset.n, 3))
    rotation = None if mset.rotations is None else np.empty(mset.n)
    for j, block in zip(mset.reflectors, blocks, strict=True):
        rows = np.flatnonzero(mset.reflector == j)
        state = evaluate_setup(space, p, block.q, regressor=False, jacobian=False)
        predicted = np.array(block.model.compute_values(state))
        if offset is not None:  # the fitted model error's mean, tracker frame
            predicted[:, :3] += offset(block.q)
        residual[rows] = block.values[:, :3] - predicted[:, :3]
        if rotation is not None:
            rotation[rows] = [np.linalg.norm(pin.log3(pin.exp3(a).T @ pin.exp3(b))) * MRAD_PER_RAD
                              for a, b in zip(predicted[:, 3:], block.values[:, 3:], strict=True)]
    return ErrorStatistics(model, np.linalg.norm(residual, axis=1) * MM_PER_M, rotation), residual


def _compensation(files: dict, space: ParameterSpace):
    """:math:`\\mu(q)` of the identification beside the URDF (:mod:`calib_oed.calibration.trust`);
    ``space`` the scene's (for the model error's pose scale)."""
    data = read_identification(files)
    try:
        prior = fitted_model_error(data["model_error"]["fitted"], space)
        comp = data["compensation"]
        configs = np.array(comp["configurations_rad"], float)
        weights = np.array(comp["weights_per_m"], float)
    except (TypeError, KeyError, ValueError, ParameterError) as exc:
        raise ExportError(f"--compensate needs the model error and its compensation data in "
                          f"{Path(files['urdf']).parent / 'identification.json'} (written by "
                          f"`calib-oed identify -o` of this version): {exc}") from exc
    return lambda q: compensate(prior, configs, weights, q)


def validate_calibration(scene: Scene, calibration: str | os.PathLike, mset: MeasurementSet,
                         compensated: bool = False) -> ValidationResult:
    """Errors of the nominal model and of the exported calibration on ``mset``.

    Args:
        scene: The cell the data were measured in (robot, tracker, reflectors, noise).
        calibration: The folder ``calib-oed identify -o DIR`` wrote, or its URDF.
        mset: Validation measurements (not used for the identification).
        compensated: Add the fitted model error's mean to the calibrated predictions
            (from ``identification.json`` beside the URDF).

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
    scene_space = CalibrationProblem.from_scene(scene).space  # its payload, for the model error's pose scale
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
    calibrated_errors, residual = _errors(calibrated_space, mset, blocks, "calibrated", p_calibrated,
                                          _compensation(files, scene_space) if compensated else None)
    ident = read_identification(files)
    record = read_record(ident, scene_space)
    return ValidationResult(
        nominal=_errors(nominal_space, mset, blocks, "nominal")[0],
        calibrated=calibrated_errors,
        noise_floor_mm=floor * MM_PER_M,
        source=mset.source,
        files={k: str(v) for k, v in files.items()},
        predicted=None if record is None else predict_rows(
            record, calibrated_space, p_calibrated, mset, blocks, residual, compensated,
            region_threshold_of(ident, compensated)),
    )
