"""Measurement models: what an external sensor reports about the robot.

Owns the measurement-model contract (``compute_values``,
``compute_param_jacobian``, ``compute_config_jacobian``,
``compute_param_config_jacobian`` on a :class:`SetupState`), the laser
tracker's position and pose models, measured data as the estimator sees it
(:class:`~calib_oed.measurement.observations.ObservationBlock`, the
:class:`~calib_oed.measurement.dataset.MeasurementSet` record) and the
noise-weighted sensitivity :math:`F_1`. It may import :mod:`calib_oed.model`
and the package's base modules (exceptions, units), nothing above.
"""

from calib_oed.measurement.base import MeasurementModel, SetupState, evaluate_setup
from calib_oed.measurement.pose import PoseMeasurement
from calib_oed.measurement.position import TrackerPosition

__all__ = ["MeasurementModel", "PoseMeasurement", "SetupState", "TrackerPosition", "evaluate_setup"]
