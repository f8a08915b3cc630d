"""Will a design fit in memory? A check before anything large is allocated."""

from __future__ import annotations

from calib_oed.exceptions import DesignMemoryError


def check_memory(n: int, nv: int, rows_per_pose: int) -> None:
    """Refuse a design whose solver would not fit in memory, before allocating anything.

    The estimate is the SQP's dense quasi-Newton matrix and its dense QP
    (about 6 copies of an (n nv)² matrix of floats) plus the constraint
    Jacobian ((n · rows_per_pose) × nv floats, a few copies) [bytes]; it is
    compared with the memory available now (``/proc/meminfo`` MemAvailable).

    Raises:
        DesignMemoryError: the estimate exceeds 80 % of the available memory.
    """
    available = _available_memory()
    if available is None:
        return

    def needed(k: int) -> float:
        return 8.0 * (6 * (k * nv) ** 2 + 4 * k * rows_per_pose * nv)

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
