"""01 — Load a scene and see what a calibration can identify.

Loads the shipped scene ``fms_kr16`` (a KUKA KR 16-class arm, a laser tracker,
one reflector 50 mm along tool z), applies the gauge rule (which of the 45
calibration parameters the tracker data determine), checks whether the KPI
(the TCP at the working configuration ``car_side``) is estimable, and compares
the predicted KPI standard deviation of two random designs of different size.

Checks: the identifiable count is the classical 4R + 3 minus 2 (the reflector
is on the A6 axis, docs/conventions.md), the tracker absorbs the base (every
``joint1.*`` parameter is fixed), and more measurements do not make the KPI
worse.

Run: .venv/bin/python examples/01_identifiability.py   (about 2 s of CPU)
"""

from __future__ import annotations

import numpy as np

from calib_oed import CalibrationProblem, load_scene

scene = load_scene("fms_kr16")                       # or load_scene("path/to/my_cell.yaml")
problem = CalibrationProblem.from_scene(scene)
report = problem.identifiability                     # the gauge rule on the scene's generic design
print(f"{scene.name}: {report.rank} of {len(report.names)} parameters identifiable, "
      f"condition number {report.condition_number:.1f} (columns in mm, mrad)")

print(f"fixed at nominal ({len(report.fixed)}), first five:")
for fixed in report.fixed[:5]:
    print(f"  {fixed.name:10s} {fixed.reason}")

# The reflector sits on the A6 axis: 4R + 3 - 2 = 25 (docs/conventions.md).
expected = 4 * scene.robot.nq + 3 - 2
if report.rank != expected:
    raise SystemExit(f"expected {expected} identifiable parameters, got {report.rank}")
# With the tracker pose unknown, the tracker absorbs the robot's base placement.
base = {f"joint1.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")}
if not base <= set(report.fixed_names):
    raise SystemExit(f"expected {sorted(base)} fixed, fixed are {report.fixed_names}")

for est in problem.kpi_estimability():
    state = "estimable" if est.estimable else f"gauge-dependent via {', '.join(est.gauge)}"
    print(f"KPI {est.label}: {state}")

rng = np.random.default_rng(7)
q60 = scene.robot.random_configurations(60, rng)     # (60, 6) [rad], uniform in the joint limits
q120 = np.vstack([q60, scene.robot.random_configurations(60, rng)])
sigma60, sigma120 = problem.kpi_sigma(q60)[0], problem.kpi_sigma(q120)[0]   # [m]
print(f"KPI sigma per axis: 60 random poses {sigma60 * 1e3:.4f} mm, 120 poses {sigma120 * 1e3:.4f} mm")
# Adding rows to F1 can only add information: the covariance cannot grow.
if not sigma120 <= sigma60:
    raise SystemExit(f"120 poses gave a larger KPI sigma ({sigma120:.3g} m) than 60 ({sigma60:.3g} m)")
print("OK")
