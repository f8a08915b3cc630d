r"""Approximate (continuous-weight) designs on a candidate pool and their equivalence-theorem bound.

**Approximate designs.** Weights :math:`w \in \Delta_N = \{w \ge 0,\ \mathbf 1^\top w = 1\}`
on candidate poses :math:`x_1..x_N` give the normalised information
(per pose; no prior)

.. math::
    M(w) = \sum_i w_i\, F_i^\top F_i \in \mathbb{R}^{p \times p},

with :math:`F_i = F(x_i) \in \mathbb{R}^{d \times p}` the weighted, unit-scaled
rows of pose :math:`i` on the free parameters
(:meth:`calib_oed.oed.objective.DesignObjective.compute_blocks`; rows
dimensionless, columns per mm or mrad). Two convex criteria are certified:
the A-type :math:`\Phi(M) = \mathrm{tr}(W M^{-1})/k` (``kpi``: the KPI mean
variance [mm²]; ``params``; any :class:`~calib_oed.oed.criteria.ACriterion`),
homogeneous, :math:`\Phi(tM) = \Phi(M)/t`, and D,
:math:`\Phi(M) = -\log\det M`, with :math:`\Phi(tM) = \Phi(M) - p\log t`.

**Sensitivity and equivalence theorem** (Kiefer & Wolfowitz 1960; Kiefer 1974).
With :math:`\Gamma = \partial\Phi/\partial M` at :math:`M(w)`,

.. math::
    d(x, w) = -\mathrm{tr}\big(\Gamma\,F(x)^\top F(x)\big) =
    \begin{cases} \|F(x)\,M^{-1}R^\top\|_F^2/k & \text{A } (W = R^\top R)\\
                  \mathrm{tr}\big(F(x)\,M^{-1}F(x)^\top\big) & \text{D}\end{cases},
    \qquad \bar d = \sum_i w_i d_i = -\mathrm{tr}(\Gamma M) =
    \begin{cases}\Phi & \text{A}\\ p & \text{D}\end{cases}.

:math:`\partial\Phi(M(w))/\partial w_i = -d_i`, so :math:`w` is optimal on the
simplex iff :math:`\max_i d_i \le \bar d`, with equality on the support. The
*equivalence residual* is :math:`\rho = \max_i d_i/\bar d - 1 \ge 0`.

**Lower bound.** For any design :math:`w'` on a set :math:`X` and any
:math:`t > 0`, convexity of :math:`\Phi` at :math:`tM` gives
:math:`\Phi(M') \ge \Phi(tM) + \mathrm{tr}(\Gamma(tM)(M' - tM))`; with
:math:`\sum_i w'_i d_i \le d^{\max} = \sup_X d = (1+\rho)\bar d` and
maximised over :math:`t` (A: :math:`t = d^{\max}/\Phi`; D: :math:`t = d^{\max}/p`):

.. math::
    \text{A: } \Phi(M') \ge \frac{\Phi(M)^2}{d^{\max}} = \frac{\Phi(M)}{1+\rho}, \qquad
    \text{D: } \Phi(M') \ge \Phi(M) - p\log(1+\rho).

Both are exact at the optimum (:math:`\rho = 0`) and never worse than the
Frank–Wolfe bound :math:`\Phi + \bar d - d^{\max}`.

**n poses.** An exact design :math:`q_1..q_n` (repeats allowed) has
:math:`M_n = n\,M(\xi_n)` with :math:`\xi_n` uniform on its poses, so
A: :math:`\Phi(M_n) = \Phi(M(\xi_n))/n \ge \Phi_{lb}/n`;
D: :math:`\Phi(M_n) = \Phi(M(\xi_n)) - p\log n \ge \Phi_{lb} - p\log n`.
The efficiency of a design is bound/value (A) or
:math:`\exp((\text{bound} - \text{value})/p)` (D), both :math:`\le 1`.

**Solver** (:func:`solve_approximate`): column generation with projected
Newton steps. The working set is the support plus the candidates with the
largest :math:`d_i > \bar d`; on it one QP
:math:`\min_s \tfrac12 s^\top H s - d^\top s`, :math:`\mathbf 1^\top s = 0`,
:math:`s \ge -w` (a deterministic active-set QP, :mod:`calib_oed.solver.simplex_qp`:
ProxQP's last bits depend on where its buffers lie, which made designs differ
between processes; the solve takes 0.9-1.3x its CPU with ProxQP, ``docs/benchmarks.md``)
with the exact Hessian
:math:`H_{ij} = c\sum (F_i(-\Gamma)F_j^\top)\odot(F_i M^{-1}F_j^\top)`
(:math:`c = 2` for A, 1 for D; ``docs/derivations.md`` §12), then an
Armijo line search; a pairwise (vertex-exchange) step when the QP gives no
descent. It stops on :math:`\rho \le` ``tol`` over all candidates: a duality
gap, not an iteration count.

The certificate of an exact design, which takes :math:`d^{\max}` over a pool and
the continuous feasible set, is :mod:`calib_oed.oed.certificate`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from calib_oed.exceptions import CertificateError, NotIdentifiableError
from calib_oed.oed.criteria import ACriterion, DCriterion
from calib_oed.oed.criterion_base import Criterion
from calib_oed.oed.exchange import check_blocks
from calib_oed.solver.simplex_qp import solve_simplex_qp

__all__ = ["CERTIFIABLE", "DROP_WEIGHT", "NEWTON_REGULARISATION", "ApproximateDesign",
           "criterion_kind", "efficiency", "information", "lower_bound", "mean_sensitivity",
           "scale_to_poses", "sensitivities", "solve_approximate"]

#: Criterion names :func:`calib_oed.oed.certificate.certify` accepts.
CERTIFIABLE = ("kpi", "params", "D")
#: Levenberg term of the Newton QP, relative to the largest diagonal entry of the Hessian.
NEWTON_REGULARISATION = 1e-8
#: Weights below this (of a total 1) are set to zero.
DROP_WEIGHT = 1e-11


# ------------------------------------------------------------- the pieces
def criterion_kind(criterion: Criterion) -> str:
    """``"A"`` (:class:`ACriterion`) or ``"D"`` (:class:`DCriterion`); CertificateError otherwise."""
    if isinstance(criterion, ACriterion):
        return "A"
    if isinstance(criterion, DCriterion):
        return "D"
    name = getattr(criterion, "name", criterion)
    raise CertificateError("criterion", name, "has no certificate (it is not A-type or D; "
                           "E and O2-O4 are not smooth, O1 and O5 not implemented)", CERTIFIABLE)


def information(blocks: np.ndarray, w: np.ndarray) -> np.ndarray:
    r""":math:`M(w) = \sum_i w_i F_i^\top F_i`, (p, p)."""
    idx = np.flatnonzero(w)
    f = blocks[idx] * np.sqrt(w[idx])[:, None, None]
    f = f.reshape(-1, blocks.shape[2])
    m = f.T @ f
    return 0.5 * (m + m.T)


def sensitivities(blocks: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    r""":math:`d_i = -\mathrm{tr}(\Gamma F_i^\top F_i)` for blocks (N, d, p) and :math:`\Gamma` (p, p), shape (N,)."""
    n, d, p = blocks.shape
    flat = blocks.reshape(n * d, p)
    return -np.sum((flat @ gamma) * flat, axis=1).reshape(n, d).sum(axis=1)


def mean_sensitivity(kind: str, value: float, n_params: int) -> float:
    r""":math:`\bar d = -\mathrm{tr}(\Gamma M)`: :math:`\Phi` for A, :math:`p` for D."""
    return float(value) if kind == "A" else float(n_params)


def lower_bound(kind: str, value: float, residual: float, n_params: int) -> float:
    r"""Normalised bound from :math:`\Phi(M(w))` and :math:`\rho`: :math:`\Phi/(1+\rho)` (A), :math:`\Phi - p\log(1+\rho)` (D)."""
    rho = max(float(residual), 0.0)
    return value / (1.0 + rho) if kind == "A" else value - n_params * np.log1p(rho)


def scale_to_poses(kind: str, value: float, n: int, n_params: int) -> float:
    r"""Normalised value to n poses: :math:`\Phi/n` (A), :math:`\Phi - p\log n` (D)."""
    return value / n if kind == "A" else value - n_params * np.log(n)


def efficiency(kind: str, bound: float, value: float, n_params: int) -> float:
    r"""bound/value (A) or :math:`\exp((\text{bound}-\text{value})/p)` (D); :math:`\le 1` when the bound holds."""
    return bound / value if kind == "A" else float(np.exp((bound - value) / n_params))


def _value(criterion: Criterion, m: np.ndarray) -> float:
    try:
        return float(criterion.compute_value(m))
    except NotIdentifiableError:
        return np.inf


# -------------------------------------------------------- approximate design
@dataclass(frozen=True, eq=False)
class ApproximateDesign:
    r"""Weights on candidates minimising :math:`\Phi(M(w))`, with their equivalence-theorem certificate.

    Attributes:
        criterion: Criterion name.
        kind: ``"A"`` or ``"D"``.
        weights: :math:`w` (N,), on the simplex, read-only.
        value: :math:`\Phi(M(w))`, normalised (one pose's worth of information).
        sensitivities: :math:`d_i(w)` (N,), read-only.
        mean_sensitivity: :math:`\bar d` (:math:`\Phi` for A, :math:`p` for D).
        lower_bound: Normalised bound on :math:`\min_w \Phi` over the candidates.
        iterations: Newton (or pairwise) steps.
        seconds: Wall time [s].
        converged: :math:`\rho \le` ``tol``.
        tol: The requested relative gap.
        n_params: :math:`p`.
        history: :math:`\rho` per iteration.
    """

    criterion: str
    kind: str
    weights: np.ndarray
    value: float
    sensitivities: np.ndarray
    mean_sensitivity: float
    lower_bound: float
    iterations: int
    seconds: float
    converged: bool
    tol: float
    n_params: int
    history: tuple[float, ...] = ()

    def __post_init__(self):
        for key in ("weights", "sensitivities"):
            a = np.array(getattr(self, key), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, key, a)

    @property
    def support(self) -> np.ndarray:
        """Indices of the candidates with positive weight."""
        return np.flatnonzero(self.weights > 0)

    @property
    def max_sensitivity(self) -> float:
        return float(self.sensitivities.max())

    def check(self) -> float:
        r"""Equivalence residual :math:`\rho = \max_i d_i/\bar d - 1` (0 at the optimum; the relative gap)."""
        return float(max(self.max_sensitivity / self.mean_sensitivity - 1.0, 0.0))

    def support_residual(self) -> float:
        r""":math:`\max_{i \in \mathrm{supp}} |d_i/\bar d - 1|` (0 at the optimum: equality on the support)."""
        return float(np.max(np.abs(self.sensitivities[self.support] / self.mean_sensitivity - 1.0)))

    def to_dict(self) -> dict:
        sup = self.support
        return {"criterion": self.criterion, "kind": self.kind, "value": self.value,
                "lower_bound": self.lower_bound, "residual": self.check(),
                "support_residual": self.support_residual(), "support": sup.tolist(),
                "support_weights": self.weights[sup].tolist(), "n_candidates": int(self.weights.size),
                "mean_sensitivity": self.mean_sensitivity, "max_sensitivity": self.max_sensitivity,
                "iterations": self.iterations, "seconds": self.seconds, "converged": self.converged,
                "tol": self.tol, "n_params": self.n_params, "history": list(self.history)}

    def summary(self) -> str:
        return (f"approximate {self.criterion}-optimal design on {self.weights.size} candidates: "
                f"value {self.value:.6g}, bound {self.lower_bound:.6g}, gap {self.check():.2e} "
                f"(tol {self.tol:g}, {'converged' if self.converged else 'NOT converged'}), "
                f"support {self.support.size}, {self.iterations} iterations, {self.seconds:.2f} s")


def _hessian(blocks_s: np.ndarray, gamma: np.ndarray, cov: np.ndarray, kind: str) -> np.ndarray:
    r""":math:`H_{ij} = \partial^2\Phi/\partial w_i\partial w_j` on the working set (derivations §12)."""
    s, d, p = blocks_s.shape
    flat = blocks_s.reshape(s * d, p)
    u = flat @ (-gamma) @ flat.T
    v = flat @ cov @ flat.T
    h = (u * v).reshape(s, d, s, d).sum(axis=(1, 3))
    h = (2.0 if kind == "A" else 1.0) * h
    return 0.5 * (h + h.T)


def _newton_direction(h: np.ndarray, grad: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    r"""Step :math:`s` of :math:`\min \tfrac12 s^\top H s + g^\top s`, :math:`\mathbf 1^\top s = 0`,
    :math:`-w \le s \le 1 - w`, by the deterministic active-set QP
    (:func:`calib_oed.solver.simplex_qp.solve_simplex_qp`), started at :math:`s = 0` (the
    support free, every other candidate at its bound); ``None`` if it fails.
    """
    m = w.size
    # H is singular for rank-deficient W (kpi: rank 3) once the working set is large; a
    # Levenberg term keeps the KKT systems regular and the step a descent one
    reg = NEWTON_REGULARISATION * max(float(np.max(np.diag(h))), 1e-300)
    step = solve_simplex_qp(h + reg * np.eye(m), grad, np.ones(m), -w, 1.0 - w, np.zeros(m))
    if step is None or not np.all(np.isfinite(step)) or abs(step.sum()) > 1e-6 or np.min(w + step) < -1e-6:
        return None
    return step


def _pairwise(criterion, blocks, w, d, value):
    """Vertex-exchange step: move weight from the worst support point to the best candidate."""
    sup = np.flatnonzero(w)
    lo, hi = sup[np.argmin(d[sup])], int(np.argmax(d))
    best_w, best_v = w, value
    for a in w[lo] * 0.5 ** np.arange(30):
        trial = w.copy()
        trial[lo] -= a
        trial[hi] += a
        v = _value(criterion, information(blocks, trial))
        if v < best_v:
            best_w, best_v = trial, v
            break
    return best_w, best_v


def _initial_weights(blocks, start, criterion) -> np.ndarray:
    n, d, p = blocks.shape
    if start is not None:
        idx = np.unique(np.asarray(start, dtype=np.intp))
        if idx.size == 0 or idx.min() < 0 or idx.max() >= n:
            raise CertificateError("start", np.asarray(start).tolist()[:10],
                                   f"must be candidate indices in [0, {n})")
        w = np.zeros(n)
        w[idx] = 1.0 / idx.size
        if np.isfinite(_value(criterion, information(blocks, w))):
            return w
    w = np.full(n, 1.0 / n)
    m = information(blocks, w)
    try:
        gamma = criterion.compute_gradient(m)
    except NotIdentifiableError as exc:
        raise NotIdentifiableError(exc.names, f"the {n} candidates together do not identify the "
                                   "parameters; no design on them has a finite criterion") from None
    order = np.argsort(-sensitivities(blocks, gamma))
    k = min(n, max(2 * p, 4 * -(-p // d)))
    while True:  # the most sensitive candidates of the uniform design, enough of them to be regular
        w = np.zeros(n)
        w[order[:k]] = 1.0 / k
        if k == n or np.isfinite(_value(criterion, information(blocks, w))):
            return w
        k = min(n, 2 * k)


def solve_approximate(
    blocks,
    criterion: Criterion,
    *,
    start=None,
    weights=None,
    tol: float = 1e-4,
    max_iterations: int = 500,
) -> ApproximateDesign:
    r"""The approximate design minimising :math:`\Phi(M(w))` over candidates, to a certified gap.

    Args:
        blocks: Candidate rows :math:`F_i`, (N, d, p).
        criterion: An A-type criterion or D.
        start: Candidate indices whose uniform design starts the solver
            (default: the most sensitive candidates of the uniform design).
        weights: Start weights (N,) instead (e.g. a previous solution, padded).
        tol: Stop when the equivalence residual :math:`\rho \le` tol (the
            relative gap of the bound; module docstring).
        max_iterations: Most Newton steps. Each adds up to :math:`p` violating candidates
            to the working set.

    Raises:
        CertificateError: unsupported criterion, bad tolerance, start or weights.
        ShapeError, NonFiniteError: bad blocks.
        NotIdentifiableError: no design on the candidates identifies the parameters.
    """
    t0 = time.perf_counter()
    blocks = check_blocks(blocks, "candidate blocks")
    kind = criterion_kind(criterion)
    n, d, p = blocks.shape
    if not (np.isfinite(tol) and 0 < tol < 1):
        raise CertificateError("tol", tol, "must be a relative gap in (0, 1), e.g. 1e-4")
    if int(max_iterations) != max_iterations or max_iterations < 0:
        raise CertificateError("max_iterations", max_iterations, "must be an integer >= 0")
    if weights is not None:
        w = np.array(weights, dtype=float)
        if w.shape != (n,) or not np.all(np.isfinite(w)) or w.min() < 0 or w.sum() <= 0:
            raise CertificateError("weights", "array", f"must be ({n},), finite, >= 0, not all 0")
        w = w / w.sum()
        if not np.isfinite(_value(criterion, information(blocks, w))):
            w = _initial_weights(blocks, start, criterion)
    else:
        w = _initial_weights(blocks, start, criterion)
    m = information(blocks, w)
    value = _value(criterion, m)
    history, it = [], 0
    while True:
        gamma = criterion.compute_gradient(m)
        dsen = sensitivities(blocks, gamma)
        dbar = mean_sensitivity(kind, value, p)
        rho = max(float(dsen.max()) / dbar - 1.0, 0.0)
        history.append(rho)
        if rho <= tol or it >= max_iterations:
            break
        it += 1
        sup = np.flatnonzero(w)
        viol = np.setdiff1d(np.argsort(-dsen)[: p + sup.size], sup)
        viol = viol[dsen[viol] > dbar][:p]
        work = np.concatenate([sup, viol])
        cov = scipy.linalg.cho_solve((scipy.linalg.cholesky(m, lower=True), True), np.eye(p))
        h = _hessian(blocks[work], gamma, cov, kind) / dbar
        grad = -dsen[work] / dbar
        step = _newton_direction(h, grad, w[work])
        new_w, new_v = w, value
        if step is not None and grad @ step < 0:
            for alpha in 0.5 ** np.arange(30):
                trial = w.copy()
                trial[work] = np.maximum(w[work] + alpha * step, 0.0)
                trial[trial < DROP_WEIGHT] = 0.0
                trial /= trial.sum()
                v = _value(criterion, information(blocks, trial))
                if v <= value + 1e-4 * alpha * dbar * (grad @ step):
                    new_w, new_v = trial, v
                    break
        if new_v >= value:
            new_w, new_v = _pairwise(criterion, blocks, w, dsen, value)
            if new_v >= value:  # no descent found: numerical floor
                break
        w, value = new_w, new_v
        m = information(blocks, w)
    return ApproximateDesign(
        criterion=criterion.name, kind=kind, weights=w, value=value, sensitivities=dsen,
        mean_sensitivity=dbar, lower_bound=lower_bound(kind, value, rho, p), iterations=it,
        seconds=time.perf_counter() - t0, converged=rho <= tol, tol=float(tol), n_params=p,
        history=tuple(history))
