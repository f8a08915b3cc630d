"""The calibration workflow in a few calls, as the ``calib-oed`` command runs it.

Each function assembles library pieces for one step a calibration engineer
takes: a feasible design for a scene, simulated tracker data for it, the
identification of measured data, and the export of the result. Nothing here
has mathematics of its own.
"""

from __future__ import annotations

import os
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin
import yaml

from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.realistic import RealisticTruth, sample_truth
from calib_oed.calibration.realistic_defaults import RealisticSettings
from calib_oed.calibration.realistic_measure import (
    RealisticMeasurements,
    blocks_to_measurement_set,
    measure,
    read_realistic_truth,
)
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.exceptions import DesignError, ExportError, InputFileError, SceneError
from calib_oed.feasibility.constraints import FeasibilityModel
from calib_oed.feasibility.pairs import PairReport, feasibility_from_scene
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.io.atomic import atomic_write_text
from calib_oed.io.measurement_reader import read_measurements
from calib_oed.io.measurement_writer import write_measurements
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.robot import load_robot
from calib_oed.scene.records import Scene
from calib_oed.scene.yaml_file import load_yaml_file

if TYPE_CHECKING:
    from calib_oed.calibration.identification import IdentificationResult


class Setup:
    """A scene with its calibration problem and (built on first use) its feasibility model.

    Args:
        scene: The scene.
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        self.problem = CalibrationProblem.from_scene(scene)

    @cached_property
    def _feasibility(self) -> tuple[FeasibilityModel, PairReport]:
        return feasibility_from_scene(self.scene)  # the pruning pass takes ~1 s: only when needed

    @property
    def feasibility(self) -> FeasibilityModel:
        """The scene's constraints (capsules, cell, beam, incidence, joint limits)."""
        return self._feasibility[0]

    @property
    def pairs(self) -> PairReport:
        """Which capsule pairs are checked, and why the others are not."""
        return self._feasibility[1]

    @property
    def reflector_names(self) -> list[str]:
        return [r.name for r in self.scene.reflectors]


def setup(scene: Scene | str | os.PathLike) -> Setup:
    """Assemble problem and feasibility model of a scene: a loaded :class:`Scene`, a
    shipped scene name (``"fms_kr16"``) or a scene file path.

    Raises:
        UnknownSceneError: a name that is no shipped scene (the message lists them).
        SceneError: a missing or invalid scene file.
    """
    if isinstance(scene, (str, os.PathLike)):
        from calib_oed.scene.reader import load_scene

        scene = load_scene(scene)
    elif not isinstance(scene, Scene):
        raise SceneError(f"setup() takes a Scene, a shipped scene name or a scene file path, "
                         f"not {type(scene).__name__}")
    return Setup(scene)


def heuristic_design(s: Setup, n: int, seed: int = 0) -> np.ndarray:
    """The paper's heuristic design: n poses uniform in the joint ranges, kept if feasible.

    Raises:
        DesignError: ``n`` is not a whole number >= 1, or ``seed`` neither an integer >= 0
            nor a ``numpy.random.Generator``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise DesignError("n", n, "a whole number of poses >= 1")
    if not isinstance(seed, np.random.Generator) and (
            isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise DesignError("seed", seed, "an integer >= 0 or a numpy Generator")
    return sample_feasible(s.feasibility, int(n), seed)


def simulated_measurements(s: Setup, q: np.ndarray, truth_seed: int) -> tuple[MeasurementSet, np.ndarray]:
    """Tracker data of a random true robot (free parameters 0.5 mm / 0.5 mrad) at design ``q``.

    Returns the measurements and the true parameter vector [SI].
    """
    problem = s.problem
    rng = np.random.default_rng(truth_seed)
    p_true = draw_true_parameters(problem.space, problem.identifiability.free_indices, rng)
    blocks = simulate_observations(problem.space, problem.models, q, p_true, rng)
    return blocks_to_measurement_set(problem.robot, blocks), p_true


def realistic_measurements(s: Setup, q: np.ndarray, truth_seed: int,
                           settings: RealisticSettings | None = None
                           ) -> tuple[MeasurementSet, RealisticTruth, RealisticMeasurements]:
    """Tracker data of a realistic true robot (:mod:`calib_oed.calibration.realistic`) at design ``q``.

    One generator from ``truth_seed`` draws the truth, then the noise and gross errors.
    Returns the measurements, the truth and the simulation's record (exact readings, gross rows).
    """
    rng = np.random.default_rng(truth_seed)
    truth = sample_truth(s, rng, settings)
    meas = measure(truth, s.problem.models, q, rng)
    return meas.measurement_set(s.problem.robot), truth, meas


def write_truth(path: str | os.PathLike, s: Setup, p_true: np.ndarray, truth_seed: int) -> Path:
    """The true parameters of a simulation, by name [SI], as YAML (atomic)."""
    data = {
        "scene": s.scene.name,
        "robot": s.problem.robot.name,
        "truth_seed": int(truth_seed),
        "units": "SI (m, rad)",
        "parameters": {n: float(v) for n, v in zip(s.problem.space.names, p_true, strict=True)},
    }
    return atomic_write_text(path, "# calib_oed simulated truth\n" + yaml.safe_dump(data, sort_keys=False))


def read_truth(path: str | os.PathLike, s: Setup) -> np.ndarray | RealisticTruth:
    """Read :func:`write_truth` output back into a parameter vector; a realistic truth
    (``simulate --realistic``) into its :class:`RealisticTruth`.

    Raises:
        InputFileError: a missing or unreadable file, not a truth file, the truth of
            another scene or robot, or parameters that are not the scene's (names listed).
    """
    try:
        data = load_yaml_file(path, "truth file")
    except yaml.YAMLError as exc:
        raise InputFileError(path, f"not a truth file: YAML error ({getattr(exc, 'problem', exc)})") from exc
    if isinstance(data, dict):
        for key, mine in (("scene", s.scene.name), ("robot", s.problem.robot.name)):
            if key in data and str(data[key]) != mine:
                raise InputFileError(path, f"the truth of {key} {data[key]!r}, not of this {key} {mine!r}; "
                                     "give the truth file simulate wrote for this scene")
        if data.get("kind") == "realistic":
            return read_realistic_truth(data, s, path)
    params = data.get("parameters") if isinstance(data, dict) else None
    if not isinstance(params, dict):
        raise InputFileError(path, "not a truth file (expected 'parameters:' by name, as "
                             "`calib-oed simulate --truth` writes)")
    space = s.problem.space
    unknown = [n for n in params if n not in space.names]
    missing = [n for n in space.names if n not in params]
    if unknown or missing:
        raise InputFileError(path, "the truth's parameters are not the scene's: "
                             + (f"unknown {', '.join(map(str, unknown[:5]))}; " if unknown else "")
                             + (f"missing {', '.join(missing[:5])}; " if missing else "")
                             + f"the scene has {space.size} parameters ({space.names[0]} .. {space.names[-1]})")
    try:
        p = np.array([float(params[n]) for n in space.names])
    except (TypeError, ValueError) as exc:
        raise InputFileError(path, f"a truth value is not a number ({exc})") from exc
    if not np.all(np.isfinite(p)):
        raise InputFileError(path, "a truth value is NaN or infinite")
    return p


def read_scene_measurements(s: Setup, path: str | os.PathLike, **units) -> MeasurementSet:
    """A measurement file of this scene's robot and reflectors, with at least
    :data:`MIN_MEASUREMENTS` rows (the tracker registration needs three points).

    Raises:
        MeasurementFileError: the file has problems, or fewer rows than that.
    """
    mset = read_measurements(path, s.problem.robot, s.reflector_names,
                             controller=s.scene.controller, **units)
    if len(mset.q) < MIN_MEASUREMENTS:
        from calib_oed.exceptions import MeasurementFileError

        raise MeasurementFileError(str(path), [(None, (
            f"{len(mset.q)} measurement(s): registering the tracker needs at least "
            f"{MIN_MEASUREMENTS} measured points, a calibration tens of poses"))])
    return mset


#: Fewest rows of a measurement file: three points fix the tracker pose.
MIN_MEASUREMENTS = 3


def identify_measurements(s: Setup, mset: MeasurementSet) -> IdentificationResult:
    """Identify the scene's free parameters from measured data."""
    blocks = mset.blocks(error_model=s.scene.error_model())
    from calib_oed.calibration.identification import identify  # scipy.optimize: not for designs

    return identify(s.problem.space, blocks, s.problem.identifiability)


def export_result(s: Setup, result: IdentificationResult, folder: str | os.PathLike) -> dict[str, Path]:
    """Calibrated URDF and sensor YAML into ``folder`` (created if missing)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ExportError(f"cannot create output folder {folder}: {exc}") from exc
    from calib_oed.calibration.export import export_calibration  # yourdfpy, trimesh: the same

    return export_calibration(s.problem.space, result.p, folder, stem=s.problem.robot.name)


def round_trip_error(s: Setup, p: np.ndarray, urdf_path: str | os.PathLike, n: int = 20, seed: int = 0) -> float:
    """Largest tool-frame position difference [m] between the exported URDF and the
    identified model, at ``n`` random configurations and the working configurations."""
    robot = s.problem.robot
    loaded = load_robot(urdf_path, tool_frame=robot.tool_frame, lock_joints=robot.locked_joints or None,
                        package_dirs=robot.package_dirs)
    ident = s.problem.space.perturbed_model(p)
    q = np.vstack([robot.random_configurations(n, seed), s.problem.kpi.configurations])
    d1, d2 = loaded.model.createData(), ident.createData()
    worst = 0.0
    for qk in q:
        pin.framesForwardKinematics(loaded.model, d1, qk)
        pin.framesForwardKinematics(ident, d2, qk)
        a, b = d1.oMf[loaded.tool_frame_id], d2.oMf[robot.tool_frame_id]
        worst = max(worst, float(np.linalg.norm(a.translation - b.translation)))
        worst = max(worst, float(np.linalg.norm(pin.log3(a.rotation.T @ b.rotation))) * 0.1)
    return worst


def tcp_errors(s: Setup, p_true: np.ndarray | RealisticTruth, p_est: np.ndarray | None,
               frame: str = "tracker") -> np.ndarray:
    """KPI error of the model ``p_est`` (None: nominal) against the truth (true parameters
    or a realistic truth), (t, 3) [m], in ``frame``: by default the tracker frame, each model
    with its own tracker placement, the frame of ``identify``'s predicted TCP accuracy
    (:mod:`calib_oed.calibration.prediction`). In the world frame the error also holds the
    rigid move between the model's base frame and the truth's that no tracker data fix (the
    base gauge): zero for a parametric truth (its gauge parameters are nominal), 0.3-0.5 mm for
    a realistic one, whose unmodelled errors move the base gauge."""
    kpi, space = s.problem.kpi.in_frame(frame), s.problem.space
    if isinstance(p_true, RealisticTruth):
        return kpi.compute_values(space, p_est) - p_true.compute_kpi_values(kpi)
    return kpi.compute_values(space, p_est) - kpi.compute_values(space, p_true)


def write_measurement_file(s: Setup, path: str | os.PathLike, mset: MeasurementSet, comment: str) -> Path:
    return write_measurements(path, mset, s.problem.robot, s.reflector_names, comment=comment)
