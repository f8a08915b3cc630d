"""02 — Identify a robot from (simulated) laser-tracker data and export the result.

The chain a calibration engineer runs, on the shipped scene ``fms_kr16``, with
a simulated robot standing in for the real one:

1. a heuristic design: 40 random feasible measurement poses (the paper's
   baseline, docs/feasibility.md §5);
2. simulated tracker data: a "true" robot whose 25 identifiable parameters are
   off by 0.5 mm / 0.5 mrad (standard deviation), measured with the scene's
   noise: the tracker error model of a current tracker (Leica AT500 MPE,
   radial 5 um + 0.15 um/m, lateral 7.5 um + 3 um/m, 1 sigma) plus the KR 16's
   repeatability (0.014 mm per axis), written to ``meas.csv`` in the measurement file format
   (docs/data_format.md) and read back, as real data would be;
3. identification by weighted least squares (docs/identification.md);
4. export of the calibrated URDF and the sensor YAML (tracker pose, reflector
   offsets), loaded back to check the round trip;
5. validation: 30 further poses of the same true robot, measured with fresh
   noise, predicted by the exported files (what ``calib-oed validate`` does).

Checks: the solver converged; every identified parameter is within 4 standard
deviations of the truth and the whole estimate passes a chi-square test; the
TCP error after calibration is consistent with the predicted covariance C_s and
much smaller than before; the exported URDF reproduces the identified model
to 1 nm; on the validation poses the calibrated files leave only the
measurement noise (the noise floor sqrt(mean tr Sigma_i), ~0.03 mm here).

Everything is written into a temporary folder that is removed at the end.
Run: .venv/bin/python examples/02_identify_simulated.py   (about 4 s of CPU)
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from calib_oed import MeasurementSet, load_scene, simulate_observations, validate_calibration
from calib_oed.calibration.workflow import (
    export_result,
    heuristic_design,
    identify_measurements,
    read_scene_measurements,
    round_trip_error,
    setup,
    simulated_measurements,
    tcp_errors,
    write_measurement_file,
)

s = setup(load_scene("fms_kr16"))                    # scene + calibration problem + feasibility model
problem = s.problem
free = problem.identifiability.free_indices          # the 25 parameters the data determine

q = heuristic_design(s, 40, seed=0)                  # (40, 6) [rad], every pose feasible
mset, p_true = simulated_measurements(s, q, truth_seed=1)   # p_true: (45,) [m, rad], fixed ones 0

with tempfile.TemporaryDirectory(prefix="calib_oed_example02_") as tmp:
    tmp = Path(tmp)
    meas = write_measurement_file(s, tmp / "meas.csv", mset, comment="example 02: simulated data")
    result = identify_measurements(s, read_scene_measurements(s, meas))
    print(result.summary(top=5))
    print()

    # --- the estimate against the truth ----------------------------------------------------
    if not result.converged:
        raise SystemExit(f"identification did not converge: {result.status.value}: {result.message}")
    error = result.p_free - p_true[free]             # [m, rad]
    z = error / result.std                           # in standard deviations of C_p
    worst = int(np.argmax(np.abs(z)))
    print(f"largest parameter error: {result.free_names[worst]} at {abs(z[worst]):.2f} sigma "
          f"(all {len(z)} within 4 sigma: {bool(np.all(np.abs(z) < 4))})")
    if np.any(np.abs(z) >= 4):
        raise SystemExit(f"{result.free_names[worst]} is {z[worst]:.1f} sigma from the truth")
    # (p_hat - p)^T C_p^-1 (p_hat - p) is chi-square with 25 degrees of freedom.
    d2 = float(error @ np.linalg.solve(result.covariance, error))
    limit = chi2.ppf(0.999, len(free))
    print(f"Mahalanobis distance^2 of the estimate: {d2:.1f} (chi-square, {len(free)} dof; "
          f"99.9 % quantile {limit:.1f})")
    if d2 > limit:
        raise SystemExit(f"the estimate is too far from the truth for its covariance: {d2:.1f} > {limit:.1f}")

    # --- the KPI: TCP error at the working configuration -----------------------------------
    # in the KPI's own frame, as C_s (a simulated truth keeps the gauge parameters nominal)
    before = tcp_errors(s, p_true, None, problem.kpi.frame)      # nominal model against the truth, (1, 3) [m]
    after = tcp_errors(s, p_true, result.p, problem.kpi.frame)   # calibrated model against the truth
    c_s = problem.kpi_covariance(q)                  # predicted C_s (3, 3) [m^2]
    for name, b, a in zip(problem.kpi.names, before, after, strict=True):
        print(f"TCP error at {name}: before {np.linalg.norm(b) * 1e3:.4f} mm, after "
              f"{np.linalg.norm(a) * 1e3:.4f} mm (predicted RMS {np.sqrt(np.trace(c_s)) * 1e3:.4f} mm)")
    e = after[0]
    m2 = float(e @ np.linalg.solve(c_s, e))
    if m2 > chi2.ppf(0.999, 3):
        raise SystemExit(f"TCP error {e * 1e3} mm is outside the 99.9 % ellipsoid of C_s")
    if not np.linalg.norm(after) < 0.1 * np.linalg.norm(before):
        raise SystemExit("the calibration did not reduce the TCP error tenfold")

    # --- export: calibrated URDF + sensor YAML ---------------------------------------------
    paths = export_result(s, result, tmp / "cal")   # cal/kr16_calibrated.urdf, cal/kr16_sensor.yaml
    rt = round_trip_error(s, result.p, paths["urdf"])
    print(f"exported {paths['urdf'].name} and {paths['sensor'].name}; round trip "
          f"{rt * 1e9:.2g} nm")
    if rt > 1e-9:
        raise SystemExit(f"exported URDF differs from the identified model by {rt * 1e9:.3g} nm")

    # --- validation on separate poses (calib-oed validate SCENE cal meas_val.csv) -------------
    q_val = heuristic_design(s, 30, seed=1)          # other poses than the calibration's
    blocks = simulate_observations(problem.space, problem.models, q_val, p_true, rng=2)
    val_set = MeasurementSet.from_arrays(problem.robot, q_val, blocks[0].values,
                                         source="validation poses")
    val = validate_calibration(s.scene, paths["urdf"].parent, val_set)
    print(val.summary())
    if val.check() > 1.3:
        raise SystemExit(f"calibrated residuals are {val.check():.2f} x the noise floor")
    if val.nominal.rms_mm < 10 * val.calibrated.rms_mm:
        raise SystemExit("the nominal model fits the validation data nearly as well as the calibration")
print("OK")
