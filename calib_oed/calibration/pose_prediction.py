r"""Predicted error at each validation measurement, from the identification's record.

``calib-oed identify -o DIR`` writes, in ``identification.json``, the fitted model
error (``model_error.fitted``) and the identification linearised at its estimate
(``prediction_data``: :math:`J`, the noise blocks, the residuals, the
configurations, the free parameters' names;
:meth:`~calib_oed.calibration.model_error.Linearisation.to_dict`). That is all
:func:`~calib_oed.calibration.prediction.error_covariances` needs, so ``validate``
predicts, for every validation measurement at :math:`q_\ast`, the covariance

.. math::
    V_\ast = k(q_\ast, q_\ast)\,I_3 - BC_\ast - C_\ast^\top B^\top + B\Sigma B^\top + N_\ast
    \quad [\mathrm{m}^2]

of its position error (parameter uncertainty + model error + noise; with
``--compensate`` the fitted model error's mean is added to the prediction and
:math:`B` includes it), :math:`G_\ast` the parameter Jacobian of the measured
point evaluated with the calibrated files (the same parameter names; it differs
from the Jacobian at the estimate only by second-order terms in the parameter
change). Per measurement: :math:`\sqrt{\mathrm{tr}\,V_\ast}`, the expected RMS of its
3-D error [mm], and whether the error lies in its 95 % prediction region
:math:`r^\top V_\ast^{-1} r \le c`, :math:`c` the identification's ``region_threshold``
(widened for the uncertainty of the fitted model error,
:mod:`calib_oed.calibration.hyper_uncertainty`; :math:`\chi^2_3(0.95)` when not recorded).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from calib_oed.calibration.joint_prior_choice import fitted_model_error
from calib_oed.calibration.model_error import Linearisation
from calib_oed.calibration.prediction import error_covariances
from calib_oed.exceptions import ParameterError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.model.parameters import ParameterSpace

MM_PER_M = 1e3
#: Level of the per-measurement prediction regions.
LEVEL = 0.95


@dataclass(frozen=True, eq=False)
class RowPrediction:
    """Predicted position error per validation measurement.

    Attributes:
        rms_mm: :math:`\\sqrt{\\mathrm{tr}\\,V_\\ast}` per row [mm], (n,).
        inside: Whether the achieved error lies in the row's 95 % prediction region, (n,).
        compensated: Whether the predictions add the fitted model error's mean.
    """

    rms_mm: np.ndarray = field(repr=False)
    inside: np.ndarray = field(repr=False)
    compensated: bool

    @property
    def total_rms_mm(self) -> float:
        """The predicted RMS over all rows [mm]: :math:`\\sqrt{\\mathrm{mean}\\,\\mathrm{tr}\\,V_\\ast}`."""
        return float(np.sqrt(np.mean(self.rms_mm**2)))

    def line(self) -> str:
        """The predicted RMS at these measurements and the coverage of their regions, in words."""
        n, k = self.inside.size, int(self.inside.sum())
        return (f"predicted at these measurements: RMS {self.total_rms_mm:.4f} mm (parameter "
                f"uncertainty + model error + noise); {k} of {n} ({100 * k / n:.1f} %) inside their "
                f"{100 * LEVEL:.0f} % prediction regions (about {100 * LEVEL:.0f} % expected when "
                "the calibration's statistics hold)")


def read_record(identification: dict | None, space: ParameterSpace
                ) -> tuple[Linearisation, DiscrepancyPrior, tuple[str, ...]] | None:
    """The linearised identification, its fitted model error (its pose scale restored for the
    scene's ``space``) and free parameter names, or None when ``identification.json`` has no
    ``prediction_data`` (written before it existed)."""
    try:
        data = identification["prediction_data"]
        prior = fitted_model_error(identification["model_error"]["fitted"], space)
        return Linearisation.from_dict(data), prior, tuple(str(n) for n in data["free_names"])
    except (TypeError, KeyError, ValueError, IndexError, ParameterError):
        return None


def region_threshold_of(identification: dict | None, compensated: bool) -> float:
    r"""The identification's ``region_threshold`` of the 95 % regions, or :math:`\chi^2_3(0.95)`."""
    try:
        block = identification["predicted_accuracy"]["compensated" if compensated else "uncompensated"]
        value = float(block["region_threshold"])
    except (TypeError, KeyError, ValueError):
        return float(chi2.ppf(LEVEL, 3))
    return value if np.isfinite(value) and value > 0 else float(chi2.ppf(LEVEL, 3))


def predict_rows(record, space: ParameterSpace, p: np.ndarray | None, mset, blocks,
                 residual: np.ndarray, compensated: bool = False,
                 threshold: float | None = None) -> RowPrediction:
    r""":class:`RowPrediction` of the rows of the measurement set ``mset`` (``blocks`` =
    ``mset.blocks(...)``) with the calibrated ``space`` at ``p``; ``residual`` the measured
    minus predicted position per row of ``mset``, (n, 3) [m]; ``threshold`` :math:`c`
    (None: :math:`\chi^2_3(0.95)`).

    Raises:
        ParameterError: a free parameter of the record is not a parameter of ``space``.
    """
    lin, prior, names = record
    missing = [n for n in names if n not in space.names]
    if missing:
        raise ParameterError(f"identification.json: parameters {missing} are not the calibrated "
                             "model's; identify again with this scene")
    free = np.array([space.names.index(n) for n in names], dtype=int)
    cov = np.zeros((mset.n, 3, 3))
    for j, block in zip(mset.reflectors, blocks, strict=True):
        state = evaluate_setup(space, p, block.q, regressor=True, jacobian=False)
        h = block.model.compute_values(state)
        jac = block.model.compute_param_jacobian(state)[:, :3][:, :, free]
        noise = block.model.noise_covariance(h, block.sigma)[:, :3, :3]
        cov[mset.reflector == j] = error_covariances(lin, prior, jac, block.q, noise, compensated)
    t = np.einsum("ni,nij,nj->n", residual, np.linalg.inv(cov), residual)
    limit = float(chi2.ppf(LEVEL, 3)) if threshold is None else threshold
    return RowPrediction(np.sqrt(np.trace(cov, axis1=1, axis2=2)) * MM_PER_M, t <= limit,
                         bool(compensated))
