"""ProxQP's SSE2 build: one QP, the same bits wherever the allocator puts the buffers (issue 31)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from calib_oed.solver.proxqp_build import BUILD, SSE2_BUILD
from calib_oed.solver.qp import DenseQPWorkspace, QPSubproblem


def _qp(rng: np.random.Generator, n: int, k: int) -> QPSubproblem:
    a = rng.standard_normal((n, n))
    return QPSubproblem(a @ a.T / n + np.eye(n), rng.standard_normal(n), rng.standard_normal((k, n)),
                        rng.standard_normal(k) - 1.0, np.full(n, -0.2), np.full(n, 0.2))


def _at_offset(a: np.ndarray, offset: int) -> np.ndarray:
    """A copy of ``a`` that starts ``offset`` doubles into a fresh buffer (another alignment)."""
    buf = np.empty(a.size + 8)
    view = buf[offset:offset + a.size].reshape(a.shape)
    view[...] = a
    return view


@pytest.mark.parametrize("max_iter", [10_000, 15])
def test_same_qp_same_bits_wherever_the_buffers_lie(max_iter):
    """40 solves of one dense QP, each with other allocations made before it and the inputs at
    another address: one answer. Under the AVX2 build (proxsuite imported first) this loop gives
    two answers for both ``max_iter``; ``max_iter=15`` returns an unconverged iterate, as the SQP's
    QPs that stop at their iteration limit do."""
    rng = np.random.default_rng(7)
    sub = _qp(rng, 96, 60)
    junk, answers = [], set()
    for trial in range(40):
        junk.append(np.empty(int(rng.integers(1, 50_000))))  # moves the allocator
        if trial % 3 == 0:
            junk.pop(0)
        off = int(rng.integers(0, 8))
        moved = QPSubproblem(*(_at_offset(np.asarray(x), off) for x in sub))
        step = DenseQPWorkspace(96, 1e-9, max_iter).solve(moved)
        answers.add(step.d.tobytes() + step.lam.tobytes() + step.nu.tobytes())
    assert BUILD == SSE2_BUILD
    assert len(answers) == 1


def test_proxsuite_imported_first_keeps_its_build_and_says_so():
    """A process that imported proxsuite itself before calib_oed is warned that results may differ."""
    code = ("import warnings, proxsuite\n"
            "with warnings.catch_warnings(record=True) as w:\n"
            "    warnings.simplefilter('always')\n"
            "    from calib_oed.solver.proxqp_build import BUILD\n"
            "print(BUILD); print(sum('import calib_oed before proxsuite' in str(x.message) for x in w))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    if out[0] == SSE2_BUILD:  # a processor without AVX2: proxsuite chose the SSE2 build itself
        assert out[1] == "0"
    else:
        assert out[1] == "1"


def test_the_real_instruction_set_module_stays_importable():
    import proxsuite.instructionset as real

    assert isinstance(real.has_AVX2(), bool)
