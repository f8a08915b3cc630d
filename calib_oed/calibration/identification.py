r"""Weighted nonlinear least-squares identification of the calibration parameters.

From observation blocks (configurations :math:`q`, measured values
:math:`\eta`, standard deviations :math:`\sigma`), :func:`identify` estimates
the free parameters :math:`p_f` (paper eq. 5–6), the fixed ones held at
:math:`p_0`:

.. math::
    \hat p_f = \arg\min_{p_f}\ \tfrac12 \lVert r(p)\rVert^2,
    \qquad r(p) = \Sigma^{-1}\big(h(p, q) - \eta\big) \in \mathbb{R}^m.

:math:`r` is the paper's :math:`-f_1`. Outliers are the business of
:mod:`calib_oed.calibration.robust` (judged against noise + model error), not of a
robust loss here: a robust loss mistakes the model error of a real arm for outliers. Rows: block order, then
configuration, then component. The Jacobian is analytic,
:math:`\partial r/\partial p_f = \Sigma^{-1}\,\partial h/\partial p_f = F_1[:, f]`
(the measurement models' ``compute_param_jacobian``). Solver:
``scipy.optimize.least_squares``. How to read the result: ``docs/identification.md``.

Every block is whitened per measurement by its model's noise contract
(``model.noise_whitening``), :math:`r_i = L_i^{-1}(h_i - \eta_i)`: for
independent components :math:`L_i = \mathrm{diag}(\sigma_i)` (the block's
per-row sigmas), so :math:`r = \Sigma^{-1}(h - \eta)` as above. With a full
error model (:class:`~calib_oed.measurement.noise.TrackerNoise`: tracker and
repeatability) :math:`\Sigma_i = L_i L_i^\top` is evaluated at the positions
:math:`h(\hat p, q_i)` predicted by the CURRENT ESTIMATE.
:math:`L_i` is frozen during one solve (so the Jacobian
:math:`L_i^{-1}\partial h_i/\partial p_f` is exact for the solved cost); it is
evaluated at the start :math:`p_0`, and after the solve re-evaluated at
:math:`\hat p` and solved once more from :math:`\hat p` (a fixed point; the
second solve moves the estimate by a tiny fraction of its standard deviation,
since :math:`\Sigma_i` changes by :math:`O(\lVert\Delta h\rVert/d)`).
Models without a full error model need no second solve.

This module owns the estimator: the residual :math:`r` and its Jacobian
(:func:`residual_function`), the options and :func:`identify`. The record it
returns, :class:`IdentificationResult` with :class:`IdentificationStatus`,
:class:`Outlier` and :class:`ParameterEstimate`, lives in
:mod:`calib_oed.calibration.identification_result` and is re-exported here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
import scipy.optimize

from calib_oed.calibration.covariance import information_cholesky, parameter_covariance
from calib_oed.calibration.gain_gauge import gains_the_data_fix
from calib_oed.calibration.identification_result import (
    IdentificationResult,
    IdentificationStatus,
    Outlier,
    ParameterEstimate,
)
from calib_oed.exceptions import NotIdentifiableError, ParameterError
from calib_oed.measurement import evaluate_setup
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.model.identifiability import IdentifiabilityReport
from calib_oed.model.parameters import ANGLE_SCALE, LENGTH_SCALE, ParameterSpace
from calib_oed.values import readonly

__all__ = [
    "METHODS",
    "IdentificationResult",
    "IdentificationStatus",
    "Outlier",
    "ParameterEstimate",
    "ResidualFunction",
    "identify",
    "residual_function",
]

#: Solvers of ``scipy.optimize.least_squares``.
METHODS = ("lm", "trf")


class ResidualFunction(NamedTuple):
    """Weighted residual :math:`r(p_f)` (m,) and its Jacobian (m, n_f), of the free vector."""

    fun: Callable[[np.ndarray], np.ndarray]
    jac: Callable[[np.ndarray], np.ndarray]


# --------------------------------------------------------------------------- residuals
def _free_indices(space: ParameterSpace, free) -> np.ndarray:
    if isinstance(free, IdentifiabilityReport):
        if tuple(free.names) != tuple(space.names):
            raise ParameterError("the identifiability report is for a different parameter "
                                 f"space ({len(free.names)} parameters, this one has {space.size})")
        idx = [int(i) for i in free.free_indices]
    else:
        items = [free] if isinstance(free, (str, int, np.integer)) else list(free)
        idx = []
        for item in items:
            if isinstance(item, str):
                idx.append(space.index(item))
            elif isinstance(item, (int, np.integer)) and not isinstance(item, bool):
                if not 0 <= item < space.size:
                    raise ParameterError(f"free parameter index {item} out of range 0..{space.size - 1}")
                idx.append(int(item))
            else:
                raise ParameterError(f"free: expected an IdentifiabilityReport, parameter names "
                                     f"or indices, got {item!r}")
    if not idx:
        raise ParameterError("free: no free parameters to identify")
    if len(set(idx)) != len(idx):
        dup = sorted({space.names[i] for i in idx if idx.count(i) > 1})
        raise ParameterError(f"free: parameters given twice: {dup}")
    out = np.array(sorted(idx), dtype=int)
    out.setflags(write=False)
    return out


class _Residuals:
    """Evaluates r and dr/dp_f; kinematics once per distinct q and per x (last x cached)."""

    def __init__(self, space: ParameterSpace, blocks: Sequence[ObservationBlock],
                 free: np.ndarray, p0: np.ndarray):
        self.blocks = tuple(blocks)
        if not self.blocks:
            raise ValueError("identify: no observation blocks")
        for b in self.blocks:
            if not isinstance(b, ObservationBlock):
                raise TypeError(f"expected ObservationBlock, got {type(b).__name__}")
        self.space, self.free, self.p0 = space, free, p0
        self.groups: list[tuple[np.ndarray, list[int]]] = []
        for k, b in enumerate(self.blocks):
            q = space.robot.check_configurations(b.q, f"q of block {k} ({b.model.name})")
            for gq, members in self.groups:
                if gq.shape == q.shape and np.array_equal(gq, q):
                    members.append(k)
                    break
            else:
                self.groups.append((q, [k]))
        self.sigma = np.concatenate([b.sigma.ravel() for b in self.blocks])
        self.eta = np.concatenate([b.values.ravel() for b in self.blocks])
        sizes = np.cumsum([0] + [b.values.size for b in self.blocks])
        self.slices = [slice(a, z) for a, z in zip(sizes[:-1], sizes[1:], strict=True)]
        self._x: np.ndarray | None = None
        self._states: list | None = None
        self.chol: list[np.ndarray] = [np.empty(0)] * len(self.blocks)
        self.whiten: list[np.ndarray] = [np.empty(0)] * len(self.blocks)
        #: Whether some block's covariance depends on the position (the tracker error model).
        self.has_noise = any(b.model.noise is not None for b in self.blocks)
        self.freeze_noise(p0[free])

    def freeze_noise(self, x: np.ndarray) -> None:
        """Evaluate every block's :math:`L_i` and :math:`L_i^{-1}` (the models' noise contract)
        at the positions predicted by ``x`` and keep them."""
        for state, (_, members) in zip(self._states_at(x), self.groups, strict=True):
            for k in members:
                b = self.blocks[k]
                y = b.model.compute_values(state)
                self.chol[k] = b.model.noise_cholesky(y, b.sigma)
                self.whiten[k] = b.model.noise_whitening(y, b.sigma)

    def full(self, x: np.ndarray) -> np.ndarray:
        p = self.p0.copy()
        p[self.free] = x
        return p

    def _states_at(self, x: np.ndarray) -> list:
        x = np.asarray(x, dtype=float)
        if self._x is None or not np.array_equal(self._x, x):
            p = self.full(x)
            self._states = [evaluate_setup(self.space, p, q, regressor=True, jacobian=False)
                            for q, _ in self.groups]
            self._x = x.copy()
        return self._states

    def fun(self, x: np.ndarray) -> np.ndarray:
        h = np.empty_like(self.eta)
        for state, (_, members) in zip(self._states_at(x), self.groups, strict=True):
            for k in members:
                h[self.slices[k]] = self.blocks[k].model.compute_values(state).ravel()
        r = np.empty_like(h)
        for k, w in enumerate(self.whiten):
            e = (h - self.eta)[self.slices[k]].reshape(w.shape[:2])
            r[self.slices[k]] = np.einsum("nij,nj->ni", w, e).ravel()
        return r

    def jac(self, x: np.ndarray) -> np.ndarray:
        out = np.empty((self.eta.size, self.free.size))
        for state, (_, members) in zip(self._states_at(x), self.groups, strict=True):
            for k in members:
                b = self.blocks[k]
                dh = b.model.compute_param_jacobian(state)[:, :, self.free]
                dh = np.einsum("nij,njk->nik", self.whiten[k], dh)
                out[self.slices[k]] = dh.reshape(-1, self.free.size)
        return out


def residual_function(space: ParameterSpace, blocks: Sequence[ObservationBlock], free,
                      p0: np.ndarray | None = None) -> ResidualFunction:
    r"""The weighted residual :math:`r = \Sigma^{-1}(h - \eta)` and its Jacobian as functions of :math:`p_f`.

    Args:
        space: Parameter layout.
        blocks: The measured data.
        free: An :class:`~calib_oed.model.identifiability.IdentifiabilityReport`, or
            parameter names or indices; taken in the declared parameter order.
        p0: Values of the fixed parameters (SI); nominal (zeros) by default.
    """
    free_idx = _free_indices(space, free)
    res = _Residuals(space, blocks, free_idx, space.check(p0, "p0").copy())
    return ResidualFunction(res.fun, res.jac)


# --------------------------------------------------------------------------- identify
def _check_options(method, max_nfev, correlation_threshold, outlier_threshold):
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}; valid methods are: {', '.join(METHODS)}")
    if max_nfev is not None and int(max_nfev) < 1:
        raise ParameterError(f"max_nfev must be >= 1 or None, got {max_nfev}")
    if not 0 < correlation_threshold <= 1:
        raise ParameterError(f"correlation_threshold must be in (0, 1], got {correlation_threshold}")
    if not outlier_threshold > 0:
        raise ParameterError(f"outlier_threshold must be positive [sigma], got {outlier_threshold}")


def _status(code: int) -> IdentificationStatus:
    if code > 0:
        return IdentificationStatus.CONVERGED
    return IdentificationStatus.MAX_ITERATIONS if code == 0 else IdentificationStatus.FAILED


def _uncertainty(a: np.ndarray, scale: np.ndarray, names) -> tuple[np.ndarray, float, str]:
    """:math:`C_p` (SI) and the condition number from :math:`A = F_1 D`; NaN and a note if singular."""
    try:
        cov = parameter_covariance(a, names) * np.outer(scale, scale)
    except NotIdentifiableError as exc:  # singular at the estimate: report, do not raise
        return np.full((a.shape[1],) * 2, np.nan), float("inf"), str(exc)
    sv = np.linalg.svd(a, compute_uv=False)
    return cov, float(sv[0] / sv[-1]), ""


def _correlations(cov: np.ndarray, names, threshold: float):
    std = np.sqrt(np.diag(cov))
    corr = cov / np.outer(std, std)
    corr = (corr + corr.T) / 2
    np.fill_diagonal(corr, 1.0)
    n = len(names)
    strong = sorted(
        ((names[i], names[j], float(corr[i, j]))
         for i in range(n) for j in range(i + 1, n) if abs(corr[i, j]) > threshold),
        key=lambda t: -abs(t[2]),
    )
    return corr, tuple(strong)


def _block_diagnostics(res: _Residuals, r: np.ndarray, threshold: float):
    """Per block: raw residuals, position [mm] and rotation [mrad] norms, row norms [sigma], outliers."""
    raw, pos_mm, ang_mrad, norms, outliers = [], [], [], [], []
    for k, b in enumerate(res.blocks):
        rk = r[res.slices[k]].reshape(b.values.shape)
        raw.append(readonly(np.einsum("nij,nj->ni", res.chol[k], rk)))
        units = np.array(b.model.units)
        pos_mm.append(readonly(np.linalg.norm(raw[-1][:, units == "m"], axis=1) / LENGTH_SCALE))
        ang_mrad.append(
            readonly(np.linalg.norm(raw[-1][:, units == "rad"], axis=1) / ANGLE_SCALE)
            if np.any(units == "rad") else None
        )
        norms.append(readonly(np.linalg.norm(rk, axis=1) / np.sqrt(b.model.dim)))
        outliers += [Outlier(k, int(i), float(norms[-1][i]))
                     for i in np.flatnonzero(norms[-1] > threshold)]
    return tuple(raw), tuple(pos_mm), tuple(ang_mrad), tuple(norms), tuple(outliers)


def identify(
    space: ParameterSpace,
    blocks: Sequence[ObservationBlock],
    free,
    *,
    p0: np.ndarray | None = None,
    method: str = "lm",
    max_nfev: int | None = None,
    xtol: float = 1e-10,
    ftol: float = 1e-10,
    gtol: float = 1e-10,
    correlation_threshold: float = 0.9,
    outlier_threshold: float = 3.0,
) -> IdentificationResult:
    """Estimate the free parameters from measured data (weighted nonlinear least squares).

    Args:
        space: Parameter layout.
        blocks: Measured data; blocks with equal ``q`` share one kinematics pass.
        free: An :class:`~calib_oed.model.identifiability.IdentifiabilityReport`
            (its free parameters), or parameter names or indices.
        p0: Start and value of the fixed parameters (SI); nominal by default. Joint gains
            and coupling ratios the data cannot separate are held at it too, and named in
            ``message`` (:mod:`calib_oed.calibration.gain_gauge`).
        method: ``"lm"`` (default) or ``"trf"``.
        max_nfev: Maximum residual evaluations (scipy's default ``100 n_f`` if None).
        xtol, ftol, gtol: scipy's stopping tolerances.
        correlation_threshold: ``|rho|`` above which a pair is reported.
        outlier_threshold: Measurements with :math:`\\lVert r\\rVert/\\sqrt d`
            above this [sigma] are reported as outliers.

    Raises:
        NotIdentifiableError: :math:`F_1` at ``p0`` is rank-deficient on the free
            parameters, or the data have fewer values than free parameters.
        ParameterError: bad ``free``, ``method`` or thresholds.

    Not converging within ``max_nfev`` is reported in ``status``, not raised.
    """
    _check_options(method, max_nfev, correlation_threshold, outlier_threshold)
    free_idx = _free_indices(space, free)
    res = _Residuals(space, blocks, free_idx, space.check(p0, "p0").copy())
    unseen = [] if space.joint_gains is None else gains_the_data_fix(
        space, res.jac(res.p0[free_idx]) * space.unit_scale[free_idx], free_idx)
    if unseen:  # gains the data cannot separate are held at nominal (calibration/gain_gauge.py)
        drop = {space.index(f.name) for f in unseen}
        free_idx = np.array([i for i in free_idx if i not in drop], dtype=int)
        free_idx.setflags(write=False)
        res = _Residuals(space, blocks, free_idx, res.p0)
    free_names = tuple(space.names[i] for i in free_idx)
    scale = space.unit_scale[free_idx]
    x0 = res.p0[free_idx]
    information_cholesky(res.jac(x0) * scale, free_names)  # raises NotIdentifiableError
    sol = scipy.optimize.least_squares(
        res.fun, x0, jac=res.jac, method=method, x_scale="jac",
        xtol=xtol, ftol=ftol, gtol=gtol, max_nfev=max_nfev,
    )
    if res.has_noise:  # Sigma_i at the estimate, then one more solve (module docstring)
        nfev, njev = sol.nfev, sol.njev
        res.freeze_noise(np.asarray(sol.x, dtype=float))
        sol = scipy.optimize.least_squares(
            res.fun, sol.x, jac=res.jac, method=method, x_scale="jac", xtol=xtol, ftol=ftol, gtol=gtol, max_nfev=max_nfev,
        )
        sol.nfev += nfev
        sol.njev = None if sol.njev is None or njev is None else sol.njev + njev
    x = np.asarray(sol.x, dtype=float)
    r, f1 = res.fun(x), res.jac(x)
    message = str(sol.message) + "".join(
        f"; {f.name} held at nominal, the data cannot separate it: {f.reason}" for f in unseen)
    cov, cond, note = _uncertainty(f1 * scale, scale, free_names)
    if note:
        message += f" (covariance not available: {note})"
    corr, strong = _correlations(cov, free_names, correlation_threshold)
    raw, pos_mm, ang_mrad, norms, outliers = _block_diagnostics(res, r, outlier_threshold)
    all_mm = np.concatenate(pos_mm)
    angles = [v for v in ang_mrad if v is not None]
    all_mrad = np.concatenate(angles) if angles else None
    dof = r.size - free_idx.size
    return IdentificationResult(
        names=tuple(space.names),
        free_names=free_names,
        free_indices=free_idx,
        parameter_units=tuple(p.unit for p in space.parameters),
        p=readonly(res.full(x)),
        status=_status(int(sol.status)),
        message=message,
        nfev=int(sol.nfev),
        njev=None if sol.njev is None else int(sol.njev),
        method=method,
        cost=float(sol.cost),
        residuals=readonly(r),
        block_names=tuple(b.model.name for b in res.blocks),
        block_residuals=raw,
        point_residuals_mm=pos_mm,
        angle_residuals_mrad=ang_mrad,
        measurement_norms=norms,
        rms_mm=float(np.sqrt(np.mean(all_mm**2))) if all_mm.size else None,
        max_mm=float(all_mm.max()) if all_mm.size else None,
        rms_mrad=None if all_mrad is None else float(np.sqrt(np.mean(all_mrad**2))),
        max_mrad=None if all_mrad is None else float(all_mrad.max()),
        dof=int(dof),
        noise_factor=float(r @ r / dof) if dof > 0 else float("nan"),
        covariance=readonly(cov),
        correlation=readonly(corr),
        strong_correlations=strong,
        correlation_threshold=float(correlation_threshold),
        condition_number=cond,
        outliers=outliers,
        outlier_threshold=float(outlier_threshold),
        f1=readonly(f1),
    )
