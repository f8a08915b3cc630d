"""Optimum experimental design: which configurations to measure.

Owns the design criteria (A on the KPI or parameter covariance, D, E, and
the observability indices O1-O5), the design objective with its exact
derivatives, the design NLP handed to :mod:`calib_oed.solver`, the design
driver and its record, the exchange algorithm, the approximate design, the
optimality certificate and sequential design. It may import every package
below it (model, measurement, feasibility, scene, io, calibration, solver),
never :mod:`calib_oed.viz`, :mod:`calib_oed.study` or :mod:`calib_oed.cli`.
"""
