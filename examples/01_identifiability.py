"""Identifiability and KPI precision of a random design for the kr16 FMS scene.

Loads the shipped scene, applies the gauge rule, checks the KPI's
estimability, and compares the predicted KPI standard deviation of two random
designs of different size: more measurements must not make it worse.
Run: .venv/bin/python examples/kr16_identifiability.py
"""

from __future__ import annotations

import numpy as np

from calib_oed.problem import CalibrationProblem
from calib_oed.scene import load_scene

scene = load_scene("fms_kr16")
problem = CalibrationProblem.from_scene(scene)
report = problem.identifiability
print(f"{scene.name}: {report.rank} of {len(report.names)} parameters identifiable, "
      f"condition number {report.condition_number:.1f} (mm, mrad)")

# The reflector sits on the A6 axis: 4R + 3 - 2 = 25 (docs/conventions.md).
assert report.rank == 4 * scene.robot.nq + 3 - 2

for est in problem.kpi_estimability():
    state = "estimable" if est.estimable else f"gauge-dependent via {', '.join(est.gauge)}"
    print(f"KPI {est.label}: {state}")

rng = np.random.default_rng(7)
q60 = scene.robot.random_configurations(60, rng)
q120 = np.vstack([q60, scene.robot.random_configurations(60, rng)])
sigma60, sigma120 = problem.kpi_sigma(q60)[0], problem.kpi_sigma(q120)[0]
print(f"KPI sigma: 60 random poses {sigma60 * 1e3:.4f} mm, 120 poses {sigma120 * 1e3:.4f} mm")
# Adding rows to F1 can only add information: the covariance cannot grow.
assert sigma120 <= sigma60
