"""Will a design fit in memory? A check before anything large is allocated."""

from __future__ import annotations

from calib_oed.exceptions import DesignMemoryError

#: Columns of the exact Hessian's coupling factor U budgeted per variable row (75 for one
#: KPI point on fms_kr16; a factor wider than n nv / 3 goes to a dense QP, below).
COUPLING_COLUMNS = 400
#: Dense (n nv)² arrays of floats at the peak of a design whose criterion couples every pair of
#: poses through the model-error kernel (``kpi_model``: ``needs_design``) with the exact Hessian:
#: the Hessian, its eigenvectors and the pose-pair products of
#: :func:`calib_oed.oed.model_error_hessian.compute_hessian`. Above the 60-pose process (0.22 GiB),
#: peak RSS on fms_kr16 (nv = 6) grows by 17-19 of them from 250 to 1000 poses (0.52, 1.46 and
#: 4.75 GiB at 250, 500 and 1000; ``docs/benchmarks.md``, "The memory of a coupled criterion").
#: With damped BFGS (``kpi_kriging``, ``--hessian bfgs``) the dense estimate's 6 copies: at 500
#: poses 0.61 GiB peak, 0.40 GiB above the 60-pose process against 0.41 GiB estimated.
COUPLED_COPIES = 20
#: Largest share of the available memory a design may be estimated to use.
MEMORY_SHARE = 0.8


def estimate_memory(n: int, nv: int, rows_per_pose: int, dense: bool = True, coupled: bool = False) -> float:
    """The estimated peak [bytes] of the SQP's largest arrays for ``n`` poses of ``nv`` joints.

    With a dense Hessian (damped BFGS, ``dense``) about 6 copies of an (n nv)² matrix of floats
    (the matrix, its QP copy and ProxQP's factorisation); with the exact structured Hessian the
    per-pose blocks, the coupling factor (n nv × :data:`COUPLING_COLUMNS`, a few copies) and, when
    that factor is too wide to lift, one dense (n nv)² matrix; plus the constraint Jacobian
    ((n · rows_per_pose) × nv floats, a few copies). A criterion that couples every pair of poses
    (``coupled``: the model-error criteria) holds :data:`COUPLED_COPIES` dense (n nv)² matrices with
    the exact Hessian.
    """
    rows = 4 * n * rows_per_pose * nv
    if dense:
        return 8.0 * (6 * (n * nv) ** 2 + rows)
    if coupled:
        return 8.0 * (COUPLED_COPIES * (n * nv) ** 2 + rows)
    wide = COUPLING_COLUMNS > n * nv / 3  # then formed densely
    return 8.0 * (4 * n * nv * COUPLING_COLUMNS + 2 * wide * (n * nv) ** 2 + rows)


def check_memory(n: int, nv: int, rows_per_pose: int, dense: bool = True, coupled: bool = False) -> None:
    """Refuse a design whose solver would not fit in memory, before allocating anything:
    :func:`estimate_memory` against the memory available now (``/proc/meminfo`` MemAvailable).

    Raises:
        DesignMemoryError: the estimate exceeds :data:`MEMORY_SHARE` of the available memory.
    """
    available = _available_memory()
    if available is None:
        return

    def fits(k: int) -> bool:
        return estimate_memory(k, nv, rows_per_pose, dense, coupled) <= MEMORY_SHARE * available

    if fits(n):
        return
    lo, hi = 1, n
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid - 1)
    raise DesignMemoryError(n, estimate_memory(n, nv, rows_per_pose, dense, coupled), available, lo, MEMORY_SHARE)


def _available_memory() -> float | None:
    """MemAvailable of ``/proc/meminfo`` [bytes], or None where it cannot be read."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        return None
    return None
