r"""The KPI criterion under model error: the predicted TCP error at the working configurations
after calibration, when the model error is a Gaussian process over the configuration.

**Model** (``docs/oed.md``, "The criterion under model error"). Linearised at the
nominal parameters, the measurements of a design and the KPI are

.. math::
    y = F\,\delta p + e + \varepsilon, \qquad s = G\,\delta p + e_w,

:math:`F` (m, n_f) the unit-scaled sensitivities of the measured values,
:math:`e` the model error at the measured points and :math:`e_w` at the KPI
points, each Cartesian component a zero-mean GP over :math:`q` with kernel
:math:`k` (:class:`~calib_oed.measurement.discrepancy.DiscrepancyPrior`), several
reflectors at one pose sharing it, :math:`\varepsilon \sim N(0, R)` the tracker
noise. In whitened rows (:math:`W = R^{-1/2}`, the objective's
:math:`\tilde F = W F D`) the measurement covariance is
:math:`S = I + \tilde K`, :math:`\tilde K = W\,(K \otimes I_3\text{ per reflector pair})\,W^\top`.
The best linear unbiased predictor of :math:`s` from :math:`y` (universal
kriging: the GLS estimate of :math:`\delta p` plus the GP's conditional mean;
Cressie 1993, §3.4; Santner, Williams & Notz 2003, §3.2) has the error covariance

.. math::
    C = K_{ww} - k_w^\top S^{-1} k_w + P M^{-1} P^\top, \qquad
    P = \tilde G - k_w^\top S^{-1}\tilde F, \quad M = \tilde F^\top S^{-1}\tilde F

[mm²], :math:`k_w` the covariances of the whitened measurements with the KPI
model error, :math:`K_{ww}` that of the KPI model error. The criterion is
:math:`\phi = \sum_i w_i\,\mathrm{tr}\,C_{ii}/(3\sum_i w_i)`, the weighted mean
squared KPI error [mm²]; with :math:`\sigma = 0` it is exactly the paper's ``kpi``.
Isotropic model error makes :math:`\mathrm{tr}\,C_{ii}` frame-free: the KPI rows
are turned into the tracker frame, where the measurements are, and then every
matrix above is block diagonal in the Cartesian component.

**Gradient.** With :math:`Y = M^{-1}P^\top`, :math:`V = S^{-1}(k_w + \tilde F Y)`
and :math:`\Omega` the diagonal of the weights,

.. math::
    d\phi = \mathrm{tr}(\Omega V^\top dS\, V) - 2\,\mathrm{tr}(\Omega V^\top dk_w)
            - 2\,\mathrm{tr}(\Omega\, Y^\top d\tilde F^\top V),

and :math:`dS`, :math:`dk_w` follow the kernel's gradient, :math:`d\tilde F` the
rows' configuration derivatives (``docs/oed.md``; checked against central
differences in ``tests/oed/test_model_error.py``).

**Joints that move no point.** A joint whose axis passes through every
reflector and the KPI point (the A6 axis with the shipped one-SMR scenes) moves
none of them, so it cannot change their model error: the criterion's kernel
ignores it (length scale :math:`\infty`, :func:`design_prior`), else turning
it would count as a new, independent measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from calib_oed.exceptions import CertificateError, DesignError
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.position import TrackerPosition
from calib_oed.oed.criterion_base import Criterion, _not_identifiable

#: Name of the criterion in :data:`calib_oed.oed.criteria.CRITERIA`.
MODEL_ERROR = "kpi_model"
#: SQP iterations of a kpi_model design by default: on fms_kr16 (60 poses) the value at 60
#: iterations is within 5 % of the value at 120-270 (``docs/oed.md``); keeps the design time
#: within 1.5x of the noise-only design's.
MODEL_ERROR_ITERATIONS = 60
#: Relative point motion [1] below which a joint counts as moving no point (:func:`design_prior`).
STILL_TOL = 1e-9
_MM = 1e3
#: Why the design record has no certificate for this criterion (``docs/oed.md``).
MODEL_ERROR_NO_CERTIFICATE = (
    "no certificate for kpi_model: the model error couples the poses through the kernel, so the "
    "criterion is not a convex function of a design measure and the approximate-design bound does "
    "not apply; it is never below the noise-only kpi criterion, whose certificate bounds it loosely "
    "(docs/oed.md)")


def default_criterion(scene) -> str:
    """The default design criterion: ``kpi_model`` under the scene's model-error prior
    (``robot.model_error``, else the documented default for the robot's reach), where it
    applies (reflector positions, the mean KPI aggregate); else the paper's ``kpi``."""
    return MODEL_ERROR if scene.measurement == "position" and scene.kpi.aggregate == "mean" else "kpi"


def design_settings(objective, settings):
    """``settings``, or for a criterion of the whole design the SQP defaults capped at
    :data:`MODEL_ERROR_ITERATIONS` (its Hessian is damped BFGS: ``docs/oed.md``)."""
    if settings is not None or not getattr(objective, "needs_design", False):
        return settings
    from calib_oed.solver.sqp import SQPSettings

    return SQPSettings(max_iterations=MODEL_ERROR_ITERATIONS)  # DESIGN_SQP, capped


def scene_criterion(s, criterion):
    """``criterion``, with the name ``kpi_model`` made for the set-up ``s`` with its scene's
    model-error prior (``robot.model_error``, else the default for the robot's reach);
    None: :func:`default_criterion`."""
    if criterion is None:
        criterion = default_criterion(s.scene)
    if isinstance(criterion, str) and criterion == MODEL_ERROR:
        problem = s.problem
        free = problem.identifiability.free_indices
        g = problem.kpi_jacobian(None)[:, free] * problem.space.unit_scale[free] * _MM  # as the objective's
        return make_model_error_criterion(problem, g, s.scene.discrepancy(), getattr(problem.kpi, "weights", None))
    return criterion


def design_prior(problem, prior: DiscrepancyPrior) -> DiscrepancyPrior:
    """``prior`` with an infinite length scale for every joint that moves no reflector and no KPI point.

    Judged on the generic design (:meth:`CalibrationProblem.generic_configurations`):
    the joint's column of every point Jacobian is below :data:`STILL_TOL` times the largest.
    """
    from calib_oed.measurement.base import evaluate_setup

    space = problem.space
    q = problem.generic_configurations()[:20]
    state = evaluate_setup(space, None, q, regressor=False, jacobian=True)
    offsets = list(space.reflector_offsets(None))
    if getattr(problem.kpi, "reflector", None) is None:
        offsets.append(np.asarray(problem.kpi.point, dtype=float))
    motion = np.zeros(space.robot.nq)
    for c in offsets:
        jac = state.tool_point_config_jacobian(c, "world")  # (n, 3, nv)
        motion = np.maximum(motion, np.abs(jac).max(axis=(0, 1))[: space.robot.nq])
    ell = np.array(prior.length_scales, dtype=float)
    ell[motion <= STILL_TOL * motion.max()] = np.inf
    if np.all(np.isinf(ell)):
        return prior
    return prior.with_values(prior.sigma, ell, prior.source)


@dataclass(frozen=True, eq=False)
class ModelErrorCriterion(Criterion):
    r"""The weighted mean squared KPI error after calibration under model error [mm²] (module docstring).

    Not a function of :math:`M` alone: :class:`~calib_oed.oed.objective.DesignObjective`
    evaluates it from the rows, their whitening and the configurations (:meth:`compute_design`).

    Attributes:
        prior: The model-error GP (its kernel over the configuration).
        kpi_jacobian: Unit-scaled KPI Jacobian :math:`\tilde G`, (3t, n_f)
            [mm/mm, mm/mrad], rows in the tracker frame.
        working: The working configurations (t, nq) [rad].
        weights: One weight >= 0 per KPI point, (t,), or None (all 1).
    """

    prior: DiscrepancyPrior
    kpi_jacobian: np.ndarray
    working: np.ndarray
    weights: np.ndarray | None = None
    name: str = MODEL_ERROR
    label: str = ("predicted KPI error under model error (universal kriging), "
                  "sum_i w_i tr C_ii / (3 sum_i w_i) [mm^2]")
    omega: np.ndarray = field(init=False, repr=False)

    #: Evaluated from the design (rows and configurations), not from M.
    needs_design = True

    def __post_init__(self):
        t = self.working.shape[0]
        w = np.ones(t) if self.weights is None else np.asarray(self.weights, dtype=float).reshape(t)
        object.__setattr__(self, "omega", np.repeat(w / (3.0 * w.sum()), 3))

    # ------------------------------------------------------------- not of M
    def compute_value(self, info):
        raise CertificateError("criterion", self.name, "depends on the configurations through the "
                               "model-error kernel, not on the information matrix alone")

    compute_gradient = compute_value

    # ------------------------------------------------------------- pieces
    def _solve(self, rows, q, z):
        r"""Whitened :math:`S^{-1}\tilde F`, :math:`S^{-1}k_w`, :math:`Y`, :math:`C_{cc}` and the kernels.

        ``z`` (n, d, 3): :math:`Z_j = W_j U`, the whitening of pose j's rows applied to the
        shared point error (one 3x3 block per reflector), so :math:`S_{jl} = \delta_{jl}I
        + k(q_j, q_l)\,Z_j Z_l^\top` and :math:`k_{w,ji} = k(q_j, q^w_i)\,Z_j` [mm].
        """
        n, d = rows.shape[:2]
        flat = rows.reshape(n * d, -1)
        kq = self.prior.kernel(q, q)
        kw = self.prior.kernel(q, self.working) * _MM
        s = np.einsum("jl,jac,lbc->jalb", kq, z, z).reshape(n * d, n * d)
        s[np.diag_indices_from(s)] += 1.0
        k_w = np.einsum("ji,jac->jaic", kw, z).reshape(n * d, -1)
        factor = scipy.linalg.cho_factor(s, lower=True, check_finite=False)
        a = scipy.linalg.cho_solve(factor, flat, check_finite=False)   # S^-1 F
        b = scipy.linalg.cho_solve(factor, k_w, check_finite=False)    # S^-1 k_w
        m = flat.T @ a
        p = self.kpi_jacobian - k_w.T @ a                               # G - k_w^T S^-1 F
        try:
            y = scipy.linalg.cho_solve(scipy.linalg.cho_factor(0.5 * (m + m.T), lower=True,
                                                               check_finite=False), p.T, check_finite=False)
        except np.linalg.LinAlgError:
            raise _not_identifiable(m) from None
        k_ww = self.prior.sigma**2 * _MM**2
        diag = k_ww - np.sum(k_w * b, axis=0) + np.sum(p * y.T, axis=1)  # C_cc [mm^2]
        return a, b, y, diag, kq, kw

    def compute_point_errors(self, rows: np.ndarray, q: np.ndarray, z: np.ndarray) -> np.ndarray:
        r""":math:`\mathrm{tr}\,C_{ii}/3` per working configuration [mm²], (t,)."""
        return self._solve(rows, q, z)[3].reshape(-1, 3).sum(axis=1) / 3.0

    def compute_design(self, rows: np.ndarray, q: np.ndarray, z: np.ndarray,
                       d_rows: np.ndarray | None = None, d_z: np.ndarray | None = None):
        r""":math:`\phi` [mm²] and, with ``d_rows``, :math:`\partial\phi/\partial q` (n, nq).

        Args:
            rows: :math:`\tilde F_j` per pose, (n, d, n_f).
            q: The design (n, nq) [rad].
            z: :math:`Z_j` (n, d, 3) [1/m] (:meth:`_solve`).
            d_rows: :math:`\partial\tilde F_j/\partial q_j`, (n, d, n_f, nv), or None (value only).
            d_z: :math:`\partial Z_j/\partial q_j`, (n, d, 3, nv), or None (constant whitening).
        """
        a, b, y, diag, kq, kw = self._solve(rows, q, z)
        value = float(self.omega @ diag)
        if d_rows is None:
            return value, None
        n, d = rows.shape[:2]
        vo = (b + a @ y) * self.omega                           # V Omega, V = S^-1 (k_w + F Y)
        d_f = -2.0 * vo @ y.T                                  # dphi/dF (m, n_f)
        grad = np.einsum("jdf,jdfk->jk", d_f.reshape(n, d, -1), d_rows)
        u = (vo @ (b + a @ y).T).reshape(n, d, n, d)           # dphi/dS
        x_w = -2.0 * vo.reshape(n, d, -1, 3)                    # dphi/dk_w
        t_s = np.einsum("jalb,jac,lbc->jl", u, z, z)
        t_w = np.einsum("jaic,jac->ji", x_w, z) * _MM
        grad += 2.0 * np.einsum("jl,jlk->jk", t_s, self.prior.kernel_gradient(q, q))
        grad += np.einsum("ji,jik->jk", t_w, self.prior.kernel_gradient(q, self.working))
        if d_z is not None:  # the whitening moves with the pose (a full noise model)
            g_z = 2.0 * np.einsum("jl,jalb,lbc->jac", kq, u, z) + np.einsum("ji,jaic->jac", kw, x_w)
            grad += np.einsum("jac,jack->jk", g_z, d_z)
        return value, grad


def make_model_error_criterion(problem, kpi_jacobian: np.ndarray, prior: DiscrepancyPrior,
                               weights=None) -> ModelErrorCriterion:
    """The criterion of ``problem`` with its KPI Jacobian (unit-scaled, KPI frame) and a prior.

    Raises:
        DesignError: a measurement model other than isotropic 3-D positions.
    """
    if not all(isinstance(m, TrackerPosition) for m in problem.models):
        raise DesignError("criterion", MODEL_ERROR, "needs 3-D reflector positions (measurement: position); "
                          "the model error of a 6-D pose's angles is not modelled")
    g = np.asarray(kpi_jacobian, dtype=float)
    if problem.kpi.frame == "world":  # turn each point's rows into the tracker frame
        rot = problem.space.tracker_placement(None).rotation
        g = np.einsum("ba,tbf->taf", rot, g.reshape(-1, 3, g.shape[1])).reshape(g.shape)
    working = np.asarray(problem.kpi.configurations, dtype=float)
    return ModelErrorCriterion(design_prior(problem, prior), g, working, weights)
