"""Measurement models: what an external sensor reports about the robot."""

from calib_oed.measurements.base import MeasurementModel, SetupState, evaluate_setup
from calib_oed.measurements.pose import PoseMeasurement
from calib_oed.measurements.position import TrackerPosition

__all__ = ["MeasurementModel", "PoseMeasurement", "SetupState", "TrackerPosition", "evaluate_setup"]
