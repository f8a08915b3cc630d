"""The noise contract every measurement model carries: one way to get a measurement's covariance.

Identification, covariance, simulation, Monte Carlo, cross-validation, validation and
the design get the noise of a measurement only through these methods
(:class:`NoiseContract`, a base of :class:`~calib_oed.measurement.base.MeasurementModel`):
independent components with the model's ``sigma`` (or a measurement file's per-row
sigmas), or the model's full error model ``noise`` (the tracker's range- and
direction-dependent covariance with the robot's repeatability,
:class:`~calib_oed.measurement.noise.TrackerNoise`), evaluated at the given positions.
"""

from __future__ import annotations

import numpy as np


class NoiseContract:
    """The ``noise_*`` methods of a measurement model (module docstring); needs ``dim`` and ``sigma``."""

    dim: int = 0
    sigma: np.ndarray

    #: Full error model of one measurement (a
    #: :class:`~calib_oed.measurement.noise.TrackerNoise`: tracker noise and robot
    #: repeatability), or None: independent components with standard deviations ``sigma``.
    #: Consumers call the ``noise_*`` methods below (one contract); only the design
    #: objective reads it, for the closed-form derivatives of :mod:`calib_oed.oed.whitening`.
    noise = None

    # ------------------------------------------------------ noise contract
    def _row_sigma(self, n: int, sigma) -> np.ndarray:
        return np.broadcast_to(self.sigma if sigma is None else np.asarray(sigma, float), (n, self.dim))

    def _noise_matrix(self, values, sigma, full: str, power: int) -> np.ndarray:
        """The full error model's ``full`` matrices, or :math:`\\mathrm{diag}(\\sigma^{power})`."""
        values = np.asarray(values, dtype=float)
        if self.noise is not None:
            return getattr(self.noise, full)(values[:, :3])
        s = self._row_sigma(values.shape[0], sigma)
        return (s**power)[:, :, None] * np.eye(self.dim)

    def noise_cholesky(self, values: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        r"""Lower :math:`L_i` with :math:`\Sigma_i = L_i L_i^\top` per measurement, (n, d, d) [SI].

        ``values`` (n, d): the positions the error model is evaluated at (the tracker
        model depends on range and direction); ``sigma`` (n, d): per-row standard
        deviations of a measurement file, used when the model has no full error model.
        """
        return self._noise_matrix(values, sigma, "cholesky", 1)

    def noise_covariance(self, values: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        r""":math:`\Sigma_i` (n, d, d) [SI²] of each measurement (:meth:`noise_cholesky`)."""
        return self._noise_matrix(values, sigma, "covariance", 2)

    def noise_whitening(self, values: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        r""":math:`W_i = L_i^{-1}` (n, d, d): :math:`W_i e_i \sim N(0, I)` for the noise :math:`e_i`."""
        return self._noise_matrix(values, sigma, "whitening", -1)

    def sample_noise(self, values: np.ndarray, rng: np.random.Generator,
                     sigma: np.ndarray | None = None) -> np.ndarray:
        """One noise draw per measurement at ``values`` (n, d), (n, d) [SI]."""
        values = np.asarray(values, dtype=float)
        if self.noise is not None:
            return self.noise.sample(values[:, :3], rng)
        return rng.normal(size=values.shape) * self._row_sigma(values.shape[0], sigma)
