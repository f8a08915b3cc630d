"""04 — See a design before the robot moves: the meshcat view as a static web page.

A short KPI-optimal design of 20 poses for ``fms_kr16``, drawn in meshcat:
every pose as a translucent ghost with its laser beam to the tracker, the
tracker, the car and the tracker stand, the working configuration in green,
and the 95 % confidence ellipsoid of the TCP, enlarged by a stated factor
(its true half-axes are hundredths of a millimetre). The page is written as a
self-contained HTML file that opens offline; with ``open_viewer`` instead of
``write_static_html`` the same scene is served live (print ``live.url``).

Checks: the page holds all 20 poses and no infeasible one; the drawn
ellipsoid's half-axes are those of the KPI covariance C_s at the chi-square
radius, times the stated scale; the page needs no network.

Run: .venv/bin/python examples/04_view_design.py [OUT.html]   (about 20 s of CPU)
"""

from __future__ import annotations

import dataclasses
import re
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from calib_oed import load_scene, setup
from calib_oed.oed.design import DESIGN_SQP, design
from calib_oed.viz.sessions import write_static_html

s = setup(load_scene("fms_kr16"))
optimal = design(s, 20, "kpi", seed=0, settings=dataclasses.replace(DESIGN_SQP, max_iterations=20),
                 certificate=False)                       # the view needs no optimality bound
given = [a for a in sys.argv[1:] if a.endswith(".html")]   # (the test runner's own arguments are not)
out = Path(given[0]) if given else Path(tempfile.mkdtemp()) / "fms_kr16_view.html"
view = write_static_html(out, s, optimal.q)               # starts meshcat, draws, saves, stops it
info = view.info
print(info.summary())
print(f"wrote {view.path} ({view.path.stat().st_size / 1e6:.1f} MB); open it in a browser")

# The ellipsoid as drawn must be the KPI's 95 % region, enlarged by the stated factor.
c_s = s.problem.kpi_covariance(optimal.q)[:3, :3]                   # [m²]
true_axes_mm = np.sqrt(chi2.ppf(0.95, 3) * np.linalg.eigvalsh(c_s))[::-1] * 1e3
assert info.n_poses == 20 and not info.infeasible_poses, "every design pose should be drawn, feasible"
assert np.allclose(info.half_axes_mm[0], true_axes_mm, rtol=1e-6), (info.half_axes_mm, true_axes_mm)
print(f"95 % ellipsoid half-axes {np.round(true_axes_mm, 4)} mm, drawn x{info.ellipsoid_scale:g}")
html = view.path.read_text()
assert not re.search(r"""(src|href)\s*=\s*["']https?://""", html), "the page must open offline"
