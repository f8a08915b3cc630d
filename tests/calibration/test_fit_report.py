"""The identification report on measured data: rows by file line, per reflector and pose, warnings."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.fit_report import (
    PLAUSIBLE_STD,
    fit_report,
    format_fit,
    worst_determined,
)
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.sanity import check_measurements
from calib_oed.calibration.workflow import simulated_measurements


@pytest.fixture(scope="module")
def fms(kr16_setup):
    return kr16_setup  # the session's fms_kr16 set-up (tests/conftest.py)


def _fit(s, q, truth_seed):
    mset, _ = simulated_measurements(s, q, truth_seed)
    tracker = s.scene.tracker
    blocks = mset.blocks(sigma=tracker.sigma, sigma_angle=tracker.sigma_angle)
    sanity = check_measurements(s.problem.space, mset)
    rob = identify_robust(s.problem.space, blocks, s.problem.identifiability)
    return mset, blocks, sanity, rob


def test_narrow_design_warns_about_implausible_parameters(fms):
    """30 poses within 5 deg of the working pose: the arm's tilts are barely determined."""
    q0 = fms.problem.kpi.configurations[0]
    q = q0 + np.radians(5) * np.random.default_rng(0).uniform(-1, 1, (30, 6))
    mset, blocks, sanity, rob = _fit(fms, q, 1)
    worst = worst_determined(rob, 3)
    post = rob.result.std * rob.scale
    assert worst[0]["std"] == pytest.approx(post.max())
    assert worst[0]["implausible"] and worst[0]["std"] > PLAUSIBLE_STD["rad"]
    text = format_fit(fit_report(fms.problem.space, mset, blocks, sanity, rob, fms.reflector_names),
                      rob, sanity)
    assert "WARNING: implausibly large" in text and rob.result.condition_number > 1e4


def test_report_rows_follow_the_file(fms):
    q = fms.problem.robot.random_configurations(40, 5)
    mset, blocks, sanity, rob = _fit(fms, q, 6)
    rep = fit_report(fms.problem.space, mset, blocks, sanity, rob, fms.reflector_names)
    assert rep.line.tolist() == mset.lines.tolist() and rep.pose.tolist() == list(range(1, 41))
    assert set(rep.reflector) == {"smr0"} and not rep.outlier.any()
    assert rep.after_mm.max() < 0.1 < np.sqrt(np.mean(rep.before_mm**2))
    assert np.allclose(rep.before_mm, sanity.registration.errors_mm)
    (name, g), = rep.groups("reflector")
    assert name == "smr0" and g["n"] == 40
    assert g["after_rms_mm"] == pytest.approx(np.sqrt(np.mean(rep.after_mm**2)))
    lines = rep.to_csv().splitlines()
    assert lines[1].startswith("line,pose,reflector") and len(lines) == 42
    assert all("WARNING" not in w for w in format_fit(rep, rob, sanity).splitlines())
