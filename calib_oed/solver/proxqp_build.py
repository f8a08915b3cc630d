"""ProxQP in its SSE2 build: the same QP gives the same bits in every process (issue 31).

The ``proxsuite`` package (0.8) ships ProxQP three times, built for SSE2, AVX2
and AVX-512, and loads the widest one the processor runs. The AVX2 build's
answer to one and the same QP depends on where the allocator put its buffers:
a dense QP of 96 variables and 60 rows, solved 60 times in one process with
other allocations in between, came back with one of two solutions differing
in the last bits (16 and 44 times); the SSE2 build returned the same bits all
60 times, also with the inputs at shifted addresses. The SQP amplifies such
bits: two ``calib-oed design ur5_table`` processes parted at the seventh local
maximisation of the column generation, where a ProxQP step that stopped at its
iteration limit differed, and their certificates ended at other bounds.

This module imports ``proxsuite`` with the SSE2 build chosen. Every module that
uses ProxQP imports it from here (``from calib_oed.solver.proxqp_build import
proxsuite``), so the first import in a process decides. A process that
imported ``proxsuite`` itself before ``calib_oed`` keeps its build (two builds
cannot be loaded into one process), and so does one without the SSE2 build: a
:class:`RuntimeWarning` says so once.
The SSE2 build took 0.9-1.3x the AVX2 build's CPU on dense QPs of 96-720 variables
(``bench/bench_proxqp_build.py``, ``docs/benchmarks.md``).
"""

from __future__ import annotations

import sys
import types
import warnings

#: The extension module of ProxQP's SSE2 build inside the ``proxsuite`` package.
SSE2_BUILD = "proxsuite.proxsuite_pywrap"


def _import_sse2():
    """Import ``proxsuite`` telling its loader that the processor has neither AVX2 nor AVX-512."""
    probe = types.ModuleType("proxsuite.instructionset")
    probe.has_AVX2 = probe.has_AVX512F = lambda: False
    sys.modules["proxsuite.instructionset"] = probe
    try:
        import proxsuite
    finally:  # a later `import proxsuite.instructionset` gets the real module
        del sys.modules["proxsuite.instructionset"]
        if getattr(sys.modules.get("proxsuite"), "instructionset", None) is probe:
            del sys.modules["proxsuite"].instructionset
    return proxsuite


def build_name(module) -> str:
    """The name of the extension module ``proxsuite`` loaded (``SSE2_BUILD``, or ``...pywrap_avx2`` etc.)."""
    loaded = getattr(module, "_submodule", None)
    return getattr(loaded, "__name__", "unknown")


if "proxsuite" in sys.modules:
    import proxsuite
else:
    proxsuite = _import_sse2()
    if not getattr(proxsuite, "_submodule", None):  # no SSE2 build installed: proxsuite's own choice
        del sys.modules["proxsuite"]
        import proxsuite

#: The build this process uses.
BUILD = build_name(proxsuite)
if BUILD != SSE2_BUILD:
    warnings.warn(f"proxsuite loaded {BUILD!r}, not its SSE2 build {SSE2_BUILD!r}: design results may "
                  "differ in their last digits between processes (import calib_oed before proxsuite)",
                  RuntimeWarning, stacklevel=2)
