r"""Robust identification with an estimated residual scale: outliers judged against the data's scale.

The plain estimator (:func:`calib_oed.calibration.identification.identify`,
linear least squares) judges residuals against the stated :math:`\sigma`. On real data
the residual scale is set by model error (gravity, gear play) as often as by
the tracker: :math:`\hat\sigma_0 \approx 10` flags most rows as "outliers".
:func:`identify_robust` estimates the scale from the data instead:

1. **Measurements.** Measurement :math:`i` (one row of one block, :math:`d_i`
   components) has the squared weighted residual
   :math:`t_i = \lVert r_i\rVert^2` (:math:`r = \Sigma^{-1}(h - \eta)`, units of
   :math:`\sigma`). With noise of scale :math:`s\sigma`,
   :math:`t_i/s^2 \sim \chi^2_{d_i}` (up to leverage).
2. **Robust scale** (a median, insensitive to up to half the rows being bad):
   :math:`\hat s^2 = \frac{m}{m - n_f}\ \mathrm{median}_i\big(t_i / \chi^2_{d_i,0.5}\big)`,
   :math:`\chi^2_{d,0.5}` the median of :math:`\chi^2_d`, :math:`m/(m-n_f)` the
   leverage correction of fitted residuals.
3. **Huber M-estimate by IRLS.** From the linear fit, repeat: :math:`\hat s` from
   the current residuals, weights :math:`w_i = \min(1, k/z_i)` with
   :math:`z_i = \sqrt{t_i}/\hat s` and :math:`k = \sqrt{\chi^2_{d_i,0.90}}`,
   weighted least squares (each measurement's :math:`\sigma` divided by
   :math:`\sqrt{w_i}`), until the weights change by less than 1e-4.
4. **Flags.** :math:`z_i > z_\alpha = \sqrt{\chi^2_{d_i,1-\alpha}}` (:math:`\alpha` =
   1e-3: a Gaussian measurement is flagged with probability 1e-3).
5. **Final estimate.** No flag: the linear fit itself, unchanged (its
   covariance is exact for Gaussian noise). Flags: the linear fit on the
   unflagged measurements (weight 0 for the flagged, 1 for the others), the
   flags re-decided with the scale of that fit,
   :math:`\hat\sigma_0^2 = \sum_{kept} t_i/(m_{kept} - n_f)`, until they no
   longer change (at most 5 rounds). Its covariance is the linear one on the
   kept rows; ``std_posterior`` scales it by that :math:`\hat\sigma_0`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize
from scipy.stats import chi2

from calib_oed.calibration.crossval import pose_index
from calib_oed.calibration.flags import (
    DEFAULT_ALPHA,
    FlagClasses,
    classify_flags,
    judge_measurements,
)
from calib_oed.calibration.identification import (
    IdentificationResult,
    identify,
    residual_function,
)
from calib_oed.calibration.model_error import (
    Linearisation,
    ModelErrorFit,
    estimate_covariance,
    fit_model_error,
    linearise,
)
from calib_oed.exceptions import ParameterError
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.model.parameters import ParameterSpace


@dataclass(frozen=True, eq=False)
class RobustIdentification:
    """The robust pass and the final estimate (arrays per measurement, in block-then-row order).

    Attributes:
        result: The final estimate (the linear fit, or the linear fit on the kept measurements).
        linear: The plain linear fit of all measurements.
        block, row: Block index and row in the block of each measurement, (M,).
        dim: Components per measurement, (M,).
        normalised: :math:`z_i = \\lVert r_i\\rVert / \\hat s` at the final estimate, (M,).
        robust_weight: Huber weight of the robust pass, (M,), in (0, 1].
        flagged: Outliers, excluded from the final estimate, (M,) bool.
        scale: :math:`\\hat s` used for the final flags: :math:`\\hat\\sigma_0` of the final fit.
        robust_scale: The median-based scale of the Huber pass.
        alpha: False-flag probability per Gaussian measurement.
        iterations: IRLS iterations of the Huber pass.
        rounds: Refits of the final estimate.
    """

    result: IdentificationResult
    linear: IdentificationResult
    block: np.ndarray = field(repr=False)
    row: np.ndarray = field(repr=False)
    dim: np.ndarray = field(repr=False)
    normalised: np.ndarray = field(repr=False)
    robust_weight: np.ndarray = field(repr=False)
    flagged: np.ndarray = field(repr=False)
    scale: float
    robust_scale: float
    alpha: float
    iterations: int
    rounds: int
    #: With a model-error prior (:func:`identify_robust` ``model_error=``): the fitted
    #: hyperparameters, which flags look like model error, the measurements left out of the
    #: final estimate, and the parameter std under noise + model error (n_f,) [SI].
    model_error: ModelErrorFit | None = None
    classes: FlagClasses | None = None
    dropped: np.ndarray | None = field(default=None, repr=False)
    std: np.ndarray | None = field(default=None, repr=False)
    linearisation: Linearisation | None = field(default=None, repr=False)

    @property
    def weight(self) -> np.ndarray:
        """Weight in the final estimate: 0 for a measurement left out, 1 otherwise."""
        if self.dropped is not None:
            return (~self.dropped).astype(float)
        return (~self.flagged).astype(float)

    @property
    def parameter_std(self) -> np.ndarray:
        """A-posteriori std of the free parameters [SI]: under noise + model error when fitted,
        else the noise-only std times the residual scale."""
        return self.std if self.std is not None else self.result.std * self.scale

    @property
    def threshold(self) -> np.ndarray:
        """:math:`z_\\alpha` per measurement."""
        return np.sqrt(chi2.ppf(1 - self.alpha, self.dim))

    @property
    def n_flagged(self) -> int:
        return int(self.flagged.sum())


#: Which flagged measurements :func:`identify_robust` leaves out (with a model-error prior).
DROPS = ("gross", "all", "none")


def _layout(blocks):
    block = np.concatenate([np.full(b.n, k) for k, b in enumerate(blocks)])
    row = np.concatenate([np.arange(b.n) for b in blocks])
    dim = np.concatenate([np.full(b.n, b.model.dim) for b in blocks])
    return block, row, dim


def robust_scale(t: np.ndarray, dim: np.ndarray, n_free: int) -> float:
    r"""Median-based scale :math:`\hat s` of squared measurement residuals ``t`` [sigma]."""
    m = int(dim.sum())
    ratio = m / (m - n_free) if m > n_free else 1.0
    return float(np.sqrt(ratio * np.median(t / chi2.ppf(0.5, dim))))


def _subset(blocks, keep_by_block):
    out = []
    for b, keep in zip(blocks, keep_by_block, strict=True):
        if keep.any():
            out.append(ObservationBlock(b.model, b.q[keep], b.values[keep], b.sigma[keep]))
    return out


def identify_robust(space: ParameterSpace, blocks: Sequence[ObservationBlock], free, *,
                    alpha: float = DEFAULT_ALPHA, max_iterations: int = 50,
                    model_error: DiscrepancyPrior | None = None, drop: str = "gross",
                    **options) -> RobustIdentification:
    """Outliers judged against the data, then the linear fit without the gross errors.

    With ``model_error`` (the scene's prior, ``scene.discrepancy()``): the model
    error's hyperparameters by restricted likelihood, flags against noise + model
    error (:mod:`calib_oed.calibration.flags`), gross errors left out (``drop``),
    flags that look like model error kept. Without: Huber IRLS with an estimated
    scale (module docstring), every flag left out.

    Args:
        space, blocks, free: As :func:`~calib_oed.calibration.identification.identify`.
        alpha: False-flag probability of a Gaussian measurement, in (0, 0.5).
        max_iterations: Of the IRLS pass.
        model_error: The model-error prior the hyperparameters start from.
        drop: With ``model_error``, which flagged measurements the final estimate leaves out:
            ``"gross"`` (default: the gross errors; flags that look like model error and
            suspect ones are kept, :mod:`calib_oed.calibration.flags`), ``"all"`` or ``"none"``.
        options: Passed to every :func:`identify` call.

    Raises:
        ParameterError: bad ``alpha`` or ``drop``.
        NotIdentifiableError: as :func:`identify`, also when the kept measurements
            no longer determine the parameters.
    """
    if not 0 < alpha < 0.5:
        raise ParameterError(f"alpha (false-flag probability) must be in (0, 0.5), got {alpha}")
    blocks = list(blocks)
    if drop not in DROPS:
        raise ParameterError(f"unknown drop {drop!r}; valid: {', '.join(DROPS)}")
    if model_error is not None:
        return _with_model_error(space, blocks, free, model_error, alpha, drop, options)
    linear = identify(space, blocks, free, **options)
    block, row, dim = _layout(blocks)
    meas = np.repeat(np.arange(block.size), dim)
    n_f = len(linear.free_names)
    k_huber = np.sqrt(chi2.ppf(0.90, dim))
    z_flag = np.sqrt(chi2.ppf(1 - alpha, dim))
    fun = residual_function(space, blocks, linear.free_indices, linear.p)

    def squared(x):
        return np.bincount(meas, fun.fun(x) ** 2, minlength=block.size)

    x = np.array(linear.p_free)
    w = np.ones(block.size)
    s = robust_scale(squared(x), dim, n_f)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 - reported
        t = squared(x)
        s = robust_scale(t, dim, n_f)
        z = np.sqrt(t) / s if s > 0 else np.zeros_like(t)
        w_new = np.minimum(1.0, k_huber / np.maximum(z, 1e-300))
        if iterations > 1 and np.max(np.abs(w_new - w)) < 1e-4:
            w = w_new
            break
        w = w_new
        sw = np.sqrt(w)[meas]
        sol = scipy.optimize.least_squares(lambda v, sw=sw: sw * fun.fun(v), x,
                                           jac=lambda v, sw=sw: sw[:, None] * fun.jac(v),
                                           method="lm", x_scale="jac", xtol=1e-10, ftol=1e-10,
                                           gtol=1e-10)
        x = sol.x
    t = squared(x)
    huber_scale = robust_scale(t, dim, n_f)
    flagged = np.sqrt(t) / huber_scale > z_flag if huber_scale > 0 else np.zeros(block.size, bool)
    result, rounds = linear, 0
    p_start = linear.p.copy()
    p_start[linear.free_indices] = x
    while flagged.any() and rounds < 5:
        rounds += 1
        keep = [~flagged[block == k] for k in range(len(blocks))]
        result = identify(space, _subset(blocks, keep), free, p0=p_start, **options)
        t = squared(result.p_free)
        s_fit = np.sqrt(t[~flagged].sum() / max(int(dim[~flagged].sum()) - n_f, 1))
        new = np.sqrt(t) / s_fit > z_flag
        if np.array_equal(new, flagged):
            break
        flagged, p_start = new, result.p.copy()
    if not flagged.any():
        result = linear
    t = squared(result.p_free)
    kept_dof = int(dim[~flagged].sum()) - n_f
    scale = float(np.sqrt(t[~flagged].sum() / kept_dof)) if kept_dof > 0 else float("nan")
    return RobustIdentification(
        result=result, linear=linear, block=block, row=row, dim=dim,
        normalised=np.sqrt(t) / scale, robust_weight=w, flagged=flagged, scale=scale,
        robust_scale=huber_scale, alpha=float(alpha), iterations=iterations, rounds=rounds,
    )


def _with_model_error(space, blocks, free, prior, alpha, drop, options) -> RobustIdentification:
    """:func:`identify_robust` with a model-error prior (its docstring)."""
    linear = identify(space, blocks, free, **options)
    block, row, dim = _layout(blocks)
    lin = linearise(space, blocks, linear.p, linear.free_indices)
    fit = fit_model_error(lin, prior)
    flagged, t, _ = judge_measurements(lin, fit.prior, alpha)
    rounds = 0
    while flagged.any() and rounds < 3:  # hyperparameters without the flagged, flags again
        rounds += 1
        fit = fit_model_error(lin.subset(~flagged), prior)
        new, t, _ = judge_measurements(lin, fit.prior, alpha)
        if np.array_equal(new, flagged):
            break
        flagged = new
    q = np.concatenate([b.q for b in blocks])
    classes = classify_flags(flagged, pose_index(q), q, space.robot.joint_names, t)
    dropped = {"gross": classes.gross, "all": flagged, "none": np.zeros(flagged.size, bool)}[drop]
    result, final = linear, lin
    if dropped.any():
        kept = _subset(blocks, [~dropped[block == k] for k in range(len(blocks))])
        result = identify(space, kept, free, p0=linear.p, **options)
        final = linearise(space, kept, result.p, result.free_indices)
    if flagged.any():  # the model error of what the fit keeps (suspects and model error too)
        fit = fit_model_error(final, fit.prior)
    std = np.sqrt(np.diag(estimate_covariance(final, fit.prior)))
    scale = float(result.sigma0)
    return RobustIdentification(
        result=result, linear=linear, block=block, row=row, dim=dim, normalised=np.sqrt(t),
        robust_weight=np.ones(block.size), flagged=flagged, scale=scale, robust_scale=scale,
        alpha=float(alpha), iterations=0, rounds=rounds, model_error=fit, classes=classes,
        dropped=dropped, std=std, linearisation=final)
