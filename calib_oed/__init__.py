"""calib_oed: optimum experimental design for robot kinematic calibration.

The package face: what the README, the docs and the examples use is one
import away (``from calib_oed import load_scene, setup, design``). The
subpackages, bottom to top (each imports only those before it; the diagram is
in ``DEVELOPERS.md``): :mod:`~calib_oed.model`, :mod:`~calib_oed.measurement`,
:mod:`~calib_oed.feasibility`, :mod:`~calib_oed.scene`, :mod:`~calib_oed.io`,
:mod:`~calib_oed.calibration`, :mod:`~calib_oed.solver`, :mod:`~calib_oed.oed`,
:mod:`~calib_oed.viz`, :mod:`~calib_oed.study`, :mod:`~calib_oed.cli`.

The names are imported on first use (PEP 562 ``__getattr__``): ``calib-oed
design`` then loads only what the design needs, not the identification's
scipy.optimize and scipy.stats or the URDF export's yourdfpy and trimesh
(about 0.3 s of every command's start).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from calib_oed._version import __version__

#: Each public name and the module that defines it.
_EXPORTS = {
    "compensate_joints": "calib_oed.calibration.compensation",
    "compensate_pose": "calib_oed.calibration.compensation",
    "identify": "calib_oed.calibration.identification",
    "IdentificationResult": "calib_oed.calibration.identification_result",
    "TcpKpi": "calib_oed.calibration.kpi",
    "monte_carlo": "calib_oed.calibration.montecarlo",
    "CalibrationProblem": "calib_oed.calibration.problem",
    "draw_true_parameters": "calib_oed.calibration.simulation",
    "simulate_observations": "calib_oed.calibration.simulation",
    "validate_calibration": "calib_oed.calibration.validation",
    "Setup": "calib_oed.calibration.workflow",
    "heuristic_design": "calib_oed.calibration.workflow",
    "setup": "calib_oed.calibration.workflow",
    "tcp_errors": "calib_oed.calibration.workflow",
    "read_design_csv": "calib_oed.io.design_file",
    "read_measurements": "calib_oed.io.measurement_reader",
    "write_measurements": "calib_oed.io.measurement_writer",
    "PoseMeasurement": "calib_oed.measurement",
    "TrackerPosition": "calib_oed.measurement",
    "MeasurementSet": "calib_oed.measurement.dataset",
    "ParameterSpace": "calib_oed.model.parameters",
    "Robot": "calib_oed.model.robot",
    "load_robot": "calib_oed.model.robot",
    "design": "calib_oed.oed.design",
    "evaluate_design": "calib_oed.oed.design",
    "exchange_baseline": "calib_oed.oed.design",
    "heuristic_designs": "calib_oed.oed.design",
    "write_design": "calib_oed.oed.result",
    "SequentialDesigner": "calib_oed.oed.sequential",
    "load_scene": "calib_oed.scene.reader",
    "scene_from_dict": "calib_oed.scene.reader",
    "scene_names": "calib_oed.scene.reader",
    "Scene": "calib_oed.scene.records",
}

__all__ = [
    "CalibrationProblem", "IdentificationResult", "MeasurementSet", "ParameterSpace",
    "PoseMeasurement", "Robot", "Scene", "SequentialDesigner", "Setup", "TcpKpi",
    "TrackerPosition", "compensate_joints", "compensate_pose", "design", "draw_true_parameters", "evaluate_design",
    "exchange_baseline", "heuristic_design", "heuristic_designs", "identify", "load_robot",
    "load_scene", "monte_carlo", "read_design_csv", "read_measurements", "scene_from_dict",
    "scene_names", "setup", "simulate_observations", "tcp_errors", "validate_calibration",
    "write_design", "write_measurements", "__version__",
]


#: Subpackages reachable as attributes after ``import calib_oed`` (``calib_oed.oed.design.DESIGN_SQP``).
_SUBPACKAGES = ("model", "measurement", "feasibility", "scene", "io", "calibration", "solver", "oed",
                "viz", "study", "program", "cli")


def __getattr__(name: str):
    """A public name, imported from its module on first use (then cached in the package).

    A subpackage reached as an attribute first imports every module of the
    names above, as the eager package face did, so that ``calib_oed.oed.design``
    and the like resolve as before.
    """
    module = _EXPORTS.get(name)
    if module is not None:
        value = getattr(importlib.import_module(module), name)
    elif name in _SUBPACKAGES:
        for other in dict.fromkeys(_EXPORTS.values()):
            importlib.import_module(other)
        value = importlib.import_module(f"calib_oed.{name}")
    else:
        raise AttributeError(f"module 'calib_oed' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # the names for static analysis and IDEs
    from calib_oed.calibration.compensation import compensate_joints, compensate_pose
    from calib_oed.calibration.identification import identify
    from calib_oed.calibration.identification_result import IdentificationResult
    from calib_oed.calibration.kpi import TcpKpi
    from calib_oed.calibration.montecarlo import monte_carlo
    from calib_oed.calibration.problem import CalibrationProblem
    from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
    from calib_oed.calibration.validation import validate_calibration
    from calib_oed.calibration.workflow import Setup, heuristic_design, setup, tcp_errors
    from calib_oed.io.design_file import read_design_csv
    from calib_oed.io.measurement_reader import read_measurements
    from calib_oed.io.measurement_writer import write_measurements
    from calib_oed.measurement import PoseMeasurement, TrackerPosition
    from calib_oed.measurement.dataset import MeasurementSet
    from calib_oed.model.parameters import ParameterSpace
    from calib_oed.model.robot import Robot, load_robot
    from calib_oed.oed.design import design, evaluate_design, exchange_baseline, heuristic_designs
    from calib_oed.oed.result import write_design
    from calib_oed.oed.sequential import SequentialDesigner
    from calib_oed.scene.reader import load_scene, scene_from_dict, scene_names
    from calib_oed.scene.records import Scene
