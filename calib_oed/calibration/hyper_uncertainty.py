r"""How uncertain the fitted model error is, and what that does to the predicted accuracy.

The model error's hyperparameters :math:`\theta = (\log\sigma, \log\ell_j, \log\sigma_w)`
come from one restricted-likelihood fit of a few dozen poses
(:func:`~calib_oed.calibration.model_error.fit_model_error`); the predicted
accuracy (:mod:`calib_oed.calibration.prediction`) takes them as exact. On the
realistic simulator the predicted RMS on new poses is off the achieved by up to
±10 % per truth, and the coverage of the 95 % regions follows it (0.87-0.97 on
1000 new poses per truth), while the leave-one-pose-out residuals of the
training data are calibrated (their mean :math:`t/d` is 0.91-1.05): the spread
is the hyperparameters' estimation error, not a missing term.

**Laplace approximation** (:func:`laplace_covariance`). Near the maximum the
restricted log-likelihood is quadratic, so :math:`\theta \approx N(\hat\theta, H^{-1})`,
:math:`H = -\partial^2\log L/\partial\theta^2` by central differences of its
analytic gradient (step :data:`STEP` in each log-hyperparameter), over the
hyperparameters not at a bound (a length scale at its upper bound ignores its
joint; its direction is flat and carries no information). Eigenvalues of
:math:`H` below :data:`EIGEN_FLOOR` of the largest are raised to it.

**Spread of the prediction** (:func:`log_spread`). A prediction
:math:`v(\theta)` (the mean :math:`\mathrm{tr}\,V_\ast` over new poses) has, to
first order, :math:`\mathrm{sd}(\log v) = \tau = \sqrt{g^\top H^{-1} g}`,
:math:`g = \partial\log v/\partial\theta` by central differences. The predicted
RMS then lies in :math:`\mathrm{RMS}\,e^{\pm 1.96\tau/2}` with 95 % probability.

**Not determined.** When the model error is small against the noise the
likelihood is flat in its size (an exact model's data fit :math:`\sigma` of a few µm
with a Laplace sd of hundreds in :math:`\log\sigma`), the quadratic approximation
fails and :math:`\tau` is meaningless; above :data:`TAU_MAX` no range is given
(the prediction is then noise-dominated or the poses too few to size the model
error, and the report says so) and the regions stay at :math:`\chi^2_3(0.95)`.

**Prediction regions** (:func:`region_threshold`). A new point's error with
:math:`V_\ast` scaled by :math:`e^{x}`, :math:`x \sim N(0, \tau^2)`, has
:math:`t = e^\top V_\ast^{-1} e \sim e^{x}\chi^2_3`; the 95 % region of the
mixture is :math:`t \le c`, :math:`\mathrm{E}_x\,F_{\chi^2_3}(c\,e^{-x}) = 0.95`
(Gauss-Hermite quadrature, 40 nodes), wider than :math:`\chi^2_3(0.95)` = 7.81.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.optimize
from scipy.stats import chi2

from calib_oed.calibration.model_error import (
    HARMONIC_BOUNDS,
    LENGTH_BOUNDS,
    SIGMA_BOUNDS,
    WEIGHT_BOUNDS,
    WHITE_BOUNDS,
    Linearisation,
    restricted_log_likelihood,
)
from calib_oed.measurement.discrepancy import DiscrepancyPrior

#: Central-difference step in each log-hyperparameter.
STEP = 1e-3
#: Smallest eigenvalue of the Hessian, relative to its largest.
EIGEN_FLOOR = 1e-6
#: A log-hyperparameter within this of a bound is taken as at the bound.
AT_BOUND = 0.05
#: Above this sd of the log prediction the Laplace range is not given (module docstring).
TAU_MAX = 0.5


def theta_of(prior: DiscrepancyPrior) -> np.ndarray:
    """:math:`\\theta` (``prior.n_kernel_hyperparameters`` + 1,): log sigma, log length scales,
    log harmonic amplitudes (harmonic kernels), log weight of a pose scale, log white part (each
    at least its lower bound)."""
    amp = np.maximum(prior.harmonic, HARMONIC_BOUNDS[0]) if prior.harmonic else []
    weight = [] if prior.scale is None else [max(prior.scale.weight, WEIGHT_BOUNDS[0])]
    return np.log([prior.sigma, *prior.length_scales, *amp, *weight, max(prior.sigma_white, WHITE_BOUNDS[0])])


def prior_of(prior: DiscrepancyPrior, theta: np.ndarray) -> DiscrepancyPrior:
    """``prior`` with the hyperparameters :math:`\\theta`."""
    nq, n_h = prior.nq, len(prior.harmonic)
    amp = np.exp(theta[1 + nq:1 + nq + n_h]) if prior.harmonic else None
    weight = None if prior.scale is None else float(min(np.exp(theta[-2]), 1.0))
    return prior.with_values(float(np.exp(theta[0])), np.exp(theta[1:1 + nq]), prior.source,
                             float(np.exp(theta[-1])), amp, weight)


def _bounds(prior: DiscrepancyPrior) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of :func:`theta_of` (log)."""
    n_h, n_w = len(prior.harmonic), int(prior.scale is not None)
    lo = [SIGMA_BOUNDS[0]] + [LENGTH_BOUNDS[0]] * prior.nq + [HARMONIC_BOUNDS[0]] * n_h \
        + [WEIGHT_BOUNDS[0]] * n_w + [WHITE_BOUNDS[0]]
    hi = [SIGMA_BOUNDS[1]] + [LENGTH_BOUNDS[1]] * prior.nq + [HARMONIC_BOUNDS[1]] * n_h \
        + [WEIGHT_BOUNDS[1]] * n_w + [WHITE_BOUNDS[1]]
    return np.log(lo), np.log(hi)


def laplace_covariance(lin: Linearisation, prior: DiscrepancyPrior) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the hyperparameters not at a bound and :math:`H^{-1}` over them (module
    docstring); ``prior`` the restricted-likelihood fit of ``lin``."""
    theta = theta_of(prior)
    lo, hi = _bounds(prior)
    active = np.flatnonzero((theta > lo + AT_BOUND) & (theta < hi - AT_BOUND))
    hess = np.zeros((active.size, active.size))
    for a, k in enumerate(active):
        grads = []
        for sign in (1.0, -1.0):
            th = theta.copy()
            th[k] += sign * STEP
            grads.append(restricted_log_likelihood(lin, prior_of(prior, th), gradient=True)[1][active])
        hess[a] = -(grads[0] - grads[1]) / (2 * STEP)
    w, v = np.linalg.eigh(0.5 * (hess + hess.T))
    w = np.maximum(w, EIGEN_FLOOR * max(float(w.max()), np.finfo(float).tiny))
    return active, (v / w) @ v.T


def log_spread(prior: DiscrepancyPrior, active: np.ndarray, cov: np.ndarray,
               value: Callable[[DiscrepancyPrior], float]) -> float:
    """:math:`\\tau`, the standard deviation of :math:`\\log v(\\theta)` (module docstring), for a
    positive prediction ``value`` of a prior."""
    theta = theta_of(prior)
    g = np.empty(active.size)
    for a, k in enumerate(active):
        logs = []
        for sign in (1.0, -1.0):
            th = theta.copy()
            th[k] += sign * STEP
            logs.append(np.log(value(prior_of(prior, th))))
        g[a] = (logs[0] - logs[1]) / (2 * STEP)
    return float(np.sqrt(max(g @ cov @ g, 0.0)))


def region_threshold(tau: float, dim: int = 3, level: float = 0.95) -> float:
    """:math:`c` of the mixture's ``level`` region (module docstring); :math:`\\chi^2_d(level)` at
    :math:`\\tau = 0`."""
    base = float(chi2.ppf(level, dim))
    if tau <= 0:
        return base
    x, w = np.polynomial.hermite_e.hermegauss(40)
    w = w / w.sum()

    def gap(log_c):
        return float(np.sum(w * chi2.cdf(np.exp(log_c - tau * x), dim))) - level

    return float(np.exp(scipy.optimize.brentq(gap, np.log(base), np.log(base) + 10 * tau + 1,
                                              maxiter=200)))
