r"""Measured data as the estimator sees it: blocks of one measurement model each.

An :class:`ObservationBlock` holds the n configurations at which one
measurement model (one reflector, position or pose) was measured, the
measured values :math:`\eta` (n, d) and their standard deviations
:math:`\sigma` (n, d), all SI [m, rad]. Measurement files
(:mod:`calib_oed.io.measurement_reader`) and simulations (:mod:`calib_oed.calibration.simulation`) produce
them; identification (:mod:`calib_oed.calibration.identification`) consumes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.measurement.base import MeasurementModel


@dataclass(frozen=True, eq=False)
class ObservationBlock:
    """Measurements of one model at n configurations.

    Attributes:
        model: What was measured (e.g. ``TrackerPosition(reflector=0)``).
        q: Configurations [rad or m per joint], (n, nq).
        values: Measured values :math:`\\eta` in the model's units (SI), (n, d).
        sigma: Standard deviation of each value (SI), (n, d); defaults to the
            model's ``sigma`` on every row.
    """

    model: MeasurementModel
    q: np.ndarray
    values: np.ndarray
    sigma: np.ndarray | None = None

    def __post_init__(self):
        q = np.array(self.q, dtype=float, ndmin=2)
        values = np.array(self.values, dtype=float, ndmin=2)
        d = self.model.dim
        if values.shape != (q.shape[0], d):
            raise ShapeError(f"values of {self.model.name}", f"({q.shape[0]}, {d})", values.shape)
        if self.sigma is None:
            sigma = np.tile(self.model.sigma, (q.shape[0], 1))
        else:
            sigma = np.array(self.sigma, dtype=float)
            if sigma.ndim == 1 and sigma.shape == (q.shape[0],):
                sigma = np.repeat(sigma[:, None], d, axis=1)
            if sigma.shape != values.shape:
                raise ShapeError(f"sigma of {self.model.name}", f"({q.shape[0]},) or {values.shape}", sigma.shape)
        for what, arr in (("q", q), ("values", values), ("sigma", sigma)):
            if not np.all(np.isfinite(arr)):
                raise NonFiniteError(f"{what} of {self.model.name}", np.flatnonzero(~np.isfinite(arr)))
            arr.setflags(write=False)
        if np.any(sigma <= 0):
            raise ValueError(f"sigma of {self.model.name}: every standard deviation must be > 0")
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "sigma", sigma)

    @property
    def n(self) -> int:
        """Number of configurations."""
        return self.q.shape[0]
