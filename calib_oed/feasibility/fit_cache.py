"""A small on-disk cache for results computed from a robot's collision geometry.

The link fit (:mod:`calib_oed.feasibility.link_fit`) and the mesh pair decisions
(:mod:`calib_oed.feasibility.mesh_pairs`) depend only on the geometry and their
settings, and take about a second each on a mesh robot; caching them keeps a
scene's second load in a new process fast. Entries are JSON files named by
the SHA-256 of everything the result depends on (the caller's key), in
``$CALIB_OED_CACHE_DIR``, else ``$XDG_CACHE_HOME/calib_oed``, else
``~/.cache/calib_oed``; ``CALIB_OED_CACHE_DIR=off`` disables the cache. A
cache that cannot be read or written is ignored (the result is recomputed).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

__all__ = ["cache_dir", "load", "store"]

#: Bump when a cached result's meaning changes: old entries are then not found.
VERSION = 1


def cache_dir() -> Path | None:
    """The cache folder, or ``None`` when disabled."""
    explicit = os.environ.get("CALIB_OED_CACHE_DIR")
    if explicit:
        return None if explicit.lower() == "off" else Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "calib_oed"


def _path(kind: str, key: str) -> Path | None:
    folder = cache_dir()
    return None if folder is None else folder / f"{kind}-v{VERSION}-{key}.json"


def load(kind: str, key: str):
    """The cached JSON payload, or ``None`` (absent, disabled or unreadable)."""
    path = _path(kind, key)
    if path is None:
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def store(kind: str, key: str, payload) -> None:
    """Write ``payload`` (JSON-serialisable) atomically; errors are ignored."""
    path = _path(kind, key)
    if path is None:
        return
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(payload, f)
        os.replace(tmp, path)
        tmp = None
    except OSError:
        return
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
