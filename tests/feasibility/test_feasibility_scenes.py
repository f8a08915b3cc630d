"""The FMS cells end to end: feasible sampling, checked independently against the URDF meshes."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.feasibility.margins import margin_report
from calib_oed.feasibility.mesh_check import check_design_meshes
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module", params=["fms_kr16", "fms_kr300", "fms_kr500"])
def scene_model(request):
    scene = load_scene(request.param)
    fm, report = feasibility_from_scene(scene)
    return scene, fm, report


def test_sampled_designs_are_mesh_feasible(scene_model):
    scene, fm, _ = scene_model
    q = sample_feasible(fm, 60, 0)
    assert q.shape == (60, scene.robot.nq)
    res = fm.compute(q, jacobian=False)
    assert res.feasible.all()
    offsets = np.array([r.offset for r in scene.reflectors])
    mesh = check_design_meshes(
        scene.robot, q, scene.cell,
        tracker_position=scene.tracker.placement().translation,
        reflector_offsets=offsets, beam_radius=scene.feasibility.beam_radius,
        excluded_pairs=scene.feasibility.excluded_pairs,
    )
    assert mesh.all_feasible(), mesh.summary()
    # capsules enclose the meshes, so the meshes keep at least the capsule clearance
    assert mesh.min_distance.min() >= scene.feasibility.margins.clearance


def test_no_pair_is_impossible(scene_model):
    _, _, report = scene_model
    assert not [d for d in report.dropped if d.reason.startswith("overlapping")], report.summary()


def test_margin_report_respects_settings(scene_model):
    scene, fm, _ = scene_model
    q = sample_feasible(fm, 20, 3)
    margins = {m.kind: m for m in margin_report(fm, fm.compute_values(q))}
    assert set(margins) == {"joint", "incidence", "self", "obstacle", "beam"}
    for m in margins.values():
        assert m.slack >= 0.0
    limit = np.degrees(scene.feasibility.incidence_limit - scene.feasibility.margins.incidence)
    assert margins["incidence"].actual <= limit + 1e-9
    assert margins["beam"].actual >= scene.feasibility.margins.clearance * 1e3


def test_working_configuration_clears_the_cell(scene_model):
    """The KPI pose is not a measurement pose (the reflector faces the car), but the arm
    must not be inside the car or the floor there."""
    scene, fm, _ = scene_model
    res = fm.compute(scene.kpi.q, jacobian=False)
    rows = [i for i, k in enumerate(res.kinds) if k in ("self", "obstacle")]
    assert np.all(res.values[:, rows] >= 0.0)


def test_scene_constraint_jacobian_matches_finite_differences(scene_model):
    """The shipped cells with fitted capsules, beam and half-space rows, at feasible poses. Rows on
    convex pieces (coal) are piecewise smooth: a row whose witness features switch within the step
    (two step sizes disagree) is skipped; every other row is held to 1e-6."""
    from conftest import smooth_difference

    scene, fm, _ = scene_model
    q = sample_feasible(fm, 4, 8)
    jac = fm.compute(q).jacobian
    hull = np.isin(np.array(fm.labels), fm.hull_pairs.labels)
    skipped = 0
    for k in range(len(q)):
        num, smooth = smooth_difference(lambda x: fm.compute_values(x[None])[0], q[k], eps=1e-6)
        assert np.all(smooth | hull)  # only coal's rows have kinks
        skipped += int((~smooth).sum())
        scale = np.maximum(np.abs(num).max(axis=1, keepdims=True), 1e-3)
        assert np.max(np.abs(jac[k] - num)[smooth] / scale[smooth]) < 1e-6
    assert skipped <= max(1, hull.sum())  # a kink now and then, not a blanket exclusion
