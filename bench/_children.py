"""Shared helper of the benchmarks that run ``calib-oed`` in child processes elsewhere.

A child run in another directory resolves a relative ``PYTHONPATH`` (``PYTHONPATH=.``) against
that directory, and ``python -m`` puts its own working directory first on ``sys.path``: either
way it would import another package than the checkout named. :func:`child_env` makes the entries
absolute; :func:`package_run` says which package a child run there imports.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def child_env(**extra: str) -> dict:
    """``os.environ`` with every ``PYTHONPATH`` entry made absolute, plus ``extra``."""
    entries = os.environ.get("PYTHONPATH", "").split(os.pathsep)
    return dict(os.environ, PYTHONPATH=os.pathsep.join(os.path.abspath(e) for e in entries if e), **extra)


def package_run(cwd) -> Path:
    """The checkout whose ``calib_oed`` a child started in ``cwd`` with :func:`child_env` imports."""
    where = subprocess.run([sys.executable, "-c", "import calib_oed; print(calib_oed.__file__)"], cwd=cwd,
                           env=child_env(), check=True, capture_output=True, text=True).stdout.strip()
    return Path(where).parent.parent
