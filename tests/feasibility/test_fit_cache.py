"""The on-disk cache of link fits and mesh pair decisions: round trip, keyed, never fatal."""

from __future__ import annotations

import numpy as np

from calib_oed import load_robot
from calib_oed.feasibility import fit_cache, link_fit, mesh_pairs
from calib_oed.feasibility.capsules import load_collision_model


def test_a_new_process_reads_the_fit_from_disk(tmp_path, monkeypatch):
    monkeypatch.setenv("CALIB_OED_CACHE_DIR", str(tmp_path))
    robot = load_robot("kr16")
    geom = load_collision_model(robot)
    monkeypatch.setattr(link_fit, "_CACHE", {})
    fits = link_fit.fit_robot_links(robot, geom)
    assert len(list(tmp_path.glob("link_fit-*.json"))) == 1
    monkeypatch.setattr(link_fit, "_CACHE", {})  # as in a new process
    fit_link = link_fit.fit_link
    monkeypatch.setattr(link_fit, "fit_link", lambda *a, **k: (_ for _ in ()).throw(AssertionError("refit")))
    again = link_fit.fit_robot_links(robot, geom)
    monkeypatch.setattr(link_fit, "fit_link", fit_link)
    assert [f.link for f in again] == [f.link for f in fits]
    for f0, f1 in zip(fits, again, strict=True):
        assert f1.capsule_volume == f0.capsule_volume and f1.single_volume == f0.single_volume
        np.testing.assert_array_equal(f1.hull_volume, f0.hull_volume)  # NaN for a one-point link
        for c0, c1 in zip(f0.capsules, f1.capsules, strict=True):
            np.testing.assert_array_equal(c0.a, c1.a)
            np.testing.assert_array_equal(c0.b, c1.b)
            assert (c0.radius, c0.name, c0.frame) == (c1.radius, c1.name, c1.frame)
    # other settings: another key, another file
    link_fit.fit_robot_links(robot, geom, link_fit.LinkFitSettings(max_capsules=2))
    assert len(list(tmp_path.glob("link_fit-*.json"))) == 2


def test_mesh_pairs_round_trip(tmp_path, monkeypatch):
    monkeypatch.setenv("CALIB_OED_CACHE_DIR", str(tmp_path))
    robot = load_robot("kr16")
    monkeypatch.setattr(mesh_pairs, "_CACHE", {})
    found = mesh_pairs.dropped_mesh_pairs(robot, 0.01, samples=30)
    monkeypatch.setattr(mesh_pairs, "_CACHE", {})
    monkeypatch.setattr(mesh_pairs, "mesh_pair_clearances", lambda *a, **k: (_ for _ in ()).throw(AssertionError))
    assert mesh_pairs.dropped_mesh_pairs(robot, 0.01, samples=30) == found
    assert found and all(p.decision for p in found)


def test_off_unwritable_and_corrupt_caches_are_ignored(tmp_path, monkeypatch):
    monkeypatch.setenv("CALIB_OED_CACHE_DIR", "off")
    assert fit_cache.cache_dir() is None
    fit_cache.store("x", "k", [1])
    assert fit_cache.load("x", "k") is None
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("CALIB_OED_CACHE_DIR", str(blocker / "sub"))  # a folder under a file
    fit_cache.store("x", "k", [1])
    assert fit_cache.load("x", "k") is None
    monkeypatch.setenv("CALIB_OED_CACHE_DIR", str(tmp_path))
    (tmp_path / f"x-v{fit_cache.VERSION}-k.json").write_text("{not json")
    assert fit_cache.load("x", "k") is None
    fit_cache.store("x", "k", {"a": 1})
    assert fit_cache.load("x", "k") == {"a": 1}
    assert not list(tmp_path.glob("*.tmp"))
