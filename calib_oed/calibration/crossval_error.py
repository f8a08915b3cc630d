r"""How far cross-validation can be from the error on new poses when the model error is smooth.

Cross-validation's held-out errors are not independent under a model error that
is a smooth function of the configuration: neighbouring poses err together, and
the error on a separate validation set shares the same function. The
independent-poses standard error of :mod:`calib_oed.calibration.crossval` then
understates how far CV's RMS can be from the RMS on new poses. With the fitted
model error (:class:`~calib_oed.measurement.discrepancy.DiscrepancyPrior`) both
are quadratic forms of one Gaussian vector, and their difference has a closed
form.

Linearised at the full-data estimate (:class:`~calib_oed.calibration.model_error.Linearisation`:
:math:`J`, noise :math:`N`, :math:`z = \delta + \varepsilon` with covariance
:math:`\Sigma = K + N`), fold :math:`f` fits the weighted least squares
:math:`A_f = (J_T^\top N_T^{-1}J_T)^{-1}J_T^\top N_T^{-1}` on its training values
:math:`T` and leaves on its held-out values :math:`H`

.. math::
    e_H = z_H - J_H A_f z_T,

so the held-out errors are :math:`e = Lz`. The full-data calibration
(:math:`A`) leaves at new points (:math:`n_\ast` configurations uniform in the
training joint ranges, every reflector, :math:`u_\ast = \delta_\ast + \varepsilon_\ast`)
:math:`e_\ast = u_\ast - G_\ast A z`. With :math:`y = (e, e_\ast) = M(z, u_\ast)`,
:math:`S_y = M\,\mathrm{Cov}(z, u_\ast)\,M^\top` and
:math:`Q = \mathrm{diag}(W/n, -I/n_\ast')` (:math:`W` selecting position values,
:math:`n` the CV rows, :math:`n_\ast'` the new points), the difference of the mean
squared errors :math:`D = \mathrm{MS}_{cv} - \mathrm{MS}_\ast = y^\top Q y` has

.. math::
    \mathrm{E}\,D = \mathrm{tr}(QS_y), \qquad \mathrm{Var}\,D = 2\,\mathrm{tr}(QS_yQS_y)
    \quad [\mathrm{m}^4]

(a Gaussian quadratic form). Its standard deviation over :math:`2\,\mathrm{RMS}_{cv}`
(delta method) is CV's standard error as a prediction of the RMS on new poses,
and :math:`\mathrm{E}\,D` its expected optimism or pessimism (the folds train on
fewer poses). Checked against a seeded Monte Carlo of Gaussian-process model
errors in ``tests/calibration/test_crossval_error.py``.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from calib_oed.calibration.model_error import Linearisation
from calib_oed.calibration.prediction import new_poses
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior

#: New configurations of the comparison (uniform in the training joint ranges) and their seed.
N_NEW, NEW_SEED = 100, 0


def _wls(jac: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """:math:`(J^\\top N^{-1}J)^{-1}J^\\top N^{-1}` (n_f, m)."""
    wj = scipy.linalg.cho_solve(scipy.linalg.cho_factor(noise, lower=True), jac)
    return np.linalg.solve(jac.T @ wj, wj.T)


def held_out_map(lin: Linearisation, fold: np.ndarray) -> np.ndarray:
    """:math:`L` (m, m): the held-out errors of every value given :math:`z` (module docstring);
    ``fold`` the fold of every value of ``lin``, (m,)."""
    out = np.zeros((lin.m, lin.m))
    for f in np.unique(fold):
        hold, train = np.flatnonzero(fold == f), np.flatnonzero(fold != f)
        a = _wls(lin.jac[train], lin.noise[np.ix_(train, train)])
        out[np.ix_(hold, hold)] = np.eye(hold.size)
        out[np.ix_(hold, train)] = -lin.jac[hold] @ a
    return out


def cv_difference(lin: Linearisation, prior: DiscrepancyPrior, fold: np.ndarray, space, p: np.ndarray,
                  free: np.ndarray, models, n_new: int = N_NEW, seed: int = NEW_SEED
                  ) -> tuple[float, float]:
    r""":math:`(\mathrm{E}\,D, \sqrt{\mathrm{Var}\,D})` [m²] of CV's mean squared position error
    minus that of the full calibration (``p``, free indices ``free``) on new poses measured by
    ``models`` (module docstring)."""
    m_map, cov, q_diag = quadratic_form(lin, prior, fold, space, p, free, models, n_new, seed)
    s_y = m_map @ cov @ m_map.T
    qs = q_diag[:, None] * s_y
    return float(np.trace(qs)), float(np.sqrt(2.0 * np.sum(qs * qs.T)))


def quadratic_form(lin: Linearisation, prior: DiscrepancyPrior, fold: np.ndarray, space, p: np.ndarray,
                   free: np.ndarray, models, n_new: int = N_NEW, seed: int = NEW_SEED
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r""":math:`M`, :math:`\mathrm{Cov}(z, u_\ast)` and the diagonal of :math:`Q` of
    :func:`cv_difference` (module docstring): :math:`D = w^\top M^\top QMw`, :math:`w \sim
    N(0, \mathrm{Cov})`."""
    q_new = new_poses(np.unique(lin.q, axis=0), n_new, seed)
    state = evaluate_setup(space, p, q_new, regressor=True, jacobian=False)
    g, noise_new = [], []
    for mdl in models:
        h = mdl.compute_values(state)
        g.append(mdl.compute_param_jacobian(state)[:, :3][:, :, free].reshape(-1, free.size))
        noise_new.append(mdl.noise_covariance(h)[:, :3, :3])
    r = len(models)
    n_star = 3 * n_new * r
    # Cov(u*): the model error shared by every reflector at a configuration, noise per point
    k_new = np.kron(np.ones((r, r)), np.kron(prior.covariance_kernel(q_new, q_new), np.eye(3)))
    cov_u = k_new + scipy.linalg.block_diag(*[c for block in noise_new for c in block])
    k_cross = prior.covariance_kernel(lin.q, q_new)  # (m, n_new)
    cross = np.zeros((lin.m, 3 * n_new))
    for c in range(3):
        cross[:, c::3] = np.where((lin.position & (lin.component == c))[:, None], k_cross, 0.0)
    cov = np.block([[lin.covariance(prior), np.tile(cross, (1, r))],
                    [np.tile(cross, (1, r)).T, cov_u]])
    m_map = np.zeros((lin.m + n_star, lin.m + n_star))
    m_map[:lin.m, :lin.m] = held_out_map(lin, _fold_of_values(fold, lin))
    m_map[lin.m:, :lin.m] = -np.vstack(g) @ _wls(lin.jac, lin.noise)
    m_map[lin.m:, lin.m:] = np.eye(n_star)
    n_rows = int(lin.position.sum()) // 3
    return m_map, cov, np.r_[lin.position / n_rows, -np.ones(n_star) / (n_star // 3)]


def _fold_of_values(fold: np.ndarray, lin: Linearisation) -> np.ndarray:
    """``fold`` given per value already (m,), or per measurement (M,): per value."""
    fold = np.asarray(fold, dtype=int)
    return fold if fold.size == lin.m else fold[lin.measurement]
