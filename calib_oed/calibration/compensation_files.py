r"""The calibration ``compensate`` uses: the files ``calib-oed identify -o DIR`` wrote.

* the calibrated URDF (the calibrated robot, loaded with the scene robot's tool frame,
  locked joints and package folders);
* ``identification.json`` beside it: the estimate ``p`` (by name), the free parameters
  and their covariance :math:`C_p` (``covariance``, a priori), and ``noise_factor``
  :math:`\hat\sigma_0^2`. The predicted residual uses :math:`C_p\max(1, \hat\sigma_0^2)`:
  a fit whose residuals are larger than the noise model says (model error) scales the
  uncertainty up, never down. Without the file there is no prediction (and the report
  says so);
* the sensor YAML: a calibration with joint compliance or joint gains is refused (their
  kinematics are not a URDF's; ``docs/compensate.md``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from calib_oed.calibration.compensation import CalibrationUncertainty
from calib_oed.calibration.sensor_file import read_sensor_compliance, read_sensor_gains
from calib_oed.calibration.validation import find_calibration_files
from calib_oed.exceptions import CompensationError, UnknownParameterError
from calib_oed.model.parameters import ParameterSpace
from calib_oed.model.robot import Robot, load_robot


def load_calibration(space: ParameterSpace, folder: str | os.PathLike) -> tuple[Robot, CalibrationUncertainty | None, dict]:
    """(calibrated robot, its uncertainty or None, the files used) of ``identify -o`` output.

    Args:
        space: The scene's parameter space (nominal robot, tracker, reflectors).
        folder: The folder ``calib-oed identify -o DIR`` wrote, or its URDF.

    Raises:
        ExportError: files missing; CompensationError: another robot's calibration, joint
            compliance or gains, or an ``identification.json`` that does not fit the scene.
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
    path = Path(files["urdf"]).parent / "identification.json"
    out = {k: str(v) for k, v in files.items()}
    if not path.is_file():
        return calibrated, None, out
    out["identification"] = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        p = np.zeros(space.size)
        for name, value in data["p"].items():
            p[space.index(name)] = float(value)
        free = np.array([space.index(e["name"]) for e in data["free"]], dtype=int)
        cov = np.array(data["covariance"], dtype=float)
        factor = max(1.0, float(data.get("noise_factor") or 1.0))
    except UnknownParameterError as exc:
        raise CompensationError(f"{path}: not a calibration of this scene ({exc})") from exc
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CompensationError(f"{path}: cannot read the identification ({exc}); "
                                "give the folder `calib-oed identify -o DIR` wrote") from exc
    if cov.shape != (len(free), len(free)) or not np.all(np.isfinite(cov)):
        raise CompensationError(f"{path}: the covariance is not a finite {len(free)} x {len(free)} matrix")
    return calibrated, CalibrationUncertainty(space, p, free, cov * factor), out


__all__ = ["load_calibration"]
