"""Will a design fit in memory? A check before anything large is allocated."""

from __future__ import annotations

from calib_oed.exceptions import DesignMemoryError

#: Columns of the exact Hessian's coupling factor U budgeted per variable row (75 for one
#: KPI point on fms_kr16; a factor wider than n nv / 3 goes to a dense QP, below).
COUPLING_COLUMNS = 400


def check_memory(n: int, nv: int, rows_per_pose: int, dense: bool = True) -> None:
    """Refuse a design whose solver would not fit in memory, before allocating anything.

    The estimate [bytes] of the SQP's largest arrays: with a dense Hessian
    (damped BFGS, ``dense``) about 6 copies of an (n nv)² matrix of floats
    (the matrix, its QP copy and ProxQP's factorisation); with the exact
    structured Hessian the per-pose blocks, the coupling factor
    (n nv × :data:`COUPLING_COLUMNS`, a few copies) and, when that factor is
    too wide to lift, one dense (n nv)² matrix; plus the constraint Jacobian
    ((n · rows_per_pose) × nv floats, a few copies). It is compared with the
    memory available now (``/proc/meminfo`` MemAvailable).

    Raises:
        DesignMemoryError: the estimate exceeds 80 % of the available memory.
    """
    available = _available_memory()
    if available is None:
        return

    def needed(k: int) -> float:
        rows = 4 * k * rows_per_pose * nv
        if dense:
            return 8.0 * (6 * (k * nv) ** 2 + rows)
        wide = COUPLING_COLUMNS > k * nv / 3  # then formed densely
        return 8.0 * (4 * k * nv * COUPLING_COLUMNS + 2 * wide * (k * nv) ** 2 + rows)

    if needed(n) <= 0.8 * available:
        return
    lo, hi = 1, n
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if needed(mid) <= 0.8 * available else (lo, mid - 1)
    raise DesignMemoryError(n, needed(n), available, lo)


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
