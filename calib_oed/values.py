"""Values that records hold and files write: read-only arrays, plain JSON and YAML values."""

from __future__ import annotations

import math
from enum import Enum

import numpy as np

from calib_oed.exceptions import NonFiniteError, ShapeError


def readonly(value, dtype=None) -> np.ndarray:
    """A read-only copy of ``value`` as an array (of ``dtype`` if given)."""
    arr = np.array(value, dtype=dtype)
    arr.setflags(write=False)
    return arr


def finite_vector(value, what: str, size: int | None = None) -> np.ndarray:
    """A finite, read-only float copy of a vector (of length ``size`` if given).

    Raises:
        ShapeError: not a vector (of that length).
        NonFiniteError: an entry is NaN or infinite.
    """
    arr = np.array(value, dtype=float)
    if size is not None and arr.size == size:
        arr = arr.reshape(size)
    if arr.ndim != 1 or (size is not None and arr.shape[0] != size):
        raise ShapeError(what, f"({size if size is not None else 'n'},)", arr.shape)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(arr)).tolist())
    arr.setflags(write=False)
    return arr


def plain(value):
    """``value`` with numpy arrays and scalars made Python lists and numbers, enums their
    values, non-finite floats ``None`` and dict keys strings, recursively."""
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    return value
