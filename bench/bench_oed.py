"""Benchmark: the KPI-optimal design on fms_kr16 — our SQP against general-purpose NLP solvers,
and design quality against the baselines.

Run from the repository root:

    .venv/bin/python bench/bench_oed.py [--scene fms_kr16] [--poses 60] [--seed 0]
        [--solvers sqp,slsqp,trust-constr,ipopt] [--time-limit 300] [--heuristics 10] [--pool 3000]
        [--max-iterations 300] [--no-quality]

Every solver gets the same NLP (:class:`calib_oed.oed.problem.DesignProblem`:
objective scaled to 1 at the start, exact gradient, the same constraint rows
with their sparse exact Jacobian, joint limits as bounds) from the same
heuristic start. For each solver the run prints its final objective, whether
its last iterate is feasible, the wall time to converge, and the time at which
it first reached a feasible point within 1 % of our SQP's final objective
("time to 1 %"); the ratio to our SQP is the result. IPOPT runs through
casadi's bundled IPOPT when ``casadi`` is installed (``pip install casadi``),
with a limited-memory Hessian.

The quality table compares the KPI average variance [mm²] of the heuristic
designs (median over ``--heuristics`` seeds), the exchange algorithm's best
KPI design from a ``--pool``-pose feasible pool, the C_p-optimal design
(state of the art) and the KPI-optimal design (the paper's method).
Recorded in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np
import scipy
import scipy.optimize
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.oed.design import design, evaluate_design, exchange_baseline
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import DesignProblem
from calib_oed.scene.reader import load_scene
from calib_oed.solver.sqp import SQPSettings, solve_sqp


class Trace:
    """Objective, feasibility and time of every evaluation, to find the time to 1 %."""

    def __init__(self, nlp: DesignProblem, tol_feasibility: float = 1e-6):
        self.nlp = nlp
        self.tol = tol_feasibility
        self.t0 = time.perf_counter()
        self.points: list[tuple[float, float, bool]] = []
        self._last_x = None
        self._last = None

    def objective(self, x):
        f, g = self.nlp.compute_objective(x)
        elapsed = time.perf_counter() - self.t0
        # feasibility of this point is checked outside the timed region
        pause = time.perf_counter()
        viol = self.nlp.max_violation(x)
        self.t0 += time.perf_counter() - pause
        self.points.append((elapsed, f, viol <= self.tol))
        return f, g

    def time_to(self, target: float) -> float:
        for t, f, ok in self.points:
            if ok and f <= target:
                return t
        return float("nan")


def run_sqp(nlp, x0, max_iterations):
    trace = Trace(nlp)
    start = time.perf_counter()
    res = solve_sqp(trace.objective, x0, constraints=nlp.compute_constraints, bounds=nlp.bounds,
                    settings=SQPSettings(max_iterations=max_iterations))
    return res.x, time.perf_counter() - start, trace, f"{res.status.value}, {res.iterations} it"


def run_scipy(nlp, x0, method, time_limit):
    trace = Trace(nlp)
    lb, ub = nlp.bounds
    deadline = time.perf_counter() + time_limit

    class Timeout(Exception):
        pass

    def fun(x):
        if time.perf_counter() > deadline:
            raise Timeout
        return trace.objective(x)

    if method == "SLSQP":
        cons = {"type": "ineq", "fun": lambda x: nlp.compute_constraint_rows(x, False)[0].ravel(),
                "jac": lambda x: nlp.compute_constraints(x)[1].toarray()}
        opts = {"maxiter": 1000, "ftol": 1e-10}
    else:
        cons = scipy.optimize.NonlinearConstraint(
            lambda x: nlp.compute_constraint_rows(x, False)[0].ravel(), 0.0, np.inf,
            jac=lambda x: nlp.compute_constraints(x)[1])
        opts = {"maxiter": 3000, "gtol": 1e-8, "xtol": 1e-10}
    start = time.perf_counter()
    try:
        res = scipy.optimize.minimize(fun, x0, jac=True, method=method, bounds=list(zip(lb, ub, strict=True)),
                                      constraints=[cons], options=opts)
        x, status = res.x, f"{res.message} ({res.nit} it)"
    except Timeout:
        best = min((p for p in trace.points if p[2]), key=lambda p: p[1], default=None)
        x, status = None, f"stopped at the {time_limit:.0f} s limit (best feasible {best[1] if best else 'none'})"
    return x, time.perf_counter() - start, trace, status


def run_ipopt(nlp, x0, time_limit):
    try:
        import casadi
    except ImportError:
        return None, float("nan"), None, "casadi not installed (pip install casadi)"
    n = x0.size
    m = nlp.compute_constraint_rows(x0, False)[0].size
    trace = Trace(nlp)

    # IPOPT sees exact first derivatives (dense Jacobian blocks through a casadi
    # Callback), a limited-memory Hessian and the same bounds.
    x = casadi.MX.sym("x", n)

    class Model(casadi.Callback):
        def __init__(self):
            casadi.Callback.__init__(self)
            self.construct("model", {"enable_fd": False})

        def get_n_in(self):
            return 1

        def get_n_out(self):
            return 2

        def get_sparsity_in(self, i):
            return casadi.Sparsity.dense(n, 1)

        def get_sparsity_out(self, i):
            return casadi.Sparsity.dense(1, 1) if i == 0 else casadi.Sparsity.dense(m, 1)

        def eval(self, arg):
            xv = np.array(arg[0]).ravel()
            f, _ = nlp.compute_objective(xv)
            c, _ = nlp.compute_constraint_rows(xv, False)
            return [f, c.ravel()]

        def has_jacobian(self):
            return True

        def get_jacobian(self, name, inames, onames, opts):
            self._jac = JacobianCallback(name, opts)
            return self._jac

    class JacobianCallback(casadi.Callback):
        """Inputs: x and the two nominal outputs; outputs: df/dx (1, n), dc/dx (m, n)."""

        def __init__(self, name, opts):
            casadi.Callback.__init__(self)
            self.construct(name, opts)

        def get_n_in(self):
            return 3

        def get_n_out(self):
            return 2

        def get_sparsity_in(self, i):
            return [casadi.Sparsity.dense(n, 1), casadi.Sparsity.dense(1, 1),
                    casadi.Sparsity.dense(m, 1)][i]

        def get_sparsity_out(self, i):
            return casadi.Sparsity.dense(1, n) if i == 0 else casadi.Sparsity.dense(m, n)

        def eval(self, arg):
            xv = np.array(arg[0]).ravel()
            _, g = trace.objective(xv)
            _, a = nlp.compute_constraints(xv)
            return [g[None, :], a.toarray()]

    model = Model()
    f_sym, c_sym = model(x)
    lb, ub = nlp.bounds
    solver = casadi.nlpsol("ipopt", "ipopt", {"x": x, "f": f_sym, "g": c_sym},
                           {"ipopt.hessian_approximation": "limited-memory", "ipopt.print_level": 0,
                            "print_time": False, "ipopt.max_cpu_time": float(time_limit),
                            "ipopt.tol": 1e-8})
    start = time.perf_counter()
    sol = solver(x0=x0, lbx=lb, ubx=ub, lbg=0.0, ubg=np.inf)
    status = solver.stats()["return_status"]
    return np.array(sol["x"]).ravel(), time.perf_counter() - start, trace, status


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fms_kr16")
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--solvers", default="sqp,slsqp,trust-constr,ipopt")
    parser.add_argument("--time-limit", type=float, default=300.0, help="per general-purpose solver [s]")
    parser.add_argument("--heuristics", type=int, default=10)
    parser.add_argument("--pool", type=int, default=3000)
    parser.add_argument("--no-quality", action="store_true")
    parser.add_argument("--max-iterations", type=int, default=300, help="of our SQP (default 300)")
    args = parser.parse_args(argv)
    print(f"# {' '.join(['.venv/bin/python', 'bench/bench_oed.py'] + (sys.argv[1:] if argv is None else argv))}")
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}")
    s = setup(load_scene(args.scene))
    q0 = heuristic_design(s, args.poses, args.seed)
    objective = DesignObjective(s.problem, "kpi")
    phi0 = objective.compute_value(q0)
    x0 = q0.ravel()
    solvers = args.solvers.split(",")
    rows = []
    ours = None
    for name in solvers:
        nlp = DesignProblem(objective, s.feasibility, args.poses, scale=phi0)
        if name == "sqp":
            x, secs, trace, status = run_sqp(nlp, x0, args.max_iterations)
        elif name in ("slsqp", "trust-constr"):
            x, secs, trace, status = run_scipy(nlp, x0, "SLSQP" if name == "slsqp" else "trust-constr",
                                               args.time_limit)
        elif name == "ipopt":
            x, secs, trace, status = run_ipopt(nlp, x0, args.time_limit)
        else:
            raise SystemExit(f"unknown solver {name!r}; choose from sqp, slsqp, trust-constr, ipopt")
        if x is None and trace is not None:
            feasible = [p for p in trace.points if p[2]]
            final, viol = (min(p[1] for p in feasible), 0.0) if feasible else (float("nan"), float("nan"))
        elif x is None:
            final, viol = float("nan"), float("nan")
        else:
            final, viol = nlp.compute_objective(x)[0], nlp.max_violation(x)
        if name == "sqp":
            ours = final
        rows.append((name, final, viol, secs, trace, status))
    print(f"\nKPI-optimal design, {args.poses} poses, start = heuristic seed {args.seed} "
          f"(phi0 = {phi0:.4e} mm²); objective = phi/phi0")
    print(f"{'solver':14s} {'final phi/phi0':>14s} {'max viol':>9s} {'wall [s]':>9s} "
          f"{'to 1% [s]':>10s} {'ratio':>7s}  status")
    t_ours = None
    for name, final, viol, secs, trace, status in rows:
        t1 = trace.time_to(ours * 1.01) if (trace is not None and ours is not None) else float("nan")
        if name == "sqp":
            t_ours = t1
        ratio = t1 / t_ours if t_ours else float("nan")
        print(f"{name:14s} {final:14.6f} {viol:9.1e} {secs:9.2f} {t1:10.2f} {ratio:7.1f}  {status}")
    if args.no_quality:
        return 0
    print(f"\nDesign quality, KPI average variance [mm²] ({args.poses} poses)")
    heur = [evaluate_design(s, heuristic_design(s, args.poses, k), "kpi").kpi_variance
            for k in range(args.heuristics)]
    med = float(np.median(heur))
    t = time.perf_counter()
    ex = exchange_baseline(s, args.poses, "kpi", pool=args.pool, seed=args.seed)
    t_ex = time.perf_counter() - t
    cp = design(s, args.poses, "params", seed=args.seed)
    kp = design(s, args.poses, "kpi", seed=args.seed)
    t = time.perf_counter()
    kx = design(s, args.poses, "kpi", start=ex.q, seed=args.seed)
    t_kx = time.perf_counter() - t + t_ex
    print(f"{'design':34s} {'KPI avg var':>12s} {'/ heuristic':>12s} {'/ C_p-opt':>10s} {'time [s]':>9s}")
    table = [(f"heuristic median of {args.heuristics}", med, 0.0),
             (f"exchange KPI, pool {args.pool}", ex.kpi_variance, t_ex),
             ("C_p-optimal (SQP, params)", cp.kpi_variance, cp.seconds),
             ("KPI-optimal (SQP, kpi)", kp.kpi_variance, kp.seconds),
             ("KPI-optimal from the exchange design", kx.kpi_variance, t_kx)]
    for name, v, secs in table:
        print(f"{name:34s} {v:12.4e} {v / med:12.1%} {v / cp.kpi_variance:10.1%} {secs:9.2f}")
    print(f"KPI-optimal feasible: {kp.feasible} ({kp.solver['iterations']} it, {kp.solver['status']}); "
          f"C_p-optimal feasible: {cp.feasible}; exchange feasible: {ex.feasible}; "
          f"KPI-optimal from exchange feasible: {kx.feasible} ({kx.solver['iterations']} it)")
    return 0


if __name__ == "__main__":
    # every solver with single-threaded BLAS, as calib_oed.oed.design runs ours
    with threadpool_limits(limits=1, user_api="blas"):
        raise SystemExit(main())
