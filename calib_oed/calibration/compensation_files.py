r"""The calibration ``compensate`` uses: the files ``calib-oed identify -o DIR`` wrote.

* the calibrated URDF (the calibrated robot, loaded with the scene robot's tool frame,
  locked joints and package folders);
* ``identification.json`` beside it: the estimate ``p`` (by name), the free parameters
  and their covariance :math:`C_p` (``covariance``, a priori), the fitted model error
  (``model_error.fitted``, a Gaussian process over the joints) and ``noise_factor``
  :math:`\hat\sigma_0^2`. The predicted residual uses :math:`C_p` plus the model error's
  variance :math:`k(q,q)I_3` at the target
  (:func:`~calib_oed.calibration.compensation.marginal_model_error`); a file without a
  fitted model error (older ``identify``) uses :math:`C_p\max(1, \hat\sigma_0^2)`: a fit
  whose residuals are larger than the noise model says scales the uncertainty up, never
  down. Without the file there is no prediction (and the report says so);
* the sensor YAML: a calibration with joint compliance or joint gains is refused (their
  kinematics are not a URDF's; ``docs/compensate.md``).

**Is it this robot's calibration?** Every joint placement of the calibrated URDF must be
the nominal one times :math:`\exp_6(\delta_i)` with :math:`\delta_i` below
:data:`PLAUSIBLE_LENGTH` and :data:`PLAUSIBLE_ANGLE` (another robot's URDF with the same
joint names fails), and with ``identification.json`` the URDF must be
``space.perturbed_model(p)`` of its estimate to 1e-9 (the two files belong together).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pinocchio as pin

from calib_oed.calibration.compensation import CalibrationUncertainty, marginal_model_error
from calib_oed.calibration.sensor_file import read_sensor_compliance, read_sensor_gains
from calib_oed.calibration.validation import find_calibration_files
from calib_oed.exceptions import CompensationError, UnknownParameterError
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.model.parameters import ParameterSpace
from calib_oed.model.robot import Robot, load_robot
from calib_oed.scene.yaml_file import MAX_TEXT_BYTES, read_text_file

#: Largest joint placement change [m] and [rad] a calibration of this robot can hold.
PLAUSIBLE_LENGTH = 0.05
PLAUSIBLE_ANGLE = 0.05


def _placement_deltas(nominal: pin.Model, calibrated: pin.Model) -> np.ndarray:
    r""":math:`\log_6(M_i^{-1} M'_i)` of every joint, (n, 6)."""
    return np.array([pin.log6(nominal.jointPlacements[i].actInv(calibrated.jointPlacements[i])).vector
                     for i in range(1, nominal.njoints)])


def load_calibration(space: ParameterSpace, folder: str | os.PathLike) -> tuple[Robot, CalibrationUncertainty | None, dict]:
    """(calibrated robot, its uncertainty or None, the files used) of ``identify -o`` output.

    Args:
        space: The scene's parameter space (nominal robot, tracker, reflectors).
        folder: The folder ``calib-oed identify -o DIR`` wrote, or its URDF.

    Raises:
        ExportError: files missing; CompensationError: another robot's calibration, joint
            compliance or gains, or an ``identification.json`` that does not fit the scene;
            InputFileError: an ``identification.json`` that is not a regular file or is larger
            than :data:`~calib_oed.scene.yaml_file.MAX_TEXT_BYTES` (the bound ``validate`` reads it with).
    """
    robot = space.robot
    files = find_calibration_files(folder, robot.name)
    for read, what in ((read_sensor_compliance, "joint compliance"), (read_sensor_gains, "joint gains")):
        if read(files["sensor"], robot.joint_names) is not None:
            raise CompensationError(f"{files['sensor']}: the calibration has {what}, which compensate does "
                                    "not model (the kinematics are not a URDF's): identify without it")
    calibrated = load_robot(str(files["urdf"]), tool_frame=robot.tool_frame,
                            lock_joints=robot.locked_joints or None, package_dirs=robot.package_dirs)
    if tuple(calibrated.joint_names) != tuple(robot.joint_names):
        raise CompensationError(f"{files['urdf']}: joints {list(calibrated.joint_names)} are not the scene "
                                f"robot's {list(robot.joint_names)}")
    deltas = _placement_deltas(robot.model, calibrated.model)
    if np.abs(deltas[:, :3]).max() > PLAUSIBLE_LENGTH or np.abs(deltas[:, 3:]).max() > PLAUSIBLE_ANGLE:
        raise CompensationError(
            f"{files['urdf']}: its joint placements differ from the scene robot {robot.name!r}'s by up to "
            f"{1e3 * np.abs(deltas[:, :3]).max():.1f} mm and {1e3 * np.abs(deltas[:, 3:]).max():.1f} mrad: "
            "not a calibration of this robot (give the scene the calibration was identified in)")
    path = Path(files["urdf"]).parent / "identification.json"
    out = {k: str(v) for k, v in files.items()}
    if not path.exists():
        return calibrated, None, out
    out["identification"] = str(path)
    text = read_text_file(path, "identification", MAX_TEXT_BYTES)     # bounded; a folder or pipe refused
    try:
        data = json.loads(text)
        p = np.zeros(space.size)
        for name, value in data["p"].items():
            p[space.index(name)] = float(value)
        free = np.array([space.index(e["name"]) for e in data["free"]], dtype=int)
        cov = np.array(data["covariance"], dtype=float)
        fitted = (data.get("model_error") or {}).get("fitted")
        prior = None if fitted is None else DiscrepancyPrior.from_dict(fitted, space.robot.nq, str(path))
        factor = 1.0 if prior is not None else max(1.0, float(data.get("noise_factor") or 1.0))
    except UnknownParameterError as exc:
        raise CompensationError(f"{path}: not a calibration of this scene ({exc})") from exc
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise CompensationError(f"{path}: cannot read the identification ({exc}); "
                                "give the folder `calib-oed identify -o DIR` wrote") from exc
    if cov.shape != (len(free), len(free)) or not np.all(np.isfinite(cov)):
        raise CompensationError(f"{path}: the covariance is not a finite {len(free)} x {len(free)} matrix")
    mismatch = np.abs(_placement_deltas(space.perturbed_model(p), calibrated.model)).max()
    if mismatch > 1e-9:
        raise CompensationError(f"{path}: its estimate does not give {files['urdf']} (joint placements differ "
                                f"by {mismatch:.3g} m or rad): the two files are not from one identification")
    extra = None if prior is None else marginal_model_error(prior)
    return calibrated, CalibrationUncertainty(space, p, free, cov * factor, extra), out


__all__ = ["load_calibration"]
