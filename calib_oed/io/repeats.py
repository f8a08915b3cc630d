"""Rows of a file that repeat an earlier row exactly: a note, never an error.

A repeated configuration is a legitimate measurement (``--replicates``), but a
row identical to an earlier one, measured values included, is more often a
copied line; the readers of design and measurement files name such rows in
a :class:`~calib_oed.exceptions.CalibOedNote` and keep them.
"""

from __future__ import annotations

import numpy as np


def repeated_rows(lines: list[int], table: np.ndarray) -> list[tuple[int, int]]:
    """``(line, line of its first occurrence)`` for every row of ``table`` (one per line)
    identical to an earlier row, in file order."""
    _, first, inverse = np.unique(np.asarray(table), axis=0, return_index=True, return_inverse=True)
    inverse = np.asarray(inverse).ravel()
    return [(lines[k], lines[first[inverse[k]]]) for k in range(len(lines)) if first[inverse[k]] != k]


def describe_repeats(repeats: list[tuple[int, int]], shown: int = 5) -> str:
    """``"line 7 = line 3, ..."`` for the first ``shown`` repeats."""
    text = ", ".join(f"line {a} = line {b}" for a, b in repeats[:shown])
    return text + (" ..." if len(repeats) > shown else "")
