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
Two predictors of :math:`s`. ``kpi_model`` (predictor ``"fit"``, the default
design criterion): the noise-weighted least-squares fit alone, as
:func:`calib_oed.calibration.identification.identify` computes it, with
:math:`M = \tilde F^\top\tilde F`, :math:`X = \tilde F M^{-1}\tilde G^\top`,

.. math::
    C = K_{ww} + X^\top S X - X^\top k_w - k_w^\top X

(the noise-only covariance plus what the fit makes of the model error at the
KPI points). ``kpi_kriging`` (predictor ``"kriging"``): the best linear
unbiased predictor (universal kriging: the GLS estimate of :math:`\delta p`
plus the GP's conditional mean of the residuals; Cressie 1993, §3.4; Santner,
Williams & Notz 2003, §3.2), never worse than the fit alone, with the error covariance

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

**Gradient.** With :math:`\Omega` the diagonal of the weights, both predictors give
:math:`d\phi = \mathrm{tr}(\Omega V^\top dS\, V) - 2\,\mathrm{tr}(\Omega V^\top dk_w)
+ \langle \partial\phi/\partial\tilde F, d\tilde F\rangle`. Kriging:
:math:`Y = M^{-1}P^\top`, :math:`V = S^{-1}(k_w + \tilde F Y)`,
:math:`\partial\phi/\partial\tilde F = -2V\Omega Y^\top`. Fit: :math:`Y = M^{-1}\tilde G^\top`,
:math:`V = X`, :math:`R = SX - k_w`, :math:`Q = M^{-1}\tilde F^\top R`,
:math:`\partial\phi/\partial\tilde F = 2R\Omega Y^\top - 2\tilde F(Q\Omega Y^\top + Y\Omega Q^\top)`,

and :math:`dS`, :math:`dk_w` follow the kernel's gradient, :math:`d\tilde F` the
rows' configuration derivatives (``docs/oed.md``; checked against central
differences in ``tests/oed/test_model_error_design.py``).

**The joint-space prior** (:mod:`calib_oed.measurement.joint_prior`, the default without
``robot.model_error``): each joint's angle error a GP moved to the points by their Jacobian
columns, so with :math:`B_j = Z_j\,\partial y_j/\partial q` (tracker frame)
:math:`S_{jl} = \delta_{jl}I + \sum_k k_k(q_j, q_l)\,B_{jk}B_{lk}^\top`,
:math:`k_{w,ji} = \sum_k k_k(q_j, q^w_i)\,B_{jk}J^{w\top}_{ik}` and
:math:`K_{ww,ii} = \sum_k k_k(q^w_i, q^w_i)\,J^w_{ik}J^{w\top}_{ik}` (:meth:`ModelErrorCriterion._covariances`);
the gradient adds the terms through :math:`B_j` (:meth:`ModelErrorCriterion._joint_gradient`).
Checked against central differences and a Monte Carlo of joint-angle draws in
``tests/oed/test_joint_prior.py``.

**Joints that move no point** (the isotropic prior). A joint whose axis passes through every
reflector and the KPI point (the A6 axis with the shipped one-SMR scenes) moves
none of them, so it cannot change their model error: the criterion's kernel
ignores it (length scale :math:`\infty`, :func:`design_prior`), else turning
it would count as a new, independent measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg

from calib_oed.calibration.joint_prior_choice import joint_prior
from calib_oed.exceptions import CertificateError, DesignError
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.joint_prior import JointErrorPrior, PointJacobians, point_jacobians
from calib_oed.measurement.position import TrackerPosition
from calib_oed.oed.criterion_base import Criterion, _not_identifiable

#: Names of the criteria in :data:`calib_oed.oed.criteria.CRITERIA`: the KPI error of the
#: parametric fit (the default design criterion), and of GLS plus kriging compensation.
MODEL_ERROR = "kpi_model"
KRIGING = "kpi_kriging"
#: The predictors of :class:`ModelErrorCriterion`, in the order of the names above.
PREDICTORS = ("fit", "kriging")
#: SQP iterations of a model-error design on damped BFGS: on fms_kr16 (60 poses, kpi_kriging) the value
#: at 60 iterations is within 5 % of the value at 120-270 (``docs/oed.md``).
MODEL_ERROR_ITERATIONS = 60
#: SQP iterations of a ``kpi_model`` design of n poses: this over n (:func:`exact_iterations`), with the
#: ratio trust rule. Up to 120 poses 300 (the SQP's own limit; at n = 60 and 120 the realistic error falls
#: up to it, the prediction held: ``docs/oed.md``); above, a cost rule (an iteration costs about n²). Half
#: of it starved large designs (500 poses predicted worse than 120); this takes 15 % off the realistic
#: error at 250 poses for 1.9x the CPU (``docs/benchmarks.md``, "kpi_model's budget above 60 poses").
MODEL_ERROR_POSE_ITERATIONS = 36000
#: Most SQP iterations of a ``kpi_model`` design.
MODEL_ERROR_EXACT_ITERATIONS = 300
#: Fewest SQP iterations of a large ``kpi_model`` design (its cap before the motor-side part).
MODEL_ERROR_MIN_ITERATIONS = 25
#: Relative point motion [1] below which a joint counts as moving no point (:func:`design_prior`).
STILL_TOL = 1e-9
_MM = 1e3
#: Why the design record has no certificate for this criterion (``docs/oed.md``).
MODEL_ERROR_NO_CERTIFICATE = (
    "no certificate for the model-error criteria (kpi_model, kpi_kriging): the model error couples the poses through the kernel, so the "
    "criterion is not a convex function of a design measure and the approximate-design bound does "
    "not apply; it is never below the noise-only kpi criterion, whose certificate bounds it loosely "
    "(docs/oed.md)")


def default_criterion(scene) -> str:
    """The default design criterion: ``kpi_model`` when it applies (reflector positions, the
    mean KPI aggregate), with the scene's ``robot.model_error`` or else the joint-space prior
    (the size-class default, :func:`~calib_oed.calibration.joint_prior_choice.joint_prior`); else the
    paper's ``kpi``. Measured against ``kpi`` on the realistic simulator in ``docs/oed.md``."""
    applies = scene.measurement == "position" and scene.kpi.aggregate == "mean"
    return MODEL_ERROR if applies else "kpi"


def exact_iterations(n: int) -> int:
    """SQP iterations of a ``kpi_model`` design of ``n`` poses (:data:`MODEL_ERROR_POSE_ITERATIONS`)."""
    return min(MODEL_ERROR_EXACT_ITERATIONS, max(MODEL_ERROR_MIN_ITERATIONS, MODEL_ERROR_POSE_ITERATIONS // max(int(n), 1)))


def design_settings(objective, settings, exact: bool = False, n: int = 60, base=None):
    """``settings``, or for a criterion of the whole design of ``n`` poses ``base`` (the design's
    SQP settings, :data:`~calib_oed.oed.refine.DESIGN_SQP`; None: the SQP's defaults) capped at
    :func:`exact_iterations` with the exact Hessian (``exact``: ``kpi_model``), else
    :data:`MODEL_ERROR_ITERATIONS` (``docs/oed.md``). With the exact Hessian, an
    ``"auto"`` Hessian modification is the tangent rule at every size (``docs/benchmarks.md``,
    "Growth with n"); the trust rule is every exact-Hessian design's (:data:`~calib_oed.oed.refine.EXACT_TRUST_UPDATE`);
    one penalty for every row, no active-set start, and the SQP's default first box for ``base``'s (``SQPSettings``:
    ``penalty_weights``, ``qp_active_set_start``, ``step_bound``): the design SQP's moved these designs by percents."""
    if not getattr(objective, "needs_design", False):
        return settings
    from calib_oed.solver.sqp import SQPSettings
    if settings is None:
        settings = replace(base or SQPSettings(), max_iterations=exact_iterations(n) if exact else MODEL_ERROR_ITERATIONS)
    rule = "tangent" if exact and settings.hessian_modification == "auto" else settings.hessian_modification
    box = SQPSettings.step_bound if base is not None and settings.step_bound == base.step_bound else settings.step_bound
    return replace(settings, hessian_modification=rule, penalty_weights="single", qp_active_set_start=False,
                   step_bound=box)


def scene_criterion(s, criterion, prior=None):
    """``criterion``, with the name ``kpi_model`` made for the set-up ``s`` with ``prior``, else its
    scene's joint-space prior (``robot.model_error`` with ``kind: joint``, or ``--prior-from``:
    :func:`calib_oed.calibration.joint_prior_choice.joint_prior`), else its isotropic ``robot.model_error``,
    else :func:`~calib_oed.calibration.joint_prior_choice.joint_prior` (the size-class default); None: :func:`default_criterion`."""
    if criterion is None:
        criterion = default_criterion(s.scene)
    if isinstance(criterion, str) and criterion in (MODEL_ERROR, KRIGING):
        problem = s.problem
        free = problem.identifiability.free_indices
        g = problem.kpi_jacobian(None)[:, free] * problem.space.unit_scale[free] * _MM  # as the objective's
        if prior is None:
            prior = scene_prior(s)
            prior = joint_prior(problem) if prior is None else prior
        return make_model_error_criterion(problem, g, prior, getattr(problem.kpi, "weights", None), criterion)
    return criterion


def scene_prior(s):
    """The model-error prior the set-up ``s``'s scene gives the design criterion: its joint-space
    prior (``robot.model_error`` with ``kind: joint``, or ``--prior-from``), else its isotropic
    ``robot.model_error``, else None (the default, :func:`~calib_oed.calibration.joint_prior_choice.joint_prior` (the size-class default))."""
    if getattr(s.scene, "joint_error", None) is not None:
        return joint_prior(s.problem, s.scene.joint_error)
    return s.scene.model_error


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
        predictor: ``"fit"`` (the parametric fit alone, as ``identify`` gives it: criterion
            ``kpi_model``) or ``"kriging"`` (GLS plus the GP's conditional mean:
            ``kpi_kriging``); :data:`PREDICTORS`.
    """

    prior: DiscrepancyPrior | JointErrorPrior
    kpi_jacobian: np.ndarray
    working: np.ndarray
    weights: np.ndarray | None = None
    predictor: str = "fit"
    name: str = MODEL_ERROR
    label: str = ("predicted KPI error after calibration under model error, "
                  "sum_i w_i tr C_ii / (3 sum_i w_i) [mm^2]")
    points: PointJacobians | None = None
    kpi_points: PointJacobians | None = None
    omega: np.ndarray = field(init=False, repr=False)

    #: Evaluated from the design (rows and configurations), not from M.
    needs_design = True

    def __post_init__(self):
        if self.predictor not in PREDICTORS:
            raise DesignError("predictor", self.predictor, "how the KPI is predicted", PREDICTORS)
        t = self.working.shape[0]
        w = np.ones(t) if self.weights is None else np.asarray(self.weights, dtype=float).reshape(t)
        object.__setattr__(self, "omega", np.repeat(w / (3.0 * w.sum()), 3))
        if self.joint_space:
            if self.points is None or self.kpi_points is None:
                raise DesignError("criterion", self.name, "needs the point Jacobians with a joint-space prior")
            jw = self.kpi_points.compute(self.working)[0][:, 0]  # (t, 3, nv) [m/rad], tracker frame
            tau = None if self.prior.gravity is None else (self.prior.gravity.torques(self.working),) * 2
            kww = self.prior.compute_kernels(self.working, self.working, tau)  # (nv, t, t)
            k_ww = np.einsum("kii,ick,ick->ic", kww, jw, jw).ravel() * _MM**2  # (3t,) [mm^2]
            object.__setattr__(self, "_joint_work", (jw, tau, k_ww))
        # the joint-space pieces of the last design (the SQP asks for the gradient and the exact
        # Hessian at the same configurations): key -> value, keyed on the inputs' exact bytes
        object.__setattr__(self, "_memo", {})

    @property
    def joint_space(self) -> bool:
        """The prior is the joint-space one (:mod:`calib_oed.measurement.joint_prior`)."""
        return isinstance(self.prior, JointErrorPrior)

    # ------------------------------------------------------------- not of M
    def compute_value(self, info):
        raise CertificateError("criterion", self.name, "depends on the configurations through the "
                               "model-error kernel, not on the information matrix alone")

    compute_gradient = compute_value

    # ------------------------------------------------------------- pieces
    def _covariances(self, rows, q, z, gradient: bool = False):
        r""":math:`S` (m, m), :math:`k_w` (m, 3t) [mm] in whitened rows, :math:`\mathrm{diag}\,K_{ww}`
        [mm²] and the kernels (what the gradient needs).

        ``z`` (n, d, 3): :math:`Z_j = W_j U`, the whitening of pose j's rows applied to the
        shared point error (one 3x3 block per reflector), so :math:`S_{jl} = \delta_{jl}I
        + k(q_j, q_l)\,Z_j Z_l^\top` and :math:`k_{w,ji} = k(q_j, q^w_i)\,Z_j`. With the
        joint-space prior :math:`B_j = Z_j\,\partial y_j/\partial q` (d, nv), so
        :math:`S_{jl} = \delta_{jl}I + \sum_k k_k(q_j, q_l)\,B_{jk}B_{lk}^\top` and
        :math:`k_{w,ji} = \sum_k k_k(q_j, q^w_i)\,B_{jk}J^{w\top}_{ik}`.
        """
        n, d = rows.shape[:2]
        if not self.joint_space:
            kq = self.prior.kernel(q, q)
            kw = self.prior.kernel(q, self.working) * _MM
            s = np.einsum("jl,jac,lbc->jalb", kq, z, z).reshape(n * d, n * d)
            s[np.diag_indices_from(s)] += 1.0
            k_w = np.einsum("ji,jac->jaic", kw, z).reshape(n * d, -1)
            return s, k_w, self.prior.smooth_variance * _MM**2, (kq, kw)
        jw, tau_w, k_ww = self._joint_work
        key = ("covariances", rows.shape, q.dtype.str, q.shape, q.tobytes(), z.dtype.str, z.shape, z.tobytes())
        hit = self._memo.get(key)
        if hit is not None and (hit[3][4] is not None or not gradient):  # built with d_jac, or not needed
            return hit
        jac, d_jac = self.points.compute(q, gradient)  # (n, r, 3, nv), (n, r, 3, nv, nv)
        b = np.einsum("jrxy,jryk->jrxk", z.reshape(n, -1, 3, 3), jac).reshape(n, d, -1)
        grav = self.prior.gravity
        tau = None if grav is None else grav.torques(q)
        kk = self.prior.compute_kernels(q, q, None if grav is None else (tau, tau))
        kwk = self.prior.compute_kernels(q, self.working, None if grav is None else (tau, tau_w[0]))
        s = np.einsum("kjl,jak,lbk->jalb", kk, b, b).reshape(n * d, n * d)
        s[np.diag_indices_from(s)] += 1.0
        k_w = np.einsum("kji,jak,ick->jaic", kwk, b, jw).reshape(n * d, -1) * _MM
        return self._remember(key, (s, k_w, k_ww, (kk, kwk, b, jac, d_jac, tau)))

    def _remember(self, key, value):
        """``value`` kept under ``key`` in place of the earlier entry of its kind (read-only arrays)."""
        for old in [k for k in list(self._memo) if k[0] == key[0]]:
            del self._memo[old]
        for a in _arrays(value):
            a.flags.writeable = False
        self._memo[key] = value
        return value

    def _kernel_gradients(self, q, tau):
        r"""The gravity torques' derivatives at ``q`` (n, nv, nv) (None without gravity) and
        :math:`\partial k_\kappa/\partial q_{1}` at (q, q) and at (q, working) (joint-space prior;
        ``tau`` the torques at ``q``), for the gradient and the exact Hessian alike."""
        key = ("kernel_gradients", q.dtype.str, q.shape, q.tobytes())
        hit = self._memo.get(key)
        if hit is not None:
            return hit
        grav = self.prior.gravity
        d_tau = None if grav is None else grav.torque_derivatives(q)
        dk = self.prior.compute_kernel_gradients(q, q, None if grav is None else (tau, tau, d_tau))
        dkw = self.prior.compute_kernel_gradients(q, self.working, None if grav is None else
                                                  (tau, self._joint_work[1][0], d_tau))
        return self._remember(key, (d_tau, dk, dkw))

    def _solve(self, rows, q, z, gradient: bool):
        r""":math:`C_{cc}` [mm²] (3t,), and with ``gradient`` the kernels, :math:`V` (m, 3t) and
        :math:`\partial\phi/\partial\tilde F` (m, n_f) (module docstring, per predictor)."""
        flat = rows.reshape(-1, rows.shape[-1])
        s, k_w, k_ww, kernels = self._covariances(rows, q, z, gradient)
        om = self.omega
        if self.predictor == "fit":  # the parametric fit alone: X = F M^-1 G^T, M = F^T F
            factor = _cho(flat.T @ flat)
            y = scipy.linalg.cho_solve(factor, self.kpi_jacobian.T, check_finite=False)
            v = flat @ y
            sv = s @ v
            diag = k_ww + np.sum(v * sv, axis=0) - 2.0 * np.sum(v * k_w, axis=0)
            if not gradient:
                return diag, None
            r = sv - k_w
            qq = scipy.linalg.cho_solve(factor, flat.T @ r, check_finite=False)
            d_f = 2.0 * (r * om) @ y.T - 2.0 * flat @ ((qq * om) @ y.T + (y * om) @ qq.T)
            return diag, (kernels, v, d_f)
        factor = scipy.linalg.cho_factor(s, lower=True, check_finite=False)
        a = scipy.linalg.cho_solve(factor, flat, check_finite=False)   # S^-1 F
        b = scipy.linalg.cho_solve(factor, k_w, check_finite=False)    # S^-1 k_w
        p = self.kpi_jacobian - k_w.T @ a                               # G - k_w^T S^-1 F
        y = scipy.linalg.cho_solve(_cho(flat.T @ a), p.T, check_finite=False)
        diag = k_ww - np.sum(k_w * b, axis=0) + np.sum(p * y.T, axis=1)  # C_cc [mm^2]
        if not gradient:
            return diag, None
        v = b + a @ y                                          # V = S^-1 (k_w + F Y)
        return diag, (kernels, v, -2.0 * (v * om) @ y.T)

    def compute_design(self, rows: np.ndarray, q: np.ndarray, z: np.ndarray,
                       d_rows: np.ndarray | None = None, d_z: np.ndarray | None = None):
        r""":math:`\phi` [mm²] and, with ``d_rows``, :math:`\partial\phi/\partial q` (n, nq).

        Args:
            rows: :math:`\tilde F_j` per pose, (n, d, n_f).
            q: The design (n, nq) [rad].
            z: :math:`Z_j` (n, d, 3) [1/m] (:meth:`_covariances`).
            d_rows: :math:`\partial\tilde F_j/\partial q_j`, (n, d, n_f, nv), or None (value only).
            d_z: :math:`\partial Z_j/\partial q_j`, (n, d, 3, nv), or None (constant whitening).
        """
        diag, pieces = self._solve(rows, q, z, d_rows is not None)
        value = float(self.omega @ diag)
        if pieces is None:
            return value, None
        kernels, v, d_f = pieces
        n, d = rows.shape[:2]
        vo = v * self.omega
        grad = np.einsum("jdf,jdfk->jk", d_f.reshape(n, d, -1), d_rows)
        u = (vo @ v.T).reshape(n, d, n, d)                     # dphi/dS = V Omega V^T
        x_w = -2.0 * vo.reshape(n, d, -1, 3)                    # dphi/dk_w = -2 V Omega
        if self.joint_space:
            return value, grad + self._joint_gradient(q, z, d_z, u, x_w, kernels)
        kq, kw = kernels
        t_s = np.einsum("jalb,jac,lbc->jl", u, z, z)
        t_w = np.einsum("jaic,jac->ji", x_w, z) * _MM
        grad += 2.0 * np.einsum("jl,jlk->jk", t_s, self.prior.kernel_gradient(q, q))
        grad += np.einsum("ji,jik->jk", t_w, self.prior.kernel_gradient(q, self.working))
        if d_z is not None:  # the whitening moves with the pose (a full noise model)
            g_z = 2.0 * np.einsum("jl,jalb,lbc->jac", kq, u, z) + np.einsum("ji,jaic->jac", kw, x_w)
            grad += np.einsum("jac,jack->jk", g_z, d_z)
        return value, grad

    def _joint_gradient(self, q, z, d_z, u, x_w, kernels) -> np.ndarray:
        r"""The part of :math:`\partial\phi/\partial q` (n, nv) through :math:`S` and :math:`k_w`
        with the joint-space prior: through the kernels and through :math:`B_j` (its point
        Jacobians and whitening), given :math:`\partial\phi/\partial S` ``u`` (n, d, n, d) and
        :math:`\partial\phi/\partial k_w` ``x_w`` (n, d, t, 3)."""
        kk, kwk, b, jac, d_jac, tau = kernels
        n, d = b.shape[:2]
        jw = self._joint_work[0]
        _, dk, dkw = self._kernel_gradients(q, tau)
        ub = np.einsum("jalb,lbk->jalk", u, b)                   # (n, d, n, nv)
        t_s = np.einsum("jalk,jak->kjl", ub, b)
        grad = 2.0 * np.einsum("kjl,kjlm->jm", t_s, dk)
        g_b = 2.0 * np.einsum("jalk,kjl->jak", ub, kk)            # dphi/dB through S
        xw = np.einsum("jaic,ick->jaik", x_w, jw) * _MM          # (n, d, t, nv)
        t_w = np.einsum("jaik,jak->kji", xw, b)
        grad += np.einsum("kji,kjim->jm", t_w, dkw)
        g_b += np.einsum("jaik,kji->jak", xw, kwk)                # dphi/dB through k_w
        zr = z.reshape(n, -1, 3, 3)
        d_b = np.einsum("jrxy,jrykm->jrxkm", zr, d_jac)
        if d_z is not None:
            d_b += np.einsum("jrxym,jryk->jrxkm", d_z.reshape(n, -1, 3, 3, d_z.shape[-1]), jac)
        return grad + np.einsum("jak,jakm->jm", g_b, d_b.reshape(n, d, b.shape[2], -1))


def _arrays(value):
    """The arrays in ``value`` (nested tuples)."""
    if isinstance(value, np.ndarray):
        return [value]
    return [a for v in value for a in _arrays(v)] if isinstance(value, tuple) else []


def _cho(m: np.ndarray):
    """Cholesky factor of a symmetric information matrix, or NotIdentifiableError."""
    try:
        return scipy.linalg.cho_factor(0.5 * (m + m.T), lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        raise _not_identifiable(m) from None


def make_model_error_criterion(problem, kpi_jacobian: np.ndarray, prior: DiscrepancyPrior | JointErrorPrior,
                               weights=None, name: str = MODEL_ERROR) -> ModelErrorCriterion:
    """The criterion ``name`` (``kpi_model`` or ``kpi_kriging``) of ``problem`` with its KPI
    Jacobian (unit-scaled, KPI frame) and a prior.

    Raises:
        DesignError: a measurement model other than 3-D positions.
    """
    if not all(isinstance(m, TrackerPosition) for m in problem.models):
        raise DesignError("criterion", name, "needs 3-D reflector positions (measurement: position); "
                          "the model error of a 6-D pose's angles is not modelled")
    g = problem.kpi.rows_in_tracker_frame(problem.space, kpi_jacobian)
    working = np.asarray(problem.kpi.configurations, dtype=float)
    predictor = PREDICTORS[(MODEL_ERROR, KRIGING).index(name)]
    if isinstance(prior, JointErrorPrior):  # the points' Jacobians carry the joints' errors
        if prior.nq != problem.robot.nq:
            raise DesignError("model error", f"{prior.nq} joints", f"one value per joint ({problem.robot.nq})")
        offsets = problem.space.reflector_offsets(None)
        kpi = problem.kpi
        point = kpi.point if getattr(kpi, "reflector", None) is None else offsets[kpi.reflector]
        return ModelErrorCriterion(prior, g, working, weights, predictor, name,
                                   points=point_jacobians(problem, offsets[[m.reflector for m in problem.models]]),
                                   kpi_points=point_jacobians(problem, point))
    return ModelErrorCriterion(design_prior(problem, prior), g, working, weights, predictor, name)
