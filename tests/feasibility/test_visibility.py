"""Reflectors the operator turns (``aim: manual``) and which SMRs of a nest the tracker sees."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest
from conftest import central_difference

from calib_oed.calibration.simulation import simulate_observations
from calib_oed.calibration.workflow import setup
from calib_oed.exceptions import SceneError
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.visibility import reflector_rows, visible_reflectors
from calib_oed.scene.reader import load_scene

NEST = """reflectors:
  - name: smr0
    offset: [0, 0, 50]
  - name: smr1                    # a second SMR of the nest, off the axis, turned by hand
    offset: [60, 0, 40]
    aim: {aim}
"""


def nest_scene(tmp_path, aim: str):
    text = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml").read_text()
    start = text.index("reflectors:")
    end = text.index("measurement: position")
    path = tmp_path / f"nest_{aim}.yaml"
    path.write_text(text[:start] + NEST.format(aim=aim) + "\n" + text[end:])
    return load_scene(path)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("nest")
    return {aim: nest_scene(tmp, aim) for aim in ("fixed", "manual")}


@pytest.fixture(scope="module")
def models(scenes):
    return {aim: feasibility_from_scene(s, prune=False)[0] for aim, s in scenes.items()}


def test_a_manual_reflector_has_no_incidence_row_but_keeps_its_beam_rows(scenes, models):
    assert scenes["manual"].reflectors[1].aim == "manual" and scenes["manual"].reflectors[0].aim == "fixed"
    fixed, manual = models["fixed"], models["manual"]
    assert [lbl for lbl in fixed.labels if lbl.startswith("incidence")] == ["incidence:smr0", "incidence:smr1"]
    assert [lbl for lbl in manual.labels if lbl.startswith("incidence")] == ["incidence:smr0"]
    beams = [lbl for lbl in manual.labels if "laser(smr1)" in lbl]
    assert beams and beams == [lbl for lbl in fixed.labels if "laser(smr1)" in lbl]
    # every other row is the same row with the same value
    q = scenes["fixed"].robot.random_configurations(30, 5)
    keep = [i for i, lbl in enumerate(fixed.labels) if lbl != "incidence:smr1"]
    np.testing.assert_array_equal(fixed.compute_values(q)[:, keep], manual.compute_values(q))
    # poses the fixed SMR's incidence rejects but its line of sight allows are feasible by hand
    vis_fixed, vis_manual = visible_reflectors(fixed, q), visible_reflectors(manual, q)
    assert np.all(vis_manual[:, 1] >= vis_fixed[:, 1]) and np.any(vis_manual[:, 1] & ~vis_fixed[:, 1])


def test_the_curvature_of_the_remaining_rows_maps_to_the_right_reflector(scenes, models):
    """Exact Hessian of the rows after the filtered incidence row (indices shift) vs finite differences."""
    fm = models["manual"]
    q = scenes["manual"].robot.random_configurations(3, 8)
    rng = np.random.default_rng(2)
    lam = rng.uniform(size=(3, fm.n_constraints))
    hull = np.isin(np.array(fm.labels), fm.hull_pairs.labels)
    lam[:, hull] = 0.0  # the convex-piece rows' curvature is a model (test_hulls.py)
    hess = fm.compute_lagrangian_hessian(q, lam)
    for j in range(3):
        def grad(x, j=j):
            return lam[j] @ fm.compute_from_states(x[None], compute_body_states(fm.robot.model, x[None])).jacobian[0]
        num = central_difference(grad, q[j])
        assert np.abs(hess[j] - num).max() / np.abs(num).max() < 1e-6


def test_visibility_rows_and_margin(models, scenes):
    fm = models["manual"]
    rows = reflector_rows(fm)
    assert [fm.labels[i] for i in rows[0]][0] == "incidence:smr0"
    for model in models.values():  # the rows the labels name: the incidence row, the laser line's rows
        for j, name in enumerate(model.reflector_names):
            named = [i for i, lbl in enumerate(model.labels) if lbl == f"incidence:{name}" or f"laser({name})" in lbl]
            assert reflector_rows(model)[j].tolist() == named and len(named) > 1
    q = scenes["manual"].robot.random_configurations(40, 3)
    loose, strict = visible_reflectors(fm, q), visible_reflectors(fm, q, margin=0.05)
    assert np.all(loose >= strict) and np.any(loose & ~strict)


def test_simulation_measures_only_the_visible_smrs(scenes):
    s = setup(scenes["manual"])
    q = s.problem.robot.random_configurations(12, 4)
    visible = np.ones((12, 2), dtype=bool)
    visible[[1, 5, 7], 1] = False
    visible[3, 0] = False
    p = np.zeros(s.problem.space.size)
    every = simulate_observations(s.problem.space, s.problem.models, q, p, 0)
    seen = simulate_observations(s.problem.space, s.problem.models, q, p, 0, visible=visible)
    assert [len(b.q) for b in seen] == [11, 9]
    for full, part, j in zip(every, seen, range(2), strict=True):
        np.testing.assert_array_equal(part.q, q[visible[:, j]])
        np.testing.assert_array_equal(part.values, full.values[visible[:, j]])


def test_an_unknown_aim_names_the_choices(tmp_path):
    with pytest.raises(SceneError, match="reflectors\\[1\\].aim.*fixed, manual"):
        nest_scene(tmp_path, "sideways")
