r"""Benchmark: the SQP with the exact structured Hessian against BFGS, and the bounded QP size.

Run from the repository root:

    .venv/bin/python bench/bench_sqp_structured.py [--poses 60] [--params 10] [--rows 60]
        [--seed 0] [--max-iterations 300] [--stress-rows 300] [--skip-compare] [--skip-stress]

A synthetic design problem shaped like ``calib_oed.oed.problem.DesignProblem``
(the solver knows no robot, so neither does this): P poses of 6 joints,
:math:`x = \mathrm{vec}(q) \in \mathbb{R}^{6P}` [rad] in :math:`[-\pi, \pi]`,
per pose a sensitivity :math:`F_j = F(q_j) \in \mathbb{R}^{3 \times p}` with
:math:`F_{ab}(q) = \sin(w_{ab}^\top q + \beta_{ab})`, information
:math:`M = \epsilon P I + \sum_j F_j^\top F_j`, the A criterion
:math:`\phi = \mathrm{tr}(M^{-1}) / \phi(q^0)`, and per pose ``--rows``
curved "obstacle" rows :math:`\|q_j - o_{ji}\|^2 - \rho^2 \ge 0` (concave, like
collision distances) around a feasible start. The exact Hessian of
:math:`L = \phi - \lambda^\top c` is per-pose blocks
:math:`\mathrm{tr}(\Gamma\, \partial_{kl} M_j) + 2 \sum_i \lambda_{ji} I` (indefinite)
plus the coupling :math:`\nabla^2\Phi[M_a, M_b] = U U^\top` with
:math:`p^2` columns (:math:`U_{a,(i,f)} = \sqrt{2/s}\,(R^\top M_a C e_i)_f`,
:math:`C = M^{-1} = R R^\top`); it is checked against finite differences of
the gradient before the runs.

Part 1 (compare): the same problem from the same start with dense BFGS, the
per-pose BFGS blocks the design driver uses (``block_size=6``), and the exact
Hessian (``abs``/``floor`` modification, per block and whole-matrix).
Part 2 (stress): ``--stress-rows`` rows per pose and the trust region at
``max_step_bound`` from the start, the situation that aborted the process on
a Panda cell before issue 16 (a dense QP of 31,616 rows): the QP rows stay at
``max_qp_rows`` and the QPs above ``max_dense_qp_size`` go to the sparse backend.
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time

import numpy as np
import scipy.sparse as sp
from threadpoolctl import threadpool_limits

from calib_oed.solver.proxqp_build import proxsuite
from calib_oed.solver.result import StructuredHessian
from calib_oed.solver.sqp import SQPSettings, solve_sqp


class SyntheticDesign:
    """The synthetic A-optimal design problem of the module docstring."""

    def __init__(self, poses, params, rows, seed, rho=0.25):
        rng = np.random.default_rng(seed)
        self.P, self.p, self.d, self.nv = poses, params, 3, 6
        self.W = rng.standard_normal((self.d, params, self.nv))
        self.beta = rng.uniform(0, 2 * np.pi, (self.d, params))
        self.prior = 1e-3 * poses * np.eye(params)
        self.q0 = rng.uniform(-2.0, 2.0, (poses, self.nv))
        direction = rng.standard_normal((poses, rows, self.nv))
        direction /= np.linalg.norm(direction, axis=2, keepdims=True)
        self.obstacles = self.q0[:, None, :] + direction * rng.uniform(0.3, 2.0, (poses, rows, 1))
        self.rho2 = rho**2
        self.scale = 1.0
        self.scale = self.value(self.q0.ravel())
        cols = (np.arange(poses)[:, None, None] * self.nv + np.arange(self.nv)).repeat(rows, axis=1)
        self._cols = cols.reshape(-1)
        self._ptr = np.arange(0, poses * rows * self.nv + 1, self.nv)

    def _features(self, x):
        q = x.reshape(self.P, self.nv)
        arg = np.einsum("abk,jk->jab", self.W, q) + self.beta
        return np.sin(arg), np.cos(arg)

    def _information(self, f):
        return self.prior + np.einsum("jab,jac->bc", f, f)

    def value(self, x):
        return float(np.trace(np.linalg.inv(self._information(self._features(x)[0])))) / self.scale

    def objective(self, x):
        f, c = self._features(x)
        C = np.linalg.inv(self._information(f))
        gamma = -C @ C / self.scale
        fd = c[..., None] * self.W  # dF/dq_k: (P, d, p, nv)
        grad = 2 * np.einsum("jab,bc,jack->jk", f, gamma, fd)
        return float(np.trace(C)) / self.scale, grad.ravel()

    def constraints(self, x):
        diff = x.reshape(self.P, 1, self.nv) - self.obstacles
        c = np.sum(diff**2, axis=2).ravel() - self.rho2
        jac = sp.csr_matrix((2 * diff.reshape(-1), self._cols, self._ptr), shape=(c.size, x.size))
        return c, jac

    def hessian(self, x, lam):
        f, c = self._features(x)
        C = np.linalg.inv(self._information(f))
        gamma = -C @ C / self.scale
        fd = c[..., None] * self.W  # (P, d, p, nv)
        fdd = -f[..., None, None] * self.W[..., :, None] * self.W[..., None, :]  # (P, d, p, nv, nv)
        fg = f @ gamma  # (P, d, p)
        blocks = 2 * np.einsum("jab,jabkl->jkl", fg, fdd)
        blocks += 2 * np.einsum("jabk,bc,jacl->jkl", fd, gamma, fd)
        blocks = 0.5 * (blocks + blocks.transpose(0, 2, 1))
        blocks += 2 * lam.reshape(self.P, -1).sum(axis=1)[:, None, None] * np.eye(self.nv)
        # coupling: M_a = F_j^T dF_k + dF_k^T F_j, U[a, (i, f)] = sqrt(2/s) (R^T M_a C e_i)_f
        L = np.linalg.cholesky(self._information(f))
        R = np.linalg.inv(L).T  # C = R R^T
        ma = np.einsum("jab,jack->jkbc", f, fd)
        ma = ma + ma.transpose(0, 1, 3, 2)  # (P, nv, p, p)
        u = np.einsum("fb,jkbc,ci->jkif", R.T, ma, C) * np.sqrt(2.0 / self.scale)
        return StructuredHessian(blocks, u.reshape(self.P * self.nv, -1))

    def check_derivatives(self, rng, h=1e-6):
        """Largest relative error of the gradient and of H v against central differences."""
        x = self.q0.ravel() + 0.1 * rng.standard_normal(self.q0.size)
        v = rng.standard_normal(x.size)
        g = self.objective(x)[1]
        g_fd = (self.value(x + h * v) - self.value(x - h * v)) / (2 * h)
        hv = self.hessian(x, np.zeros(self.P * self.obstacles.shape[1])) @ v
        hv_fd = (self.objective(x + h * v)[1] - self.objective(x - h * v)[1]) / (2 * h)
        return abs(g @ v - g_fd) / abs(g_fd), np.abs(hv - hv_fd).max() / np.abs(hv_fd).max()


def _row(label, res, seconds):
    qp = res.times.get("qp", 0.0)
    soc = sum(r.second_order_correction for r in res.history)
    kept = max((r.n_rows_kept for r in res.history), default=0)
    backends = ",".join(sorted({r.qp_backend for r in res.history if r.qp_backend}))
    return (f"| {label} | {res.status.value} | {res.iterations} | {res.fun:.8f} | {res.kkt_stationarity:.1e} | "
            f"{seconds:.1f} | {qp:.1f} | {res.times.get('hessian', 0.0):.1f} | {soc} | {kept} | {backends} |")


def _header():
    print("| run | status | iterations | f | stationarity | total [s] | QP [s] | Hessian [s] | SOC | max rows | backends |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")


def compare(args):
    prob = SyntheticDesign(args.poses, args.params, args.rows, args.seed)
    e_g, e_h = prob.check_derivatives(np.random.default_rng(1))
    print(f"\nPart 1: n = {prob.q0.size}, m = {prob.P * args.rows} rows, p = {args.params} "
          f"(U has {args.params**2} columns); finite differences: gradient {e_g:.1e}, Hv {e_h:.1e}\n")
    bounds = (-np.pi, np.pi)
    runs = [
        ("BFGS dense", {}, {}),
        ("BFGS per pose (design default)", {"block_size": 6}, {}),
        ("exact, abs, per block (lifted)", {"lagrangian_hessian": prob.hessian}, {}),
    ]
    _header()
    for label, kwargs, settings in runs:
        t = time.perf_counter()
        res = solve_sqp(prob.objective, prob.q0.ravel(), constraints=prob.constraints, bounds=bounds,
                        settings=SQPSettings(max_iterations=args.max_iterations, **settings), **kwargs)
        print(_row(label, res, time.perf_counter() - t), flush=True)


def stress(args):
    prob = SyntheticDesign(args.poses, args.params, args.stress_rows, args.seed + 1)
    n, m = prob.q0.size, prob.P * args.stress_rows
    settings = SQPSettings(max_iterations=args.stress_iterations, step_bound=1.0)
    print(f"\nPart 2: n = {n}, m = {m} rows, trust region 1 rad from the start, "
          f"max_qp_rows = {settings.qp_row_limit(n)}, max_dense_qp_size = {settings.max_dense_qp_size}, "
          f"{args.stress_iterations} iterations\n")
    c, A = prob.constraints(prob.q0.ravel())
    l1 = np.asarray(abs(A).sum(axis=1)).ravel()
    print(f"rows passing the margin test at the start (what a QP took before issue 16): "
          f"{int(np.count_nonzero(c - l1 * 1.0 <= settings.active_margin))}\n")
    _header()
    for label, kwargs in (("BFGS per pose", {"block_size": 6}), ("exact, abs, per block", {"lagrangian_hessian": prob.hessian})):
        t = time.perf_counter()
        res = solve_sqp(prob.objective, prob.q0.ravel(), constraints=prob.constraints, bounds=(-np.pi, np.pi),
                        settings=settings, **kwargs)
        print(_row(label, res, time.perf_counter() - t), flush=True)
        dropped = max(r.n_rows_dropped for r in res.history)
        print(f"|  | rows dropped by the bound: up to {dropped} per QP |||||||||||")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--params", type=int, default=10)
    parser.add_argument("--rows", type=int, default=60, help="obstacle rows per pose (part 1)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-iterations", type=int, default=300)
    parser.add_argument("--stress-rows", type=int, default=300, help="rows per pose (part 2)")
    parser.add_argument("--stress-iterations", type=int, default=30)
    parser.add_argument("--skip-compare", action="store_true")
    parser.add_argument("--skip-stress", action="store_true")
    args = parser.parse_args(argv)
    print("$ " + shlex.join(getattr(sys, "orig_argv", [sys.executable] + sys.argv)))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, proxsuite "
          f"{getattr(proxsuite, '__version__', '?')}; BLAS pinned to 1 thread (as the design driver)")
    with threadpool_limits(limits=1, user_api="blas"):
        if not args.skip_compare:
            compare(args)
        if not args.skip_stress:
            stress(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
