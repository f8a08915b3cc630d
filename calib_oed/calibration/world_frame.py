r"""The TCP accuracy in the world (robot base) frame: the tracker-frame prediction plus what the
fit's tracker estimate takes from the unmodelled joint errors.

**Why a second frame.** The tracker data fix the robot relative to the tracker, not to its own
base: a calibrated model and the true robot may differ by a rigid move of the base no tracker
data can see (the base gauge, ``docs/conventions.md``, "Estimability of KPIs"). With an exact
kinematic model that move is the noise's share of the fitted tracker pose; on a real arm the
unmodelled errors move it as well, by their part along the tracker pose's directions, which the
fit absorbs and the residuals (hence the fitted model error,
:mod:`calib_oed.calibration.prediction`) never show. The world frame is where the controller
works and where a scene's KPI is declared, so identify reports both.

**Model.** With the identification linearised at :math:`\hat p`
(:class:`~calib_oed.calibration.model_error.Linearisation`), the weighted least-squares
estimate is :math:`\hat p - p^\star = A(e + \varepsilon)`,
:math:`A = (J^\top N^{-1}J)^{-1}J^\top N^{-1}`. A point's error in the tracker frame
is :math:`G_T\,\delta p - e_\ast` and in the world frame (turned into the tracker's axes)
:math:`R^\top G_W\,\delta p - e_\ast`: the two differ only in the tracker pose's columns,
zero in :math:`G_W`. Under the joint-space prior
(:mod:`calib_oed.measurement.joint_prior`: each joint's angle error a Gaussian process, moved to
a point :math:`c` by its Jacobian column :math:`J_k(q; c)`), the model error's covariances are
:math:`\mathrm{Cov}(e_a, e_b) = \sum_k k_k(q_a, q_b)\,J_{k,a}J_{k,b}` between training values
and :math:`C_{a\ast} = \sum_k k_k(q_a, q_\ast)\,J_{k,a}J_k(q_\ast; c_\ast)^\top` with the point,
so with :math:`B_F = G_F A` and :math:`\Sigma = K + N`

.. math::
    \mathrm{tr}\,V_F = \mathrm{tr}\,K_{\ast\ast} - 2\,\mathrm{tr}(B_F C_\ast) + \mathrm{tr}(B_F\Sigma B_F^\top)
    + \mathrm{tr}\,N_\ast \quad [\mathrm{m}^2]

(the predictor of :mod:`calib_oed.oed.model_error`, criterion ``kpi_model``). The **gauge
share** :math:`\Delta = \mathrm{tr}\,V_W - \mathrm{tr}\,V_T`
(:math:`K_{\ast\ast}` and :math:`N_\ast` cancel) is the variance of the base's rigid move at
the point plus twice its covariance with the tracker-frame error; it can be negative (a design
measuring near the working configurations makes the base move cancel part of the error there).
The world-frame prediction is the tracker-frame one (fitted model error) plus the prior's
gauge share, never below the world-frame prediction of the exact model (noise only):

.. math::
    \sigma^2_W = \max\big(\mathrm{tr}\,V_T^{\mathrm{fit}} + \lambda\,\Delta^{\mathrm{prior}},\;
    \mathrm{tr}\,V_W^{\mathrm{noise}}\big), \qquad
    \lambda = \frac{\overline{\mathrm{tr}\,V_T^{\mathrm{fit}}}}{\overline{\mathrm{tr}\,V_T^{\mathrm{prior}}}}
    \text{ (means over the new poses)}.

The prior's amplitudes are the scene's ``robot.model_error`` (``kind: joint``) or else the size
class's published values (:meth:`JointErrorPrior.default_for`), not fitted to the data (the residuals do not see the part
the fit absorbs); :math:`\lambda` scales its variances to the size of this robot's model error as
the fitted model error sees it in the tracker frame, where both predict the same thing. Checked by
Monte Carlo of joint-angle draws of the prior through the nonlinear identification in
``tests/calibration/test_world_frame.py`` and on the realistic simulator in
``bench/bench_trust.py --frame world`` (``docs/benchmarks.md``, issue 29).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from calib_oed.calibration.model_error import Linearisation
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.joint_prior import JointErrorPrior

MM_PER_M = 1e3
#: What the world-frame numbers cover, in one sentence (report and JSON).
WORLD_COVERS = ("where the controller works and the KPI is declared; the tracker-frame error plus the "
                "rigid move of the base that the fit's tracker pose takes from the unmodelled joint errors, "
                "which the residuals cannot show: from the joint-space prior (the scene's robot.model_error, "
                "else the robot's size class), "
                "scaled to the model error fitted here; on three small arms of the realistic simulator this "
                "share came out 2.5 to 5 times low, from their gravity compliance (the TCP up to 1.27 times "
                "optimistic: docs/identification.md)")
#: What the tracker-frame numbers cover, in one sentence.
TRACKER_COVERS = ("where the tracker data place the TCP; for targets registered with the tracker, "
                  "and what validate measures")


def row_offsets(space, blocks, robust) -> np.ndarray:
    """Tool-frame offset of the point behind every value of ``robust``'s final linearisation,
    (m, 3) [m] at its estimate: each kept measurement's reflector, repeated per component."""
    offsets = space.reflector_offsets(robust.result.p)
    per = np.concatenate([np.repeat(offsets[b.model.reflector][None], b.n, axis=0) for b in blocks])
    dims = np.concatenate([np.full(b.n, b.model.dim) for b in blocks])
    kept = slice(None) if robust.dropped is None else ~robust.dropped
    return np.repeat(per[kept], dims[kept], axis=0)


@dataclass(frozen=True, eq=False)
class JointErrorModel:
    r"""The joint-space prior at an identification's training values (module docstring).

    Attributes:
        lin: The identification, linearised.
        prior: The joint-space prior.
        rows: :math:`J_{k,a}` of every training value, (m, nv) [m/rad], tracker frame (0 for a
            value that is not a position component).
        covariance: :math:`\Sigma = K + N` (m, m) [m²].
        fit: :math:`A` (n_f, m).
    """

    lin: Linearisation
    prior: JointErrorPrior
    rows: np.ndarray
    covariance: np.ndarray
    fit: np.ndarray

    @classmethod
    def build(cls, space, lin: Linearisation, prior: JointErrorPrior, p: np.ndarray,
              offsets: np.ndarray) -> JointErrorModel:
        """At the estimate ``p`` with the per-value tool offsets ``offsets`` (m, 3) [m]."""
        configs, index, _ = lin._configs
        state = evaluate_setup(space, p, configs, regressor=False, jacobian=True)
        rows = np.zeros((lin.m, prior.nq))
        for c in np.unique(offsets, axis=0):
            on = np.all(offsets == c, axis=1) & lin.position
            jac = state.tool_point_config_jacobian(c, "tracker")[:, :, :prior.nq]  # (P, 3, nq)
            rows[on] = jac[index[on], lin.component[on]]
        kk = prior.compute_kernels(configs, configs)[:, index][:, :, index]  # (nq, m, m)
        k = np.einsum("kab,ak,bk->ab", kk, rows, rows)
        noise_f = scipy.linalg.cho_factor(lin.noise, lower=True)
        wj = scipy.linalg.cho_solve(noise_f, lin.jac)
        a = np.linalg.solve(lin.jac.T @ wj, wj.T)
        return cls(lin, prior, rows, k + lin.noise, a)

    def cross(self, q: np.ndarray, jac: np.ndarray) -> np.ndarray:
        r""":math:`C_\ast` (m, 3n) [m²] of n points at ``q`` (n, nq) with error Jacobians ``jac``
        (n, 3, nq) [m/rad] (tracker axes), columns point-major then component."""
        configs, index, _ = self.lin._configs
        kx = self.prior.compute_kernels(configs, q)[:, index]  # (nq, m, n)
        return np.einsum("kan,ak,nck->anc", kx, self.rows, jac).reshape(self.lin.m, -1)

    def traces(self, g: np.ndarray, cross: np.ndarray) -> np.ndarray:
        r""":math:`-2\,\mathrm{tr}(B C_\ast) + \mathrm{tr}(B\Sigma B^\top)` per point (n,) [m²],
        :math:`B = G A`, ``g`` (3n, n_f) [m per unit]: :math:`\mathrm{tr}\,V` without the terms
        that do not depend on the frame."""
        b = g @ self.fit
        per = -2.0 * np.sum(b * cross.T, axis=1) + np.sum((b @ self.covariance) * b, axis=1)
        return per.reshape(-1, 3).sum(axis=1)

    def compute_frames(self, g_tracker: np.ndarray, g_world: np.ndarray, q: np.ndarray,
                       jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r""":math:`\mathrm{tr}\,V_T` without the point's noise and the gauge share
        :math:`\Delta = \mathrm{tr}\,V_W - \mathrm{tr}\,V_T` per point, each (n,) [m²] (module
        docstring); ``g_world`` already turned into the tracker's axes."""
        c = self.cross(q, jac)
        own = np.einsum("knn,nck,nck->n", self.prior.compute_kernels(q, q), jac, jac)
        tracker = self.traces(g_tracker, c)
        return own + tracker, self.traces(g_world, c) - tracker


def point_jacobians(space, p: np.ndarray, free: np.ndarray, q: np.ndarray, offset: np.ndarray,
                    reflector: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r""":math:`G_T`, :math:`R^\top G_W` (3n, n_f) [m per unit] and the error Jacobian
    :math:`\partial x/\partial q` (n, 3, nv) (tracker axes) of the tool point ``offset`` (the
    reflector ``reflector``'s centre when given) at ``q``."""
    state = evaluate_setup(space, p, q, regressor=True, jacobian=True)
    gt = state.tool_point_param_jacobian(offset, "tracker", reflector)[:, :, free]
    gw = state.tool_point_param_jacobian(offset, "world", reflector)[:, :, free]
    rot = space.tracker_placement(p).rotation
    gw = np.einsum("ba,nbf->naf", rot, gw)
    return gt.reshape(-1, free.size), gw.reshape(-1, free.size), state.tool_point_config_jacobian(offset, "tracker")


def draw_joint_errors(prior: JointErrorPrior, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    r"""One draw of every joint's angle error :math:`\varepsilon_k(q)` at the configurations ``q``
    (n, nq) jointly, (n, nq) [rad]: a true robot of the prior's own assumptions (its arm moves
    to :math:`q + \varepsilon(q)` when commanded :math:`q`). Duplicate rows of ``q`` get one draw."""
    distinct, inverse = np.unique(np.asarray(q, dtype=float), axis=0, return_inverse=True)
    kern = prior.compute_kernels(distinct, distinct)
    n = distinct.shape[0]
    eps = np.empty((n, prior.nq))
    for k in range(prior.nq):
        scale = max(float(np.max(np.diag(kern[k]))), 1e-30)
        chol = np.linalg.cholesky(kern[k] + 1e-10 * scale * np.eye(n))
        eps[:, k] = chol @ rng.normal(size=n)
    return eps[inverse.ravel()]
