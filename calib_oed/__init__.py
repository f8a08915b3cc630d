"""calib_oed: optimum experimental design for robot kinematic calibration.

The package face: what the README, the docs and the examples use is one
import away (``from calib_oed import load_scene, setup, design``). The
subpackages, bottom to top (each imports only those before it; the diagram is
in ``DEVELOPERS.md``): :mod:`~calib_oed.model`, :mod:`~calib_oed.measurement`,
:mod:`~calib_oed.feasibility`, :mod:`~calib_oed.scene`, :mod:`~calib_oed.io`,
:mod:`~calib_oed.calibration`, :mod:`~calib_oed.solver`, :mod:`~calib_oed.oed`,
:mod:`~calib_oed.viz`, :mod:`~calib_oed.study`, :mod:`~calib_oed.cli`.
"""

from calib_oed._version import __version__
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

__all__ = [
    "CalibrationProblem", "IdentificationResult", "MeasurementSet", "ParameterSpace",
    "PoseMeasurement", "Robot", "Scene", "SequentialDesigner", "Setup", "TcpKpi",
    "TrackerPosition", "design", "draw_true_parameters", "evaluate_design",
    "exchange_baseline", "heuristic_design", "heuristic_designs", "identify", "load_robot",
    "load_scene", "monte_carlo", "read_design_csv", "read_measurements", "scene_from_dict",
    "scene_names", "setup", "simulate_observations", "tcp_errors", "validate_calibration",
    "write_design", "write_measurements", "__version__",
]
