"""The continuous check never passes a move that dense sampling finds in collision."""

from __future__ import annotations

import numpy as np

from calib_oed.program.continuous import MoveChecker


def _dense_min(checker: MoveChecker, q0, q1, n=1500) -> float:
    t = np.linspace(0, 1, n)
    return float(checker.clearance(q0 + t[:, None] * (q1 - q0)).min())


def test_verified_moves_hold_under_dense_sampling(kr16_checker, kr16_poses):
    ch = kr16_checker
    q = kr16_poses[:9]
    verified = blocked = 0
    for i in range(len(q)):
        for j in range(i + 1, len(q)):
            res = ch.check(q[i], q[j])
            if ch.screen(q[i], q[j]):  # the screen's "certain collision" is one
                assert res.collision
            dense = _dense_min(ch, q[i], q[j], 400)
            if res.verified:
                verified += 1
                assert dense >= -ch.tolerance, (i, j, dense)
            else:
                blocked += 1
                if res.collision:
                    assert res.min_sampled < -ch.tolerance
    assert verified > 3 and blocked > 0  # the test sees both outcomes


def test_a_move_through_the_floor_is_a_collision(kr16_checker, kr16_scene):
    ch = kr16_checker
    home = kr16_scene.kpi.configurations[0].q
    down = home.copy()
    down[1] += 1.2  # swing the arm down: through the car and the floor
    assert ch.clearance(down[None])[0] < 0
    res = ch.check(home, down)
    assert res.blocked and res.collision and res.worst_row.startswith(("obstacle", "self"))


def test_rows_are_lipschitz_with_the_stated_constant(kr16_checker, kr16_poses):
    """|g_k(t) - g_k(s)| <= L_k |t - s| on 1501 samples: the bound the certificate rests on."""
    ch = kr16_checker
    t = np.linspace(0, 1, 1501)
    worst = 0.0
    for q0, q1 in zip(kr16_poses[:3], kr16_poses[1:4], strict=True):
        g, _ = ch.rows(q0 + t[:, None] * (q1 - q0))
        slope = np.abs(np.diff(g, axis=0)).max(axis=0) / (t[1] - t[0])
        lip = ch.lipschitz(q0, q1)
        assert np.all(slope <= lip + 1e-9)
        worst = max(worst, float((slope / lip).max()))
    assert worst > 0.05  # not a vacuous constant


def test_line_of_sight_loss_is_reported_not_blocking(kr16_checker, kr16_poses):
    ch = kr16_checker
    lost = [ch.check(a, b) for a, b in zip(kr16_poses[:-1], kr16_poses[1:], strict=True)]
    assert any(r.sight_lost and r.verified for r in lost)


def test_interval_constants_bound_the_slopes_inside(kr16_checker, kr16_poses):
    """The tightened per-interval constants (motion_bound.EndpointBounds) still bound the
    rows' slopes inside each interval, and are smaller than the move's constant."""
    ch = kr16_checker
    q0, q1 = kr16_poses[2], kr16_poses[5]
    dq = np.abs(q1 - q0)
    growth = ch._ends.growth(dq)
    lip = ch.lipschitz(q0, q1)
    edges = np.linspace(0, 1, 9)
    _, _, d = ch._evaluate(q0 + edges[:, None] * (q1 - q0))
    local = ch._interval_lipschitz(lip, d[:-1], d[1:], np.diff(edges), dq, growth)
    assert np.all(local <= lip + 1e-12) and local.mean() < 0.9 * lip.mean()
    for k in range(8):
        t = np.linspace(edges[k], edges[k + 1], 400)
        g, _ = ch.rows(q0 + t[:, None] * (q1 - q0))
        slope = np.abs(np.diff(g, axis=0)).max(axis=0) / (t[1] - t[0])
        assert np.all(slope <= local[k] + 1e-9)


def test_the_check_keeps_every_row_of_the_design_and_the_far_pairs(kr16_scene, kr16_checker):
    """The design's collision rows, plus those its sampling pass dropped as never close; a row
    the sampling pass dropped for another reason stays out, as in the design."""
    from calib_oed.feasibility.pairs import feasibility_from_scene

    design, report = feasibility_from_scene(kr16_scene)
    rows = {lbl for lbl, k in zip(design.labels, design.kinds, strict=True) if k in ("self", "obstacle")}
    checked = set(kr16_checker.collision_labels)
    assert rows <= checked
    far = {d.label for d in report.dropped if d.reason.startswith("never closer")}
    others = {d.label for d in report.dropped} - far
    base = {lbl.replace(".a|", "|").replace(".b|", "|") for lbl in checked - rows}
    # a far capsule pair whose links the model without the pass checks on convex pieces
    # (link_fit hulls: links at most three joints apart) is checked by that row instead
    link = dict(zip(design.segments.names, design.segments.links, strict=True))
    on_pieces = {frozenset(lbl.split(":")[1].split("|")) for lbl in base if "#" not in lbl
                 and lbl.startswith("self:") and "(" not in lbl}
    covered = {f for f in far if f.startswith("self:") and frozenset(
        link.get(n) for n in f.split(":")[1].split("|")) in on_pieces}
    capsule_rows = {lbl for lbl in base if frozenset(lbl.split(":")[1].split("|")) not in on_pieces}
    assert far and capsule_rows == far - covered and not base & others
    assert len(on_pieces) == len(base - capsule_rows)


def test_row_bounds_from_the_rows_sides(kr16_scene, kr16_checker):
    """Capsule pair: rho_a + rho_b; end point against a half-space: rho_a; a row on two links'
    geometry: each link's largest rho + r; a row of unknown sides: the global bound."""
    from calib_oed.feasibility.row_family import FIXED, LINK, RowSides
    from calib_oed.program.continuous import row_bounds
    from calib_oed.program.motion_bound import segment_speed_bounds

    seg = kr16_checker.feasibility.segments
    robot = kr16_scene.robot
    rho = segment_speed_bounds(robot, seg)
    names = list(seg.names)
    i, j = names.index("link_2#0"), names.index("link_6#0")
    grown = rho + seg.radius[:, None] * (rho.max(axis=1, keepdims=True) > 0)
    links = {ln: grown[[k for k, x in enumerate(seg.links) if x == ln]].max(axis=0) for ln in ("link_2", "link_6")}
    sides = RowSides(np.array([[i, j], [j, FIXED], [LINK, LINK], [LINK, LINK]]),
                     (None, None, ("link_2", "link_6"), None))
    bounds, segs = row_bounds(robot, seg, sides)
    assert np.allclose(bounds[0], rho[i] + rho[j]) and segs[0].tolist() == [i, j]
    assert np.allclose(bounds[1], rho[j]) and segs[1].tolist() == [j, -1]
    assert np.allclose(bounds[2], links["link_2"] + links["link_6"]) and segs[2].tolist() == [-2, -2]
    assert np.all(bounds[2] >= bounds[0]) and np.allclose(bounds[3], 2 * grown.max(axis=0))


def test_rows_on_convex_pieces_of_meshes_keep_their_bound(ur5_checker):
    """ur5_table (example-robot-data meshes, link_fit hulls): the rows on convex pieces of the links
    take the pieces' own speed bound (motion_bound.piece_speed_bounds): every row's slope on 401
    samples of each move stays below its constant, and a verified move holds under that sampling."""
    from calib_oed.feasibility.pairs import feasibility_from_scene
    from calib_oed.feasibility.sampling import sample_feasible
    from calib_oed.scene.reader import load_scene

    scene = load_scene("ur5_table")
    ch = ur5_checker
    pieces = np.array([lbl.split(":")[1].split("|")[0] in ch.feasibility.hull_pairs.pieces
                       and "#" not in lbl for lbl in ch.collision_labels])
    assert pieces.sum() >= 5
    q = sample_feasible(feasibility_from_scene(scene)[0], 4, 3)
    t = np.linspace(0, 1, 401)
    worst, verified = 0.0, 0
    for i in range(len(q)):
        for j in range(i + 1, len(q)):
            g, _ = ch.rows(q[i] + t[:, None] * (q[j] - q[i]))
            slope = np.abs(np.diff(g, axis=0)).max(axis=0) / (t[1] - t[0])
            lip = ch.lipschitz(q[i], q[j])
            assert np.all(slope <= lip + 1e-9)
            worst = max(worst, float((slope[pieces] / lip[pieces]).max()))
            if ch.check(q[i], q[j]).verified:
                verified += 1
                assert g.min() >= -ch.tolerance
    assert worst > 0.1 and verified >= 3
