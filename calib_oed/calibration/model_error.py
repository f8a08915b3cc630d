r"""The model error left after an identification: its hyperparameters, and residuals judged against it.

The identification (:mod:`calib_oed.calibration.identification`) fits
:math:`\hat p` by weighted least squares on the noise. Linearised at
:math:`\hat p`, with :math:`J = \partial h/\partial p_f` (m, n_f) [m per unit],
the measured values are

.. math::
    \eta = h(p^\star) + \delta + \varepsilon, \qquad
    \delta \sim N(0, K), \quad \varepsilon \sim N(0, N), \qquad \Sigma = K + N,

:math:`K` the model-error covariance of
:class:`~calib_oed.measurement.discrepancy.DiscrepancyPrior` over the rows'
configurations and :math:`N` the noise (:mod:`calib_oed.measurement.error_model`).

**Hyperparameters by restricted marginal likelihood** (:func:`fit_model_error`).
The parameters are unknown, so the likelihood of the hyperparameters
:math:`\theta = (\log\sigma, \log\ell_j)` is the restricted one (REML,
Patterson & Thompson 1971; Rasmussen & Williams 2006 §2.7), which integrates
:math:`p` out under a flat prior and so accounts for the part of the model
error the fit absorbed:

.. math::
    \log L(\theta) = -\tfrac12\, e^\top P e - \tfrac12\log|\Sigma|
      - \tfrac12\log|J^\top\Sigma^{-1}J| + \mathrm{const},\qquad
    P = \Sigma^{-1} - \Sigma^{-1}J(J^\top\Sigma^{-1}J)^{-1}J^\top\Sigma^{-1},

:math:`e = \eta - h(\hat p)` the fit's residual (:math:`Pe` does not depend on
which :math:`p` the residual is taken at, since :math:`PJ = 0`), with the
gradient :math:`\partial\log L/\partial\theta_k = \tfrac12\alpha^\top
\Sigma_k\alpha - \tfrac12\mathrm{tr}(P\Sigma_k)`, :math:`\alpha = Pe`,
:math:`\Sigma_k = \partial\Sigma/\partial\theta_k`
(``DiscrepancyPrior.kernel_log_gradient``), maximised by L-BFGS-B from several
starts. Why not scikit-learn's ``GaussianProcessRegressor``: its likelihood
is the plain one of the residuals (no parametric part, so it underestimates the
model error the fit absorbed), its noise is a diagonal per value (the tracker's
3x3 covariances are not), and it cannot share one process between the three
components and several reflectors.

**The kernel identify fits** (:func:`start_prior`): the scene's ``robot.model_error``
as given, else the design-time default for the robot's reach in the kernel
:data:`IDENTIFY_KERNEL`, the Matérn 5/2 with each joint's own error once and twice
per revolution beside it. Measured on the realistic simulator, 6 truths x 2 robots
(``bench/bench_trust.py``, ``docs/benchmarks.md``): the rows flagged on a UR5 where its
joint-side transmission errors peak (3.3 %) within the 2 % target (1.7 %), 4 flagged rows
of 720 instead of 6, the other figures unchanged. The plain kernel is nested in it, so its
likelihood is never lower; the gain (0.8-5.5) is no larger than on GP truths of the plain
kernel and does not by itself justify the 12 extra hyperparameters. Its size follows the pose
(:data:`POSE_SCALED`, ``measurement/pose_scale.py``): the kernel times the joint-space prior's
standard deviation at each pose over its training mean, blended with 1 by a fitted weight
(:math:`\log\beta` one more hyperparameter); on the realistic simulator the TCP prediction by
tercile of the prior's variance went from 1.26/1.08/0.87 (fms_kr16) and 1.57/1.21/0.77 (ur5_table)
to 0.92/1.03/1.19 and 0.94/1.03/1.02, the weight fitted at 0.87-1.00.

**Residuals against noise + model error** (:func:`leave_one_out`). The
leave-one-measurement-out residual of measurement :math:`i` (its :math:`d`
values), the parameters and the model error re-estimated from all others, is
:math:`(P_{ii})^{-1}(Pe)_i` with covariance :math:`(P_{ii})^{-1}` (the GLS
leave-one-out identity), so
:math:`t_i = (Pe)_i^\top (P_{ii})^{-1} (Pe)_i \sim \chi^2_d` under the model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.linalg
import scipy.optimize

from calib_oed.calibration.joint_prior_choice import pose_scale
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.error_model import block_noise, row_layout
from calib_oed.model.parameters import ParameterSpace

#: Bounds of the fitted hyperparameters: sigma [m], length scales [rad].
SIGMA_BOUNDS = (1e-7, 1e-1)
LENGTH_BOUNDS = (np.radians(3.0), np.radians(3600.0))
#: Bounds of the fitted white part [m].
WHITE_BOUNDS = (1e-8, 1e-2)
#: Bounds of the fitted harmonic amplitudes of a harmonic kernel [m].
HARMONIC_BOUNDS = (1e-8, 1e-2)
#: Bounds of the fitted weight of a pose scale (``measurement/pose_scale.py``) [1].
WEIGHT_BOUNDS = (1e-3, 1.0)
#: The kernel identify fits when the scene gives no model-error prior (module docstring).
IDENTIFY_KERNEL = "matern52_harmonic"
#: Whether identify's model error follows the joint prior's shape pose by pose (module docstring).
POSE_SCALED = True


def start_prior(scene, problem=None, scaled: bool = POSE_SCALED) -> DiscrepancyPrior:
    """The prior ``identify`` starts its model-error fit from (module docstring): the scene's
    ``robot.model_error``, else the default for the robot in :data:`IDENTIFY_KERNEL`; with
    ``problem`` and ``scaled``, times the pose scale of the scene's joint prior
    (:func:`~calib_oed.calibration.joint_prior_choice.pose_scale`)."""
    prior = scene.model_error if scene.model_error is not None \
        else DiscrepancyPrior.default_for(scene.robot, IDENTIFY_KERNEL)
    if problem is None or not scaled:
        return prior
    return prior.with_scale(pose_scale(problem, getattr(scene, "joint_error", None)))


@dataclass(frozen=True, eq=False)
class Linearisation:
    r"""An identification linearised at its estimate (module docstring), rows in block order.

    Attributes:
        q: Configuration of every value, (m, nq).
        position: Whether each value is a position component, (m,).
        component: Component index of each value in its measurement, (m,).
        measurement: Measurement number of each value (block, then row), (m,).
        jac: :math:`J = \partial h/\partial p_f` at :math:`\hat p`, (m, n_f) [m per unit].
        noise: :math:`N`, (m, m) [SI²], at the positions predicted by :math:`\hat p`.
        residual: :math:`e = \eta - h(\hat p)`, (m,) [SI].
    """

    q: np.ndarray = field(repr=False)
    position: np.ndarray = field(repr=False)
    component: np.ndarray = field(repr=False)
    measurement: np.ndarray = field(repr=False)
    jac: np.ndarray = field(repr=False)
    noise: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)

    @property
    def m(self) -> int:
        return self.residual.size

    @cached_property
    def _configs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Distinct configurations (P, nq), each value's index into them (m,), and the mask of
        value pairs the model error couples (same position component), (m, m)."""
        configs, index = np.unique(self.q, axis=0, return_inverse=True)
        same = (self.component[:, None] == self.component[None, :]) \
            & self.position[:, None] & self.position[None, :]
        return configs, index.ravel(), same

    @cached_property
    def _gather(self) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices of the coupled value pairs in (m, m) and of their configurations in (P, P)."""
        configs, index, same = self._configs
        a, b = np.nonzero(same)
        return a * self.m + b, index[a] * configs.shape[0] + index[b]

    def expand(self, per_config: np.ndarray) -> np.ndarray:
        """A (P, P) matrix over the distinct configurations as the (m, m) model-error part."""
        target, source = self._gather
        out = np.zeros(self.m * self.m)
        out[target] = per_config.ravel()[source]
        return out.reshape(self.m, self.m)

    @cached_property
    def selectors(self) -> np.ndarray:
        """:math:`E_c` (3, m, P): value a is position component c at distinct configuration u."""
        _, index, _ = self._configs
        out = np.zeros((3, self.m, int(index.max()) + 1))
        rows = np.flatnonzero(self.position)
        out[self.component[rows], rows, index[rows]] = 1.0
        return out

    def subset(self, keep: np.ndarray) -> Linearisation:
        """The values of the measurements ``keep`` (bool per measurement)."""
        rows = keep[self.measurement]
        return Linearisation(self.q[rows], self.position[rows], self.component[rows],
                             np.unique(self.measurement[rows], return_inverse=True)[1].ravel(),
                             self.jac[rows], self.noise[np.ix_(rows, rows)], self.residual[rows])

    def to_dict(self) -> dict:
        """JSON form (SI): distinct configurations, per value its configuration index, kind and
        row of :math:`J`, per measurement its noise block; :meth:`from_dict` inverts it."""
        configs, index, _ = self._configs
        noise = [self.noise[np.ix_(r, r)].tolist() for r in
                 (np.flatnonzero(self.measurement == i) for i in range(int(self.measurement.max()) + 1))]
        return {"configurations_rad": configs.tolist(), "configuration": index.tolist(),
                "position": self.position.astype(int).tolist(), "component": self.component.tolist(),
                "measurement": self.measurement.tolist(), "jacobian": self.jac.tolist(),
                "residual": self.residual.tolist(), "noise": noise}

    @classmethod
    def from_dict(cls, data) -> Linearisation:
        """From :meth:`to_dict`'s form (``KeyError``, ``ValueError`` or ``IndexError`` when malformed)."""
        configs = np.array(data["configurations_rad"], float)
        measurement = np.array(data["measurement"], int)
        noise = np.zeros((measurement.size, measurement.size))
        for i, block in enumerate(data["noise"]):
            rows = np.flatnonzero(measurement == i)
            noise[np.ix_(rows, rows)] = np.array(block, float)
        jac = np.array(data["jacobian"], float).reshape(measurement.size, -1)
        return cls(configs[np.array(data["configuration"], int)], np.array(data["position"], bool),
                   np.array(data["component"], int), measurement, jac, noise,
                   np.array(data["residual"], float))

    def covariance(self, prior: DiscrepancyPrior | None) -> np.ndarray:
        r""":math:`\Sigma = K + N` (m, m) [SI²]."""
        if prior is None:
            return self.noise
        configs = self._configs[0]
        return self.noise + self.expand(prior.covariance_kernel(configs, configs))


def linearise(space: ParameterSpace, blocks: Sequence, p: np.ndarray, free: np.ndarray) -> Linearisation:
    """The :class:`Linearisation` of the data ``blocks`` at the estimate ``p`` (free indices ``free``)."""
    jac, res, predicted = [], [], []
    for b in blocks:
        state = evaluate_setup(space, p, b.q, regressor=True, jacobian=False)
        h = b.model.compute_values(state)
        predicted.append(h)
        jac.append(b.model.compute_param_jacobian(state)[:, :, free].reshape(-1, len(free)))
        res.append((b.values - h).ravel())
    q, position, comp = row_layout(blocks)
    meas = np.repeat(np.arange(sum(b.n for b in blocks)), [b.model.dim for b in blocks
                                                            for _ in range(b.n)])
    return Linearisation(q, position, comp, meas, np.vstack(jac), block_noise(blocks, predicted),
                         np.concatenate(res))


class _Restricted:
    r"""Factors of the restricted likelihood at one prior (module docstring): with
    :math:`\Sigma = LL^\top`, :math:`W = L^{-1}[J, e, E_0, E_1, E_2]` holds all it needs."""

    def __init__(self, lin: Linearisation, prior: DiscrepancyPrior | None):
        self.lin = lin
        self.chol = scipy.linalg.cholesky(lin.covariance(prior), lower=True, check_finite=False)
        n_f = lin.jac.shape[1]
        sel = lin.selectors
        rhs = np.hstack([lin.jac, lin.residual[:, None], *sel])
        w = scipy.linalg.solve_triangular(self.chol, rhs, lower=True, check_finite=False)
        self.w_j, self.w_e = w[:, :n_f], w[:, n_f]
        self.w_sel = [w[:, n_f + 1 + k * sel.shape[2]: n_f + 1 + (k + 1) * sel.shape[2]]
                      for k in range(3)]
        self.info_chol = scipy.linalg.cho_factor(self.w_j.T @ self.w_j, lower=True)
        self.proj_e = self.w_e - self.w_j @ scipy.linalg.cho_solve(self.info_chol, self.w_j.T @ self.w_e)

    def log_likelihood(self) -> float:
        lin = self.lin
        logdet = 2 * np.log(np.diag(self.chol)).sum() + 2 * np.log(np.diag(self.info_chol[0])).sum()
        return float(-0.5 * self.w_e @ self.proj_e - 0.5 * logdet
                     - 0.5 * (lin.m - lin.jac.shape[1]) * np.log(2 * np.pi))

    def gradient_weight(self) -> np.ndarray:
        r""":math:`\tfrac12(\bar a\bar a^\top - \sum_c E_c^\top P E_c)` (P, P): the gradient is
        its sum against :math:`\partial K/\partial\theta_k` over the distinct configurations."""
        a = np.stack([ws.T @ self.proj_e for ws in self.w_sel], axis=1)  # E_c^T alpha, (P, 3)
        contracted = 0.0
        for ws in self.w_sel:
            cross = self.w_j.T @ ws
            contracted = contracted + ws.T @ ws - cross.T @ scipy.linalg.cho_solve(self.info_chol, cross)
        return 0.5 * (a @ a.T - contracted)

    @cached_property
    def alpha(self) -> np.ndarray:
        """:math:`Pe`, (m,)."""
        return scipy.linalg.solve_triangular(self.chol, self.proj_e, lower=True, trans="T")

    @cached_property
    def p(self) -> np.ndarray:
        """:math:`P` (m, m)."""
        l_inv = scipy.linalg.solve_triangular(self.chol, np.eye(self.lin.m), lower=True)
        g = l_inv.T @ self.w_j  # Sigma^-1 J
        return l_inv.T @ l_inv - g @ scipy.linalg.cho_solve(self.info_chol, g.T)


def restricted_log_likelihood(lin: Linearisation, prior: DiscrepancyPrior | None,
                              gradient: bool = False):
    r""":math:`\log L` of ``prior`` (module docstring); with ``gradient``, also
    :math:`\partial\log L/\partial(\log\sigma, \log\ell_1..\log\ell_{nq}, [\log s_{kh}], \log\sigma_w)`
    (``prior.n_kernel_hyperparameters`` + 1,; the amplitudes :math:`s_{kh}` of a harmonic kernel)."""
    fac = _Restricted(lin, prior)
    value = fac.log_likelihood()
    if not gradient:
        return value
    configs = lin._configs[0]
    dk = prior.kernel_log_gradient(configs, configs)
    weight = fac.gradient_weight()
    white = 2 * prior.sigma_white**2 * np.trace(weight)  # d(sigma_w^2 I)/d log sigma_w
    return value, np.r_[np.einsum("uvk,uv->k", dk, weight), white]


@dataclass(frozen=True)
class ModelErrorFit:
    """Hyperparameters by restricted marginal likelihood.

    Attributes:
        prior: The fitted model-error prior (``source`` ``"fit"``).
        log_likelihood: Its restricted log-likelihood.
        noise_only_log_likelihood: That of the exact model (no model error), for comparison.
        start: The prior the fit started from (the scene's or the default).
        converged: Whether the optimiser converged.
    """

    prior: DiscrepancyPrior
    log_likelihood: float
    noise_only_log_likelihood: float
    start: DiscrepancyPrior
    converged: bool

    def to_dict(self) -> dict:
        return {"fitted": self.prior.to_dict(), "start": self.start.to_dict(),
                "restricted_log_likelihood": self.log_likelihood,
                "noise_only_log_likelihood": self.noise_only_log_likelihood,
                "converged": self.converged}


def fit_model_error(lin: Linearisation, start: DiscrepancyPrior, *, max_iterations: int = 200
                    ) -> ModelErrorFit:
    """Maximise the restricted likelihood over sigma, the finite length scales of ``start``,
    the harmonic amplitudes (harmonic kernels) and the white part.

    Joints ``start`` ignores (length scale inf) stay ignored. Starts: ``start``
    itself (its white part at least a fifth of its sigma, each harmonic amplitude at least
    a tenth, a pose scale's weight at least a half), and the same with sigma from the
    residuals' RMS per axis. A pose scale is first normalised to the training configurations.
    """
    if start.scale is not None:
        start = start.with_scale(start.scale.normalised(lin._configs[0]))
    nq = start.nq
    scaled = [start.n_kernel_hyperparameters - 1] if start.scale is not None else []
    finite = [j for j, ell in enumerate(start.length_scales) if np.isfinite(ell)]
    harm = [i for i, on in enumerate(np.repeat(start.harmonic_joints, 2)) if on]
    lo = np.log([SIGMA_BOUNDS[0]] + [LENGTH_BOUNDS[0]] * len(finite)
                + [HARMONIC_BOUNDS[0]] * len(harm) + [WEIGHT_BOUNDS[0]] * len(scaled) + [WHITE_BOUNDS[0]])
    hi = np.log([SIGMA_BOUNDS[1]] + [LENGTH_BOUNDS[1]] * len(finite)
                + [HARMONIC_BOUNDS[1]] * len(harm) + [WEIGHT_BOUNDS[1]] * len(scaled) + [WHITE_BOUNDS[1]])
    pick = [0] + [1 + j for j in finite] + [1 + nq + i for i in harm] + scaled \
        + [start.n_kernel_hyperparameters]
    n_ell, n_amp = len(finite), len(harm)

    def prior_of(theta):
        ell = np.array(start.length_scales, dtype=float)
        ell[finite] = np.exp(theta[1:1 + n_ell])
        amp = np.array(start.harmonic, dtype=float)
        amp[harm] = np.exp(theta[1 + n_ell:1 + n_ell + n_amp])
        weight = float(min(np.exp(theta[-2]), 1.0)) if scaled else None
        return start.with_values(float(np.exp(theta[0])), ell, "fit", float(np.exp(theta[-1])), amp, weight)

    def objective(theta):
        value, grad = restricted_log_likelihood(lin, prior_of(theta), gradient=True)
        return -value, -grad[pick]

    rms = float(np.sqrt(np.mean(lin.residual[lin.position] ** 2))) if lin.position.any() else start.sigma
    sigma0 = max(start.sigma, SIGMA_BOUNDS[0])
    white0 = max(start.sigma_white, 0.2 * sigma0)
    amp0 = [max(start.harmonic[i], 0.1 * sigma0) for i in harm]
    weight0 = [max(start.scale.weight, 0.5)] if scaled else []
    first = np.log([sigma0] + [start.length_scales[j] for j in finite] + amp0 + weight0 + [white0])
    second = first.copy()
    second[0] = np.log(np.clip(rms, *SIGMA_BOUNDS))
    best = None
    for theta0 in (first, second):
        sol = scipy.optimize.minimize(objective, np.clip(theta0, lo, hi), jac=True, method="L-BFGS-B",
                                      bounds=list(zip(lo, hi, strict=True)),
                                      options={"maxiter": max_iterations, "ftol": 1e-8})
        if best is None or sol.fun < best.fun:
            best = sol
    prior = prior_of(best.x)
    return ModelErrorFit(prior, float(-best.fun), restricted_log_likelihood(lin, None), start,
                         bool(best.success))


def leave_one_out(lin: Linearisation, prior: DiscrepancyPrior | None) -> tuple[np.ndarray, np.ndarray]:
    r"""Per measurement: :math:`t_i = (Pe)_i^\top (P_{ii})^{-1}(Pe)_i` (~ :math:`\chi^2_{d_i}`
    under noise + model error, module docstring) and :math:`d_i`; each (M,)."""
    fac = _Restricted(lin, prior)
    n = int(lin.measurement.max()) + 1
    t, dim = np.empty(n), np.bincount(lin.measurement, minlength=n)
    for i in range(n):
        rows = np.flatnonzero(lin.measurement == i)
        a = fac.alpha[rows]
        t[i] = a @ np.linalg.solve(fac.p[np.ix_(rows, rows)], a)
    return t, dim


def estimate_covariance(lin: Linearisation, prior: DiscrepancyPrior | None) -> np.ndarray:
    r"""Covariance of the weighted least-squares estimate under noise + model error,
    :math:`A\Sigma A^\top`, :math:`A = (J^\top N^{-1}J)^{-1}J^\top N^{-1}` (n_f, n_f) [SI]."""
    noise_f = scipy.linalg.cho_factor(lin.noise, lower=True)
    wj = scipy.linalg.cho_solve(noise_f, lin.jac)
    a = np.linalg.solve(lin.jac.T @ wj, wj.T)
    return a @ lin.covariance(prior) @ a.T
