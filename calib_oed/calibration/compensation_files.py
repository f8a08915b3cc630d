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
* the sensor YAML: the joint compliances (with the payload they were identified under) and
  the joint gains of a calibration that identified them. :func:`load_calibration` (a URDF or a
  parameter table: ``calib-oed table``) refuses them, their kinematics are not a URDF's;
  :func:`load_compensation` keeps them as a
  :class:`~calib_oed.model.deflected_kinematics.JointDeflection`, with the **payload the program
  runs with**: the scene's ``robot.compliance.payload`` if the scene has that block, else the one
  the compliances were identified under (:attr:`LoadedCalibration.payload` says which). The arm's
  own weight is the one of the identification.

**Is it this robot's calibration?** Every joint placement of the calibrated URDF must be
the nominal one times :math:`\exp_6(\delta_i)` with :math:`\delta_i` below
:data:`PLAUSIBLE_LENGTH` and :data:`PLAUSIBLE_ANGLE` (another robot's URDF with the same
joint names fails), and with ``identification.json`` the URDF must be
``space.perturbed_model(p)`` of its estimate to 1e-9 (the two files belong together).
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from calib_oed.calibration.compensation import CalibrationUncertainty, marginal_model_error
from calib_oed.calibration.joint_prior_choice import fitted_model_error
from calib_oed.calibration.sensor_file import read_sensor_compliance, read_sensor_gains
from calib_oed.calibration.validation import find_calibration_files
from calib_oed.exceptions import CompensationError, UnknownParameterError
from calib_oed.model.deflected_kinematics import JointDeflection
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


@dataclass(frozen=True, eq=False)
class LoadedCalibration:
    """A calibration as ``compensate`` uses it (:func:`load_compensation`).

    Attributes:
        robot: The calibrated robot (joint placements).
        uncertainty: For the predicted residual, or None without ``identification.json``.
        files: The files used, by role.
        deflection: Joint compliance (with the working payload) and gains, or None (rigid joints).
        payload: Where the payload of the deflection comes from (one line), or "" without compliance.
        space: The calibration's parameter space (the scene's, with the identified compliance and gains).
        joint_range: ``(lower, upper)`` (nq,) each [rad or m], the joint ranges the calibration was
            measured in (``training_joint_ranges`` of ``identification.json``), or None (not recorded).
    """

    robot: Robot
    uncertainty: CalibrationUncertainty | None
    files: dict
    deflection: JointDeflection | None
    payload: str
    space: ParameterSpace
    joint_range: tuple[np.ndarray, np.ndarray] | None = None


def load_calibration(space: ParameterSpace, folder: str | os.PathLike) -> tuple[Robot, CalibrationUncertainty | None, dict]:
    """(calibrated robot, its uncertainty or None, the files used) of ``identify -o`` output, for
    what a URDF holds (``calib-oed table``): a calibration with joint compliance or gains is refused.

    Args:
        space: The scene's parameter space (nominal robot, tracker, reflectors).
        folder: The folder ``calib-oed identify -o DIR`` wrote, or its URDF.

    Raises:
        ExportError: files missing, or another robot's (the sensor file's ``robot``);
            CompensationError: another robot's calibration (its joint placements), joint
            compliance or gains, or an ``identification.json`` that does not fit the scene;
            InputFileError: an ``identification.json`` that is not a regular file or is larger
            than :data:`~calib_oed.scene.yaml_file.MAX_TEXT_BYTES` (the bound ``validate`` reads it with).
    """
    files = find_calibration_files(folder, space.robot.name)
    for read, what in ((read_sensor_compliance, "joint compliance"), (read_sensor_gains, "joint gains")):
        if read(files["sensor"], space.robot.joint_names) is not None:
            raise CompensationError(f"{files['sensor']}: the calibration has {what}, which a URDF or a parameter "
                                    "table cannot hold (`calib-oed compensate` models it): identify without it")
    return _read(space, files)[:3]


def load_compensation(space: ParameterSpace, folder: str | os.PathLike,
                      payload_mass: float | None = None) -> LoadedCalibration:
    """The calibration ``compensate`` uses: the robot, its uncertainty and the joint deflection.

    Args:
        space: The scene's parameter space (nominal robot, tracker, reflectors; its compliance
            block's payload, if any, is the working payload).
        folder: The folder ``calib-oed identify -o DIR`` wrote, or its URDF.
        payload_mass: The payload mass the program runs with [kg] (overrides the scene's; the
            centre of mass stays as below); None: the scene's ``robot.compliance`` payload, else
            the one the calibration was identified under.

    Raises:
        As :func:`load_calibration`, without the refusal of compliance and gains.
    """
    robot = space.robot
    files = find_calibration_files(folder, robot.name)
    found = read_sensor_compliance(files["sensor"], robot.joint_names)
    gains = read_sensor_gains(files["sensor"], robot.joint_names)
    compliance, source = None, ""
    if found is not None:
        identified = found[0]
        if space.compliance is not None:
            load, source = space.compliance, "the scene's robot.compliance.payload"
        else:
            load, source = identified, (f"the payload the calibration was identified under ({files['sensor']}); "
                                        "the scene declares none")
        if payload_mass is not None:
            load = dataclasses.replace(load, payload_mass=payload_mass)
            source = f"--payload-kg, the centre of mass from {source}"
        compliance = dataclasses.replace(identified, payload_mass=load.payload_mass, payload_com=load.payload_com)
    own = ParameterSpace(robot, space.tracker_placement0, space.reflector_offsets0, compliance=compliance,
                         joint_gains=None if gains is None else gains[0])
    calibrated, uncertainty, out, joint_range = _read(own, files)
    sensor = own.zeros()                    # the sensor file's values (no identification.json: these)
    if found is not None:
        sensor[own.compliance_slice] = found[1]
    if gains is not None:
        sensor[own.gain_slice] = gains[1]
    joint = slice(own.compliance_slice.start, own.size)
    if uncertainty is not None and not np.allclose(uncertainty.p[joint], sensor[joint], rtol=1e-9, atol=0):
        raise CompensationError(f"{out['identification']}: its compliances or gains are not those of "
                                f"{files['sensor']}: the two files are not from one identification")
    deflection = JointDeflection.from_space(own, sensor if uncertainty is None else uncertainty.p)
    text = f"payload {deflection.payload}: {source}" if found is not None else ""
    return LoadedCalibration(calibrated, uncertainty, out, deflection, text, own, joint_range)


def _read(space: ParameterSpace, files: dict) -> tuple[Robot, CalibrationUncertainty | None, dict, tuple | None]:
    """The calibrated robot and its uncertainty of ``files``, parameters read into ``space``, the
    files used and the training joint ranges (None if not recorded)."""
    robot = space.robot
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
        return calibrated, None, out, None
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
        prior = None if fitted is None else fitted_model_error(fitted, space, str(path))
        factor = 1.0 if prior is not None else max(1.0, float(data.get("noise_factor") or 1.0))
        ranges = data.get("training_joint_ranges")
        joint_range = None if ranges is None else tuple(
            np.array([float(ranges[name][k]) for name in robot.joint_names]) for k in (0, 1))
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
    return calibrated, CalibrationUncertainty(space, p, free, cov * factor, extra), out, joint_range


__all__ = ["LoadedCalibration", "load_calibration", "load_compensation"]
