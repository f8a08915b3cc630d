r"""Predicted accuracy at any pose: parameter uncertainty + model error + noise.

With the identification linearised at :math:`\hat p`
(:class:`~calib_oed.calibration.model_error.Linearisation`: :math:`J`, noise
:math:`N`, :math:`\Sigma = K + N`), the weighted least-squares estimate is
:math:`\hat p - p^\star = A(\delta + \varepsilon)`,
:math:`A = (J^\top N^{-1}J)^{-1}J^\top N^{-1}`. A point at a new configuration
:math:`q_\ast` with Jacobian :math:`G_\ast = \partial y_\ast/\partial p_f`
(3, n_f) is predicted as :math:`\hat y_\ast = y_\ast(\hat p) + c\,\mu_\ast`,
:math:`\mu_\ast = C_\ast^\top\Sigma^{-1}e` the model error's conditional mean
(the optional compensation, :math:`c \in \{0, 1\}`), :math:`C_\ast` (m, 3) the
covariance of the training values' model error with the point's,
:math:`e = \eta - h(\hat p)` the residuals. Its error
:math:`y_\ast - \hat y_\ast = \delta_\ast + \varepsilon_\ast - B(\delta + \varepsilon)`,
:math:`B = G_\ast A + c\,C_\ast^\top\Sigma^{-1}(I - JA)`, is linear in the
Gaussian errors, so exactly (for the linearised model)

.. math::
    V_\ast = k(q_\ast, q_\ast)\,I_3 - BC_\ast - C_\ast^\top B^\top + B\Sigma B^\top + N_\ast
    \quad [\mathrm{m}^2],

:math:`N_\ast` the noise of a measured point (tracker and repeatability), or
the robot's repeatability alone for a TCP at a working configuration (no
tracker there). The TCP is predicted **in the tracker frame** (each model with its own tracker
placement): that is what the tracker data determine. In the world (robot base) frame a
calibrated model and the true robot differ by a rigid move no tracker data fix (the base
gauge, docs/conventions.md "Estimability of KPIs"): a real arm's unmodelled errors move it by
their part along the gauge directions (0.3-0.5 mm on ``ur5_table``'s realistic truths), which no
prediction can include. The new poses of the expected RMS are feasible poses in the training
joint ranges (:func:`feasible_new_poses`), where the calibrated robot will be used.
:math:`\sqrt{\mathrm{tr}\,V_\ast}` is the expected RMS of the
3-D error; the 95 % prediction region is :math:`e^\top V_\ast^{-1}e \le \chi^2_3(0.95)`.
With no model error (:math:`K = 0`) this is the noise-only :math:`G C_p G^\top + N_\ast`.
Checked against Monte Carlo of Gaussian-process model errors in
``tests/calibration/test_prediction.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.stats import chi2

from calib_oed.calibration.hyper_uncertainty import TAU_MAX, log_spread, region_threshold
from calib_oed.calibration.model_error import Linearisation
from calib_oed.calibration.world_frame import (
    TRACKER_COVERS,
    WORLD_COVERS,
    JointErrorModel,
    point_jacobians,
)
from calib_oed.exceptions import SamplingError
from calib_oed.feasibility.constraints import FeasibilityModel
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior

MM_PER_M = 1e3
#: New poses for the expected RMS: this many, feasible in the training joint ranges, this seed.
N_NEW_POSES, NEW_POSE_SEED = 200, 0
#: New poses (the first of them) for the derivative of the expected RMS in the hyperparameters.
N_SPREAD = 50


def _cross(lin: Linearisation, prior: DiscrepancyPrior | None, q_new: np.ndarray) -> np.ndarray:
    """:math:`C_\\ast` for all new points, (m, 3n) [m²], columns point-major then component."""
    n = q_new.shape[0]
    out = np.zeros((lin.m, 3 * n))
    if prior is None:
        return out
    k = prior.covariance_kernel(lin.q, q_new)
    for c in range(3):
        out[:, c::3] = np.where((lin.position & (lin.component == c))[:, None], k, 0.0)
    return out


def error_covariances(lin: Linearisation, prior: DiscrepancyPrior | None, jac_new: np.ndarray,
                      q_new: np.ndarray, noise_new: np.ndarray | None = None,
                      compensate: bool = False) -> np.ndarray:
    r""":math:`V_\ast` (n, 3, 3) [m²] of n new points (module docstring).

    Args:
        lin: The identification, linearised.
        prior: The model error (None: the model is exact).
        jac_new: :math:`G_\ast` per point, (n, 3, n_f) [m per unit].
        q_new: Their configurations, (n, nq).
        noise_new: :math:`N_\ast` per point, (n, 3, 3) [m²], or None.
        compensate: Whether the prediction adds the model error's conditional mean.
    """
    n = q_new.shape[0]
    g = jac_new.reshape(3 * n, -1)
    noise_f = scipy.linalg.cho_factor(lin.noise, lower=True)
    wj = scipy.linalg.cho_solve(noise_f, lin.jac)
    a = np.linalg.solve(lin.jac.T @ wj, wj.T)  # (n_f, m)
    b = g @ a
    sigma = lin.covariance(prior)
    cross = _cross(lin, prior, q_new)
    if compensate and prior is not None:
        s_inv_c = scipy.linalg.cho_solve(scipy.linalg.cho_factor(sigma, lower=True), cross)
        b = b + s_inv_c.T - (s_inv_c.T @ lin.jac) @ a
    bc = b @ cross
    v = (b @ sigma) @ b.T - bc - bc.T
    blocks = np.stack([v[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(n)])
    if prior is not None:
        blocks += prior.pose_variance(q_new)[:, None, None] * np.eye(3)
    if noise_new is not None:
        blocks += noise_new
    return 0.5 * (blocks + np.swapaxes(blocks, 1, 2))


def compensation(lin: Linearisation, prior: DiscrepancyPrior, q_new: np.ndarray) -> np.ndarray:
    r""":math:`\mu_\ast = C_\ast^\top\Sigma^{-1}e` (n, 3) [m]: the model error's conditional mean
    at ``q_new``, in the frame of the residuals (the tracker frame)."""
    alpha = scipy.linalg.cho_solve(scipy.linalg.cho_factor(lin.covariance(prior), lower=True),
                                   lin.residual)
    return (_cross(lin, prior, q_new).T @ alpha).reshape(-1, 3)


def new_poses(q_train: np.ndarray, n: int = N_NEW_POSES, seed: int = NEW_POSE_SEED) -> np.ndarray:
    """``n`` configurations uniform in the training data's joint ranges (per joint min..max)."""
    lo, hi = q_train.min(axis=0), q_train.max(axis=0)
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, q_train.shape[1]))


#: What the new poses of the expected RMS are, in words (:func:`feasible_new_poses`).
FEASIBLE_POSES = "feasible poses in the training joint ranges"
UNIFORM_POSES = "poses uniform in the training joint ranges (feasibility not checked)"


def feasible_new_poses(feasibility: FeasibilityModel | None, q_train: np.ndarray,
                       n: int = N_NEW_POSES, seed: int = NEW_POSE_SEED) -> tuple[np.ndarray, str]:
    """``n`` new poses for the expected RMS and what they are: feasible (uniform on the scene's
    feasible set, :func:`~calib_oed.feasibility.sampling.sample_feasible`) within the training
    joint ranges; uniform in those ranges when there is no feasibility model or it finds too
    few. Poses uniform in the ranges reach far outside what a robot can do there (arm folded
    into itself, reflector turned away) and overstate the error where it is used."""
    if feasibility is not None:
        try:
            return sample_feasible(feasibility, n, seed, bounds=(q_train.min(axis=0), q_train.max(axis=0)),
                                   max_draws=100_000), FEASIBLE_POSES
        except SamplingError:
            pass
    return new_poses(q_train, n, seed), UNIFORM_POSES


@dataclass(frozen=True)
class PredictedAccuracy:
    r"""Predicted error of the calibrated model, per working configuration and on new poses [mm].

    Attributes:
        names: Working configurations.
        tcp_sigma_mm: Per working configuration, :math:`\sqrt{\mathrm{tr} V/3}` (per axis) of the
            TCP in the tracker frame [mm].
        tcp_rms_mm: Per working configuration, :math:`\sqrt{\mathrm{tr} V}` (3-D RMS) [mm], same frame.
        new_pose_rms_mm: Expected RMS of the measured position error (3-D) on new poses
            (``poses``), noise included [mm].
        noise_only_new_pose_rms_mm: The same if the model were exact (noise only) [mm].
        compensated: Whether the predictions add the fitted model error's mean.
        covers: What the numbers cover, in words.
        new_pose_rms_range_mm: 95 % range of ``new_pose_rms_mm`` from the uncertainty of the
            fitted model error (:mod:`calib_oed.calibration.hyper_uncertainty`), or None.
        region_threshold: :math:`c` of the 95 % prediction regions :math:`e^\top V^{-1}e \le c`,
            widened for that uncertainty (:math:`\chi^2_3(0.95)` = 7.81 without it).
        log_variance_sd: :math:`\tau`, the sd of the log predicted variance, or None when not
            computed; above ``TAU_MAX`` the range is None (not determined).
        poses: What the new poses are (:func:`feasible_new_poses`).
        world_tcp_rms_mm: Per working configuration, the 3-D RMS of the TCP in the world (robot
            base) frame [mm] (:mod:`calib_oed.calibration.world_frame`), or None when not predicted.
        world_new_pose_rms_mm: The expected RMS on new poses in the world frame [mm], or None.
        gauge_share_mm2: Per working configuration, the joint-space prior's gauge share
            :math:`\Delta` [mm²] (world minus tracker frame), or None.
        world_prior: Where the joint-space prior behind the world-frame numbers comes from.
        world_prior_scale: The factor on the prior's variances: the fitted model error's mean
            tracker-frame trace on the new poses over the prior's (uncompensated).
        world_new_gauge_share_mm2: The mean gauge share on the new poses [mm²], scaled.
    """

    names: tuple[str, ...]
    tcp_sigma_mm: tuple[float, ...]
    tcp_rms_mm: tuple[float, ...]
    new_pose_rms_mm: float
    noise_only_new_pose_rms_mm: float
    compensated: bool
    covers: str
    new_pose_rms_range_mm: tuple[float, float] | None = None
    region_threshold: float = float(chi2.ppf(0.95, 3))
    log_variance_sd: float | None = None
    poses: str = FEASIBLE_POSES
    world_tcp_rms_mm: tuple[float, ...] | None = None
    world_new_pose_rms_mm: float | None = None
    gauge_share_mm2: tuple[float, ...] | None = None
    world_prior: str | None = None
    world_prior_scale: float | None = None
    world_new_gauge_share_mm2: float | None = None

    def world_dict(self) -> dict | None:
        """The world-frame numbers (JSON), or None when not predicted."""
        if self.world_tcp_rms_mm is None:
            return None
        return {"frame": "world", "covers": WORLD_COVERS, "prior": self.world_prior, "prior_kind": "joint-space (measurement/joint_prior.py)",
                "prior_scale": self.world_prior_scale, "new_pose_gauge_share_mm2": self.world_new_gauge_share_mm2,
                "new_pose_rms_mm": self.world_new_pose_rms_mm,
                "working_configurations": [
                    {"name": n, "rms_mm": r, "sigma_mm": r / np.sqrt(3.0), "gauge_share_mm2": d}
                    for n, r, d in zip(self.names, self.world_tcp_rms_mm, self.gauge_share_mm2, strict=True)]}

    def to_dict(self) -> dict:
        return {"compensated": self.compensated, "covers": self.covers,
                "new_poses": self.poses, "tcp_frame": "tracker", "tracker_frame_covers": TRACKER_COVERS,
                "headline_frame": "tracker" if self.world_tcp_rms_mm is None else "world",
                "world_frame": self.world_dict(),
                "new_pose_rms_mm": self.new_pose_rms_mm,
                "new_pose_rms_range_mm": None if self.new_pose_rms_range_mm is None
                else list(self.new_pose_rms_range_mm),
                "region_threshold": self.region_threshold, "log_variance_sd": self.log_variance_sd,
                "noise_only_new_pose_rms_mm": self.noise_only_new_pose_rms_mm,
                "working_configurations": [
                    {"name": n, "sigma_mm": s, "rms_mm": r}
                    for n, s, r in zip(self.names, self.tcp_sigma_mm, self.tcp_rms_mm, strict=True)]}

    def lines(self) -> list[str]:
        head = "with the model error's mean compensated" if self.compensated else "uncompensated"
        out = [f"predicted accuracy ({head}; {self.covers}):"]
        if self.world_tcp_rms_mm is not None:
            out += [f"  world (robot base) frame, the KPI's: TCP at {n} {r:.4f} mm RMS (3-D, "
                    f"{r / np.sqrt(3.0):.4f} mm per axis)" for n, r in zip(self.names, self.world_tcp_rms_mm, strict=True)]
            out.append(f"    new {self.poses}: {self.world_new_pose_rms_mm:.4f} mm RMS (3-D)")
        out += [f"  tracker frame: TCP at {n} {r:.4f} mm RMS (3-D, {s:.4f} mm per axis)"
                for n, s, r in zip(self.names, self.tcp_sigma_mm, self.tcp_rms_mm, strict=True)]
        out.append(f"    new {self.poses}: {self.new_pose_rms_mm:.4f} mm RMS (3-D; noise alone would give "
                   f"{self.noise_only_new_pose_rms_mm:.4f} mm)")
        if self.new_pose_rms_range_mm is not None:
            lo, hi = self.new_pose_rms_range_mm
            out.append(f"    95 % range {lo:.4f}..{hi:.4f} mm: how well the model error's size is known "
                       "from these poses")
        elif self.log_variance_sd is not None:
            out.append("    95 % range not determined: these poses do not determine the model error's "
                       "size (small against the noise, or too few poses)")
        if self.world_tcp_rms_mm is not None:
            out.append(f"  world frame: {WORLD_COVERS} [{self.world_prior}]")
        else:
            out.append("  world frame: not predicted (it needs the reflector-position data); a "
                       "calibration fixes the base only up to a rigid move no tracker data see")
        out.append(f"  tracker frame: {TRACKER_COVERS}")
        return out


def _repeatability(models) -> float:
    rho = [float(m.noise.repeatability) for m in models if m.noise is not None]
    return max(rho) if rho else 0.0


def predict_accuracy(problem, lin: Linearisation, prior: DiscrepancyPrior | None, p: np.ndarray,
                     free: np.ndarray, q_train: np.ndarray, compensate: bool = False,
                     n_new: int = N_NEW_POSES, seed: int = NEW_POSE_SEED,
                     spread: tuple | None = None,
                     feasibility: FeasibilityModel | None = None,
                     joint: JointErrorModel | None = None) -> PredictedAccuracy:
    """:class:`PredictedAccuracy` of the calibration ``p`` of ``problem`` (a
    :class:`~calib_oed.calibration.problem.CalibrationProblem`) identified from ``lin``;
    ``spread``: the Laplace approximation ``(active, cov)`` of ``prior``'s fit
    (:func:`~calib_oed.calibration.hyper_uncertainty.laplace_covariance`), for the range of the
    new-pose RMS and the widened regions (its derivative on the first :data:`N_SPREAD` new poses);
    ``feasibility``: the scene's constraints, for feasible new poses (:func:`feasible_new_poses`);
    ``joint``: the joint-space prior at the training values, for the world-frame numbers
    (:mod:`calib_oed.calibration.world_frame`; None: tracker frame only)."""
    space = problem.space
    q_new, poses = feasible_new_poses(feasibility, q_train, n_new, seed)
    state = evaluate_setup(space, p, q_new, regressor=True, jacobian=False)
    tr, tr_noise, parts, points = [], [], [], []
    for mdl in problem.models:
        h = mdl.compute_values(state)
        jac = mdl.compute_param_jacobian(state)[:, :3][:, :, free]
        noise = mdl.noise_covariance(h)[:, :3, :3]
        parts.append((jac[:N_SPREAD], noise[:N_SPREAD]))
        tr.append(np.trace(error_covariances(lin, prior, jac, q_new, noise, compensate), axis1=1, axis2=2))
        tr_noise.append(np.trace(error_covariances(lin, None, jac, q_new, noise), axis1=1, axis2=2))
        if joint is not None:  # the uncompensated traces scale the prior (world_frame docstring)
            fitted = tr[-1] if not compensate else np.trace(error_covariances(lin, prior, jac, q_new, noise),
                                                            axis1=1, axis2=2)
            points.append((state.reflector_offset(mdl.reflector), mdl.reflector, noise, tr[-1], fitted))
    rms_new = float(np.sqrt(np.mean(np.concatenate(tr))) * MM_PER_M)
    rms_range, threshold, tau = None, float(chi2.ppf(0.95, 3)), None
    if spread is not None and prior is not None:
        def mean_trace(pr):
            return float(np.mean([np.trace(error_covariances(lin, pr, j, q_new[:N_SPREAD], n, compensate),
                                           axis1=1, axis2=2).mean() for j, n in parts]))

        tau = log_spread(prior, *spread, mean_trace)
        if tau <= TAU_MAX:
            rms_range = (rms_new * float(np.exp(-0.98 * tau)), rms_new * float(np.exp(0.98 * tau)))
            threshold = region_threshold(tau)
    # the TCP in the tracker frame (module docstring), the frame of the model error's components
    kpi = problem.kpi.in_frame("tracker")
    g = kpi.compute_param_jacobian(space, p)[:, free].reshape(-1, 3, free.size)
    rho = _repeatability(problem.models)
    v = error_covariances(lin, prior, g, kpi.configurations,
                          np.broadcast_to(rho**2 * np.eye(3), (g.shape[0], 3, 3)), compensate)
    t = np.trace(v, axis1=1, axis2=2)
    world = {}
    if joint is not None:
        point = kpi.point if kpi.reflector is None else space.reflector_offsets(p)[kpi.reflector]
        world = _world_numbers(joint, lin, space, p, free, q_new, points,
                               (point, kpi.reflector, np.broadcast_to(rho**2 * np.eye(3), (g.shape[0], 3, 3)), t),
                               kpi.configurations)
    words = ["parameter uncertainty"] + (["model error"] if prior is not None else []) \
        + ["tracker noise and robot repeatability on measured points; repeatability at the TCP"]
    return PredictedAccuracy(
        tuple(kpi.names), tuple(float(x) for x in np.sqrt(t / 3) * MM_PER_M),
        tuple(float(x) for x in np.sqrt(t) * MM_PER_M),
        rms_new, float(np.sqrt(np.mean(np.concatenate(tr_noise))) * MM_PER_M), bool(compensate),
        ", ".join(words), rms_range, threshold, tau, poses, **world)


def _world_numbers(joint: JointErrorModel, lin: Linearisation, space, p, free, q_new, points, tcp, q_work) -> dict:
    r"""The world-frame fields of :class:`PredictedAccuracy` (:mod:`calib_oed.calibration.world_frame`):
    ``points`` per measurement model (offset, reflector, noise (n, 3, 3), tracker-frame traces,
    uncompensated ones) at the new poses ``q_new``, ``tcp`` the same (offset, reflector, noise,
    traces) at the working configurations ``q_work``. The prior's gauge share is scaled by the
    fitted over the prior's tracker-frame mean trace on the new poses."""
    def share_of(offset, reflector, noise, q):
        gt, gw, jq = point_jacobians(space, p, free, q, offset, reflector)
        prior_t, share = joint.compute_frames(gt, gw, q, jq[:, :, :joint.prior.nq])
        floor = np.trace(error_covariances(lin, None, gw.reshape(-1, 3, free.size), q, noise), axis1=1, axis2=2)
        return prior_t + np.trace(noise, axis1=1, axis2=2), share, floor

    new = [share_of(c, r, n, q_new) + (t, fitted) for c, r, n, t, fitted in points]
    scale = sum(x[4].sum() for x in new) / sum(x[0].sum() for x in new)
    world_new = np.concatenate([np.maximum(t + scale * share, floor) for _, share, floor, t, _ in new])
    _, share, floor = share_of(*tcp[:3], q_work)
    world_tcp = np.maximum(tcp[3] + scale * share, floor)
    return {"world_tcp_rms_mm": tuple(float(x) for x in np.sqrt(world_tcp) * MM_PER_M),
            "world_new_pose_rms_mm": float(np.sqrt(np.mean(world_new)) * MM_PER_M),
            "gauge_share_mm2": tuple(float(x) for x in scale * share * MM_PER_M**2),
            "world_prior": joint.prior.source, "world_prior_scale": float(scale),
            "world_new_gauge_share_mm2": float(scale * np.mean(np.concatenate([x[1] for x in new])) * MM_PER_M**2)}
