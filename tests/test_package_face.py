"""The package face imports its names on first use; the design command does not load the export's libraries."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

import calib_oed


def test_every_public_name_resolves_to_its_defining_module():
    for name in calib_oed.__all__:
        value = getattr(calib_oed, name)
        if name != "__version__":
            module = importlib.import_module(calib_oed._EXPORTS[name])
            assert value is getattr(module, name), name
    assert set(calib_oed.__all__) <= set(dir(calib_oed))


def test_unknown_names_raise_and_subpackages_resolve_as_before():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        calib_oed.nope  # noqa: B018
    assert calib_oed.oed.design.DESIGN_SQP.max_iterations >= 1  # as the docs use it


def test_the_design_path_leaves_the_urdf_export_unloaded():
    code = ("import sys, calib_oed.cli, calib_oed.oed.design, calib_oed.oed.result; "
            "print(sorted(m for m in ('yourdfpy', 'trimesh', 'calib_oed.calibration.export') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
