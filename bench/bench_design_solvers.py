"""Benchmark: our SQP against IPOPT, trust-constr and SLSQP on the same design NLP, same start.

Run from the repository root (IPOPT needs the bench extra and Debian's
``coinor-libipopt-dev liblapack-dev libblas-dev pkg-config`` to build cyipopt):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_design_solvers.py [--scene fms_kr16]
        [--poses 60] [--seed 0] [--pool 3000]
        [--solvers sqp-exact,sqp-bfgs,ipopt-exact,ipopt-exact-active,ipopt-lbfgs,trust-constr,slsqp]
        [--time-limit 300] [--step-bound RAD] [--trace]

Every solver gets the same NLP (:class:`calib_oed.oed.problem.DesignProblem`:
objective scaled to 1 at the start, exact gradient, the same constraint rows
with their sparse block-diagonal Jacobian, joint limits as bounds) from the
same start, the exchange algorithm's design of the default pipeline. Each is
given its best shot: IPOPT the sparse Jacobian structure and the exact
Lagrangian Hessian (per-pose blocks plus the dense low-rank coupling, lower
triangle; ``ipopt-exact-active`` with the constraints' curvature only for rows whose multiplier is
at least ``ACTIVE_CURVATURE`` times the largest, as the SQP computes it for its active rows only),
or its L-BFGS; our SQP as the design runs it (exact Hessian or per-pose BFGS blocks, kinked rows' pieces, trial points
by their values alone, traced like every other evaluation); trust-constr the sparse Jacobian and the exact
Hessians of the objective and of the constraints as separate callbacks; SLSQP
(which takes no Hessian) dense Jacobians. Reported per solver: the final
objective, whether the last iterate is feasible (1e-6), its status, the CPU
time (``time.process_time``) and wall time to the end, and the CPU time at
which it first reached a feasible point within 1 % of the best final
objective of all solvers. Results: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import scipy
import scipy.optimize
import scipy.sparse
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import setup
from calib_oed.oed.design import DESIGN_SQP
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem
from calib_oed.oed.refine import sqp_settings
from calib_oed.oed.starts import candidate_pool, exchange_start
from calib_oed.scene.reader import load_scene
from calib_oed.solver.sqp import solve_sqp

FEASIBLE = 1e-6


class Trace:
    """Objective value, feasibility and CPU time of every objective evaluation."""

    def __init__(self, nlp: DesignProblem):
        self.nlp = nlp
        self.cpu0 = time.process_time()
        self.points: list[tuple[float, float, bool]] = []
        self.violations: list[float] = []

    def _seen(self, x, f) -> None:
        """Record ``f`` at ``x`` with the CPU so far and whether ``x`` is feasible (that check not charged)."""
        t = time.process_time() - self.cpu0
        pause = time.process_time()
        violation = self.nlp.max_violation(x)
        self.cpu0 += time.process_time() - pause
        self.points.append((t, f, violation <= FEASIBLE))
        self.violations.append(violation)

    def objective(self, x):
        f, g = self.nlp.compute_objective(x)
        self._seen(x, f)
        return f, g

    def values(self, x):
        """The SQP's trial points without derivatives (``values``), traced like :meth:`objective`."""
        f, c = self.nlp.compute_values(x)
        self._seen(x, f)
        return f, c

    def cpu_to(self, target: float) -> float:
        return next((t for t, f, ok in self.points if ok and f <= target), float("nan"))


def run_sqp(nlp, x0, exact: bool, time_limit: float, step_bound: float | None = None):
    from dataclasses import replace

    trace = Trace(nlp)
    # as the design runs it (calib_oed.oed.refine.optimise_from): the exact Hessian's trust rule,
    # per-pose blocks, kinked rows' pieces; ``step_bound``: another first box than the design's
    settings = sqp_settings(replace(DESIGN_SQP, time_limit=time_limit), exact)
    if step_bound is not None:
        settings = replace(settings, step_bound=step_bound)
    kwargs = {"lagrangian_hessian": nlp.compute_lagrangian_hessian} if exact else {}
    res = solve_sqp(trace.objective, x0, constraints=nlp.compute_constraints, bounds=nlp.bounds,
                    settings=settings, block_size=nlp.nq, row_pieces=nlp.compute_row_pieces,
                    values=trace.values, **kwargs)
    return res.x, trace, f"{res.status.value}, {res.iterations} it"


ACTIVE_CURVATURE = 1e-6
"""``ipopt-exact-active``: rows whose IPOPT multiplier is below this times the largest get no curvature
(an interior point's multipliers are never 0, so without it every row's curvature is computed, where
the SQP computes those of its QP's active rows only)."""


def run_ipopt(nlp, x0, exact: bool, time_limit: float, active_only: bool = False):
    try:
        import cyipopt
    except ImportError:
        return None, None, "cyipopt not installed (bench extra; see the module docstring)"
    n = x0.size
    c0, _ = nlp.compute_constraints(x0)
    m = c0.size // nlp.n
    # block-diagonal structure, fixed for all x: entry (j, i, k) of the (n, m, nq) blocks
    j, i, k = np.meshgrid(np.arange(nlp.n), np.arange(m), np.arange(nlp.nq), indexing="ij")
    jrow, jcol = (j * m + i).ravel(), (j * nlp.nq + k).ravel()
    tril = np.tril_indices(n)
    trace = Trace(nlp)
    lb, ub = nlp.bounds

    class Problem:
        def objective(self, x):
            return trace.objective(x)[0]

        def gradient(self, x):
            return nlp.compute_objective(x)[1]

        def constraints(self, x):
            return nlp.compute_constraint_rows(x, False)[0].ravel()

        def jacobianstructure(self):
            return jrow, jcol

        def jacobian(self, x):
            return nlp.compute_constraint_rows(x, True)[1].ravel()

        def hessianstructure(self):
            return tril

        def hessian(self, x, lagrange, obj_factor):
            # IPOPT's Lagrangian is obj_factor f + sum lagrange_i c_i; ours is f - lam^T c
            hf = nlp.compute_lagrangian_hessian(x, np.zeros_like(lagrange)).dense()
            q = nlp.configurations(x)
            lam = np.asarray(lagrange, dtype=float).reshape(nlp.n, -1)
            if active_only:  # the SQP's shortcut: curvature of the rows that hold the design only
                lam = np.where(np.abs(lam) >= ACTIVE_CURVATURE * np.max(np.abs(lam), initial=0.0), lam, 0.0)
            hc = nlp.feasibility.compute_lagrangian_hessian(q, lam, kinds=nlp.kinds)
            h = obj_factor * hf
            for j in range(nlp.n):
                sl = slice(j * nlp.nq, (j + 1) * nlp.nq)
                h[sl, sl] += hc[j]
            return h[tril]

    prob = cyipopt.Problem(n=n, m=c0.size, problem_obj=Problem(), lb=lb, ub=ub,
                           cl=np.zeros(c0.size), cu=np.full(c0.size, 2e19))
    prob.add_option("print_level", 0)
    prob.add_option("max_cpu_time", float(time_limit))
    prob.add_option("max_iter", 3000)
    prob.add_option("tol", 1e-8)
    prob.add_option("hessian_approximation", "exact" if exact else "limited-memory")
    x, info = prob.solve(x0)
    return x, trace, f"{info['status_msg'].decode() if isinstance(info['status_msg'], bytes) else info['status_msg']}"


def run_scipy(nlp, x0, method: str, time_limit: float):
    trace = Trace(nlp)
    lb, ub = nlp.bounds
    deadline = time.process_time() + time_limit

    class Timeout(Exception):
        pass

    def fun(x):
        if time.process_time() > deadline:
            raise Timeout
        return trace.objective(x)

    if method == "SLSQP":
        cons = {"type": "ineq", "fun": lambda x: nlp.compute_constraint_rows(x, False)[0].ravel(),
                "jac": lambda x: nlp.compute_constraints(x)[1].toarray()}
        opts, hess = {"maxiter": 3000, "ftol": 1e-12}, None
    else:
        def cons_hess(x, v):  # sum v_i hess c_i, block diagonal, sparse
            hc = nlp.feasibility.compute_lagrangian_hessian(nlp.configurations(x),
                                                            np.asarray(v).reshape(nlp.n, -1), kinds=nlp.kinds)
            return scipy.sparse.block_diag(list(hc), format="csr")

        cons = scipy.optimize.NonlinearConstraint(
            lambda x: nlp.compute_constraint_rows(x, False)[0].ravel(), 0.0, np.inf,
            jac=lambda x: nlp.compute_constraints(x)[1], hess=cons_hess)
        opts = {"maxiter": 5000, "gtol": 1e-8, "xtol": 1e-12}

        def hess(x):
            return nlp.compute_lagrangian_hessian(x, np.zeros(0)).dense()
    try:
        res = scipy.optimize.minimize(fun, x0, jac=True, hess=hess, method=method,
                                      bounds=scipy.optimize.Bounds(lb, ub), constraints=[cons],
                                      options=opts)
        return res.x, trace, f"{res.message} ({res.nit} it)"
    except Timeout:
        return None, trace, f"stopped at the {time_limit:.0f} s CPU limit"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="fms_kr16")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pool", type=int, default=3000)
    ap.add_argument("--solvers", default="sqp-exact,sqp-bfgs,ipopt-exact,ipopt-lbfgs,trust-constr,slsqp")
    ap.add_argument("--time-limit", type=float, default=300.0, help="CPU seconds per solver")
    ap.add_argument("--trace", action="store_true",
                    help="every point a solver evaluated: CPU, value [mm²], largest violation")
    ap.add_argument("--step-bound", type=float, default=None,
                    help="our SQP's first trust box [rad] (default: the design's, DESIGN_STEP_BOUND)")
    args = ap.parse_args(argv)
    print(f"# {platform.node()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
          f"numpy {np.__version__}, scipy {scipy.__version__}")
    s = setup(load_scene(args.scene))
    objective = DesignObjective(s.problem, "kpi")
    with threadpool_limits(limits=1, user_api="blas"):
        pool = candidate_pool(s, args.pool, args.seed)
        q0, _ = exchange_start(objective, pool, args.poses, args.seed)
        phi0 = objective.compute_value(q0)
        runs = {}
        for name in args.solvers.split(","):
            nlp = DesignProblem(objective, s.feasibility, args.poses, scale=phi0)
            x0 = q0.ravel().copy()
            wall, cpu = time.perf_counter(), time.process_time()
            if name.startswith("sqp"):
                x, trace, status = run_sqp(nlp, x0, name == "sqp-exact", args.time_limit, args.step_bound)
            elif name.startswith("ipopt"):
                x, trace, status = run_ipopt(nlp, x0, name.startswith("ipopt-exact"), args.time_limit,
                                             active_only=name == "ipopt-exact-active")
            else:
                x, trace, status = run_scipy(nlp, x0, {"trust-constr": "trust-constr", "slsqp": "SLSQP"}[name],
                                             args.time_limit)
            cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
            final = None if x is None else nlp.compute_objective(x)[0] * phi0
            feasible = None if x is None else nlp.max_violation(x) <= FEASIBLE
            runs[name] = (final, feasible, status, cpu, wall, trace)
            print(f"{name}: {status}; value {final}, feasible {feasible}, {cpu:.1f} s CPU", flush=True)
            if args.trace and trace:
                for k, ((t, f, _), v) in enumerate(zip(trace.points, trace.violations, strict=True)):
                    print(f"  {name} point {k}: {t:6.3f} s CPU, {f * phi0:.5e} mm², violation {v:.1e}")
    best = min(r[0] for r in runs.values() if r[0] is not None and r[1])
    print(f"\n{args.scene}, {args.poses} poses, exchange start {phi0:.5e} mm²; best {best:.5e} mm²")
    print(f"{'solver':13s} {'final [mm²]':>12s} {'feasible':>8s} {'CPU [s]':>8s} {'wall [s]':>8s} "
          f"{'CPU to 1%':>9s}  status")
    ref = runs.get("sqp-exact")
    for name, (final, feasible, status, cpu, wall, trace) in runs.items():
        to1 = trace.cpu_to(1.01 * best / phi0) if trace else float("nan")
        shown = "-" if final is None else f"{final:.5e}"
        print(f"{name:13s} {shown:>12s} {feasible!s:>8s} {cpu:8.1f} {wall:8.1f} {to1:9.1f}  {status}")
    if ref and ref[5]:
        t_ref = ref[5].cpu_to(1.01 * best / phi0)
        for name, run in runs.items():
            if name != "sqp-exact" and run[5]:
                print(f"CPU to 1 %: {name} / sqp-exact = {run[5].cpu_to(1.01 * best / phi0) / t_ref:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
