"""Calibration: from a scene and data to calibrated parameters and their uncertainty.

Owns the calibration problem (a scene's pieces wired together), the KPI and
its Jacobian, covariances of the parameters and the KPI, confidence regions,
identification by weighted nonlinear least squares and its result, simulated
calibrations and the Monte Carlo check, validation against separate data,
export of calibrated URDFs and sensor files, text reports, and the
:mod:`~calib_oed.calibration.workflow` that assembles a scene into a set-up.
It may import :mod:`calib_oed.model`, :mod:`calib_oed.measurement`,
:mod:`calib_oed.feasibility`, :mod:`calib_oed.scene`, :mod:`calib_oed.io`
and the base modules, nothing above.
"""
