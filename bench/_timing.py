"""Shared timing helper of the benchmarks."""

from __future__ import annotations

import time


def timed(fun, repeat, number):
    """Best of ``repeat`` samples, each the mean of ``number`` calls (as timeit).

    The minimum is the least disturbed by other load on the machine. Returns
    ``(seconds per call, the first call's result)``.
    """
    out = fun()
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(number):
            fun()
        samples.append((time.perf_counter() - start) / number)
    return min(samples), out
