r"""One covariance contract: measurement noise, robot repeatability and model error.

Every consumer (identification, covariance, Monte Carlo, cross-validation,
validation, design) gets the errors of the measurements from one
:class:`ErrorModel`:

- the **measurement models** it builds (:meth:`ErrorModel.models`, the only place
  they are built from a scene or a file), each carrying its noise contract
  (``noise_cholesky``, ``noise_covariance``, ``noise_whitening``, ``sample_noise``
  of :class:`~calib_oed.measurement.base.MeasurementModel`): independent
  components with standard deviations ``sigma``, or the tracker error model with
  the robot's repeatability (:class:`~calib_oed.measurement.noise.TrackerNoise`);
- the **model error** (:class:`~calib_oed.measurement.discrepancy.DiscrepancyPrior`),
  a Gaussian process over the joint configuration shared by every reflector
  measured at the same configuration.

The covariance of all measured values, in the estimator's row order (block,
then row, then component; :meth:`ErrorModel.covariance`), is

.. math::
    \Sigma = \mathrm{blockdiag}_i(\Sigma_{\mathrm{noise},i})
      + \big[k(q_a, q_b)\,\delta_{cc'}\big]_{(a,c),(b,c')} \quad [\mathrm{m}^2],

the model-error term on the three position components of each row
(:math:`c, c' \in \{x, y, z\}`; a 6-D probe's rotation components have none).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from calib_oed.exceptions import ParameterError
from calib_oed.measurement.base import MeasurementModel
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.measurement.pose import DEFAULT_SIGMA_ANGLE, PoseMeasurement
from calib_oed.measurement.position import DEFAULT_SIGMA, TrackerPosition

__all__ = ["MEASUREMENTS", "ErrorModel"]

#: Measurement kinds.
MEASUREMENTS = ("position", "pose")


@dataclass(frozen=True, eq=False)
class ErrorModel:
    """Measurement noise, robot repeatability and model error of a measurement set-up.

    Attributes:
        measurement: ``"position"`` (3-D per reflector) or ``"pose"`` (6-D probe).
        sigma: Position noise per tracker axis [m], scalar or (3,).
        sigma_angle: Rotation noise per axis [rad] (pose only).
        noise: The tracker error model with the robot's repeatability, or None:
            independent components with ``sigma`` (position only).
        discrepancy: The model-error prior, or None: the model is taken as exact.
    """

    measurement: str = "position"
    sigma: float | np.ndarray = DEFAULT_SIGMA
    sigma_angle: float | np.ndarray = DEFAULT_SIGMA_ANGLE
    noise: TrackerNoise | None = None
    discrepancy: DiscrepancyPrior | None = None

    def __post_init__(self):
        if self.measurement not in MEASUREMENTS:
            raise ParameterError(f"unknown measurement {self.measurement!r}; valid: "
                                 f"{', '.join(MEASUREMENTS)}")
        if self.noise is not None and self.measurement != "position":
            raise ParameterError("noise: the tracker error model applies to position rows only; "
                                 "this set-up measures poses (give noise=None)")

    def for_rows(self, pose_rows: bool) -> ErrorModel:
        """This model for data with (``True``) or without pose rows: the kind follows the data."""
        kind = "pose" if pose_rows else "position"
        return self if kind == self.measurement else replace(
            self, measurement=kind, noise=None if pose_rows else self.noise)

    def model(self, reflector: int) -> MeasurementModel:
        """The measurement model of one reflector."""
        if self.measurement == "pose":
            return PoseMeasurement(reflector, self.sigma, self.sigma_angle)
        return TrackerPosition(reflector, self.sigma, self.noise)

    def models(self, reflectors: Sequence[int]) -> list[MeasurementModel]:
        """One measurement model per reflector index, in the given order."""
        return [self.model(int(j)) for j in reflectors]

    # ------------------------------------------------------------ covariance
    def covariance(self, blocks, values: Sequence[np.ndarray] | None = None,
                   discrepancy: DiscrepancyPrior | None | bool = True) -> np.ndarray:
        r""":math:`\Sigma` (m, m) of the stacked values of ``blocks`` (module docstring) [SI²].

        Args:
            blocks: :class:`~calib_oed.measurement.observations.ObservationBlock` s.
            values: Per block, the (n, d) positions the noise is evaluated at
                (default: the measured values).
            discrepancy: True: this model's prior; a prior: that one; None or False: noise only.
        """
        noise = block_noise(blocks, values)
        prior = self.discrepancy if discrepancy is True else (discrepancy or None)
        if prior is None:
            return noise
        return noise + discrepancy_covariance(prior, blocks)


def row_layout(blocks) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per stacked value: its configuration (m, nq), whether it is a position component (m,),
    and its component index 0..d-1 (m,)."""
    q = np.concatenate([np.repeat(b.q, b.model.dim, axis=0) for b in blocks])
    comp = np.concatenate([np.tile(np.arange(b.model.dim), b.n) for b in blocks])
    units = np.concatenate([np.tile(np.array(b.model.units), b.n) for b in blocks])
    return q, units == "m", comp


def block_noise(blocks, values: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """Block-diagonal noise covariance (m, m) of the stacked values of ``blocks`` [SI²]."""
    mats = []
    for k, b in enumerate(blocks):
        y = b.values if values is None else values[k]
        mats.append(b.model.noise_covariance(y, b.sigma))
    m = sum(a.shape[0] * a.shape[1] for a in mats)
    out = np.zeros((m, m))
    start = 0
    for a in mats:
        for cov in a:
            d = cov.shape[0]
            out[start:start + d, start:start + d] = cov
            start += d
    return out


def discrepancy_covariance(prior: DiscrepancyPrior, blocks) -> np.ndarray:
    r"""The model-error part :math:`k(q_a, q_b)\,\delta_{cc'}` on position components, (m, m) [m²]."""
    q, position, comp = row_layout(blocks)
    same = (comp[:, None] == comp[None, :]) & position[:, None] & position[None, :]
    return np.where(same, prior.covariance_kernel(q, q), 0.0)
