"""The reused ProxQP objects of calib_oed.solver.qp keep an equilibration that fits their rows.

The data are two QPs of the ``ur5_table`` ``kpi_model`` design (issue 30; 60 poses, damped BFGS
blocks): the one the dense object was built on (1235 rows, the slots above it padding) and the QP
of a later iteration with 1442 rows. With the equilibration of the first kept, ProxQP stopped at
its iteration limit on the second, every retry too, and the SQP stalled after 9 iterations (then
reported as "the linearised constraints are inconsistent at a point feasible to tolerance").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp

from calib_oed.solver.polish import polish
from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem, SparseQPWorkspace
from calib_oed.solver.settings import SQPSettings
from calib_oed.solver.subproblem import QPSolver

DATA = Path(__file__).parent / "data"
EPS, MAX_ITER = 1e-9, 100  # the SQP's defaults (SQPSettings.qp_eps_abs, qp_max_iterations)


def _qp(tag):
    """QP ``tag`` (``"build"`` or ``"grown"``) and the duals the SQP warm-started it with."""
    z = np.load(DATA / "qp_ur5_table_kpi_model.npz")
    blocks = z[f"{tag}_blocks"]
    C = sp.csr_matrix((z[f"{tag}_C_data"], z[f"{tag}_C_indices"], z[f"{tag}_C_indptr"]),
                      shape=tuple(z[f"{tag}_C_shape"]))
    sub = QPSubproblem(sp.block_diag(list(blocks)).toarray(), z[f"{tag}_g"], C.toarray(), z[f"{tag}_lower"],
                       z[f"{tag}_box_lower"], z[f"{tag}_box_upper"])
    return sub, z[f"{tag}_lam0"], z[f"{tag}_nu0"]


def _tolerances(sub):
    """The SQP's residual test of this QP (:meth:`calib_oed.solver.subproblem._SubproblemMixin._qp`)."""
    scale = max(1.0, float(np.max(np.abs(sub.lower))))
    return 10 * EPS * scale, 10 * EPS * max(scale, float(np.max(np.abs(sub.g))))


def _built_on_the_first():
    """A dense object as the SQP had it: built (and equilibrated) on the 1235-row QP."""
    build, lam0, nu0 = _qp("build")
    ws = DenseQPWorkspace(build.g.size, EPS, MAX_ITER, max_capacity=SQPSettings().max_dense_qp_size - build.g.size)
    assert ws.solve(build, None, lam0, nu0).is_solved(*_tolerances(build))
    assert ws.scaled_rows == build.lower.size < ws.capacity
    return ws


def _reference(sub):
    """The QP solved by a fresh sparse object, polished to its exact KKT point."""
    ref = SparseQPWorkspace(sub.g.size, EPS, MAX_ITER).solve(sub)
    exact = polish(sub, ref, _tolerances(sub)[1])
    assert exact is not None
    return exact


def test_the_stale_equilibration_of_padding_slots_fails_the_grown_qp():
    """The failure this module guards against, reproduced: the grown QP on the old scaling."""
    ws = _built_on_the_first()
    grown, lam0, nu0 = _qp("grown")
    ws.scaled_rows = grown.lower.size  # pretend the equilibration had seen every row (the old code)
    stale = ws.solve(grown, None, lam0, nu0)
    assert stale.status == "max_iter"
    assert not stale.is_solved(*_tolerances(grown))
    assert stale.primal_residual > 1e-3  # far from solved, not a near miss


def test_a_qp_with_more_rows_than_the_equilibration_saw_is_rescaled_and_solved():
    ws = _built_on_the_first()
    grown, lam0, nu0 = _qp("grown")
    step = ws.solve(grown, None, lam0, nu0)
    assert ws.scaled_rows == grown.lower.size
    assert step.status == "solved" and step.iterations < MAX_ITER // 2
    exact = polish(grown, step, _tolerances(grown)[1])
    assert exact is not None and exact.is_solved(*_tolerances(grown))
    np.testing.assert_allclose(exact.d, _reference(grown).d, atol=1e-7)


def test_the_retry_of_a_failed_qp_recomputes_the_equilibration():
    """``QPSolver.solve(..., refresh=True)``, the SQP's retry, also repairs a stale scaling
    that the row count cannot reveal."""
    settings = SQPSettings()
    grown, lam0, nu0 = _qp("grown")
    solver = QPSolver(grown.g.size, settings)
    solver._ws["dense"] = ws = _built_on_the_first()
    ws.scaled_rows = grown.lower.size  # stale, as above
    assert not solver.solve(grown, lam0, nu0).is_solved(*_tolerances(grown))
    retry = solver.solve(grown, None, None, refresh=True)
    assert solver.last_backend == "dense"
    assert retry.status == "solved" and retry.iterations < MAX_ITER // 2
    np.testing.assert_allclose(retry.d, _reference(grown).d, atol=1e-7)
