"""Files: measurement and design files, and atomic writes.

Owns the measurement CSV format (reader and writer, producing
:class:`~calib_oed.measurement.dataset.MeasurementSet`), the design CSV files
(joint names, rad) and :func:`~calib_oed.io.atomic.atomic_write_text`, through
which every file calib_oed writes goes (never a half-written file). It may
import :mod:`calib_oed.model`, :mod:`calib_oed.measurement` and the base
modules, nothing above.
"""
