"""Benchmark: the capsule model against the exact mesh check, and the link geometry's tightness.

Run from the repository root (each cell alone, or all three):

    .venv/bin/python bench/bench_feasibility_mesh.py [--cells ur10 panda kr16] [--feasible 2000] [--single]

For each cell (bench/scenes/ur10_cell.yaml, bench/scenes/panda_cell.yaml, the
shipped fms_kr16): configurations are drawn uniformly in the joint limits
(seed 0) and those passing the joint and incidence rows (the same for both
models) are checked by

- the mesh check (coal on the URDF collision meshes, every robot-robot pair not
  adjacent, the cell's capsules and half-spaces, the beams), clearance = the
  scene's margin, the scene's excluded pairs plus the pairs the meshes never
  separate, and
- the optimiser's model (self, obstacle and beam rows of ``feasibility_from_scene``),

until ``--feasible`` configurations are mesh-feasible. Printed: the share of
mesh-feasible configurations the model accepts (target >= 90 %), the number
of mesh-rejected ones it accepts (must be 0; each is listed), the volume ratio
capsules / convex hull per link, the time of one values + Jacobian evaluation
of 60 poses, the time to sample 60 feasible poses and the model build time
(fit and mesh pairs, first and cached). ``--single`` uses one capsule per link
and no mesh pair decisions (the behaviour before issue 17) for comparison.
Process CPU time is printed next to wall time (the machine is shared).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.capsules import fit_capsules, load_collision_model
from calib_oed.feasibility.link_fit import LinkFitSettings, fit_link_capsules, fit_robot_links
from calib_oed.feasibility.mesh_check import check_design_meshes
from calib_oed.feasibility.mesh_pairs import dropped_mesh_pairs
from calib_oed.feasibility.pairs import build_feasibility_model
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.scene.reader import load_scene

HERE = Path(__file__).resolve().parent
CELLS = {"ur10": HERE / "scenes" / "ur10_cell.yaml", "panda": HERE / "scenes" / "panda_cell.yaml",
         "kr16": "fms_kr16"}


def clock():
    return time.perf_counter(), time.process_time()


def since(t):
    return time.perf_counter() - t[0], time.process_time() - t[1]


def hull_pieces(robot, geom, slabs):
    """Per link, convex pieces enclosing its geometry: the convex hulls of ``slabs`` equal
    slabs of its meshes along their principal axis (:func:`link_fit.slab_points`), or its
    primitives (convex already); each piece is ``(geometry object index, coal shape, T_geom_piece)``."""
    import coal

    from calib_oed.feasibility.link_fit import link_meshes, slab_points

    meshes = link_meshes(robot, geom)
    out: dict[str, list] = {}
    for k, go in enumerate(geom.geometryObjects):
        frame = robot.model.frames[go.parentFrame]
        mesh = meshes.get(frame.name)
        if mesh is None:
            out.setdefault(frame.name, []).append((k, go.geometry, pin.SE3.Identity()))
            continue
        if frame.name in out:
            continue  # the link's meshes are pieced once, in the link frame
        v = mesh.vertices
        u = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)[2][0]
        t = v @ u
        cuts = np.concatenate([[-np.inf], np.linspace(t.min(), t.max(), slabs + 1)[1:-1], [np.inf]])
        link_from_geom = frame.placement.actInv(go.placement)
        for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
            pts = slab_points(mesh, u, lo, hi)
            if len(pts) < 4:
                continue
            vec = coal.StdVec_Vec3s()
            for p in pts:
                vec.append(p)
            # the piece is in link coordinates: place it relative to geometry k
            out.setdefault(frame.name, []).append((k, coal.Convex.convexHull(vec, False, ""),
                                                   link_from_geom.inverse()))
    return out


def hull_distances(robot, geom, q, link_pairs, slabs):
    """Per pose and link pair, the smallest coal distance [m] between their convex pieces
    (:func:`hull_pieces`), (n, len(link_pairs))."""
    import coal

    pieces = hull_pieces(robot, geom, slabs)
    model, data = robot.model, robot.model.createData()
    gdata = pin.GeometryData(geom)
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    out = np.empty((len(q), len(link_pairs)))
    for i, qi in enumerate(q):
        pin.forwardKinematics(model, data, qi)
        pin.updateGeometryPlacements(model, data, geom, gdata)
        placed = {name: [(shape, gdata.oMg[k] * M) for k, shape, M in ps] for name, ps in pieces.items()}
        for p, (la, lb) in enumerate(link_pairs):
            best = np.inf
            for s1, M1 in placed[la]:
                for s2, M2 in placed[lb]:
                    res.clear()  # a DistanceResult keeps the smallest distance it has seen
                    best = min(best, coal.distance(s1, M1, s2, M2, req, res))
            out[i, p] = best
    return out


def near_pairs(robot, model, max_joints=3):
    """Link pairs of the kept self rows with at most ``max_joints`` joints between them."""
    from calib_oed.feasibility.mesh_pairs import _path_joints

    seg, parents = model.segments, list(robot.model.parents)
    pairs = {}
    for r, (i, j) in enumerate(model.pairs):
        if model.pair_kinds[r] != "self" or "reflector" in (seg.roles[i], seg.roles[j]):
            continue
        if len(_path_joints(parents, int(seg.body_a[i]), int(seg.body_a[j]))) <= max_joints:
            pairs.setdefault((seg.links[i], seg.links[j]), []).append(r)
    return pairs


def build(scene, single: bool, split_primitives: bool = False):
    kwargs = {}
    if single:
        kwargs = {"capsules": fit_capsules(scene.robot), "mesh_pairs": False}
    elif split_primitives:
        settings = LinkFitSettings(split_primitives=True)
        kwargs = {"capsules": fit_link_capsules(scene.robot, settings=settings), "mesh_pairs": True}
    # the fitted link geometry is the scene setting link_fit: split (default: single)
    feasibility = scene.feasibility if single else dataclasses.replace(scene.feasibility, link_fit="split")
    return build_feasibility_model(
        scene.robot, scene.cell, feasibility, scene.tracker.placement().translation,
        np.array([r.offset for r in scene.reflectors]), [r.name for r in scene.reflectors], **kwargs)


def run_cell(name: str, args) -> None:
    scene = load_scene(str(CELLS[name]))
    if args.no_scene_exclusions:
        scene = dataclasses.replace(scene, feasibility=dataclasses.replace(scene.feasibility, excluded_pairs=()))
    robot, fs = scene.robot, scene.feasibility
    t = clock()
    model, report = build(scene, args.single, args.split_primitives)
    first = since(t)
    t = clock()
    build(scene, args.single, args.split_primitives)
    cached = since(t)
    geom = load_collision_model(robot)
    never = [(p.link_a, p.link_b) for p in dropped_mesh_pairs(robot, fs.margins.clearance)
             if p.decision == "never separated"]
    excluded = tuple(fs.excluded_pairs) + tuple(never)
    tracker = scene.tracker.placement().translation
    offsets = np.array([r.offset for r in scene.reflectors])
    print(f"\n== {name}: {scene.name} ({'one capsule per link' if args.single else 'fitted link geometry'}) ==")
    print(f"model build (fit, mesh pairs, pruning) [s]: first {first[0]:.2f} wall / {first[1]:.2f} CPU, "
          f"again {cached[0]:.2f} wall / {cached[1]:.2f} CPU; {len(model.segments)} segments, "
          f"rows per pose {model.count_per_pose()}")
    for d in report.dropped:
        if d.reason.startswith("meshes"):
            print(f"  dropped {d.label}: {d.reason}")
    if not args.single:
        print("link       capsules  volume ratio capsules/hull (one capsule before)")
        settings = LinkFitSettings(split_primitives=args.split_primitives)
        for f in fit_robot_links(robot, geom, settings):
            print(f"  {f.link:20s} {len(f.capsules)}  {f.ratio:5.2f}  ({f.single_ratio:5.2f})")
    rng = np.random.default_rng(args.seed)
    geo_kinds = ("self", "obstacle", "beam")
    n_feas = n_acc = n_rej = n_bad = draws = 0
    bad: list[str] = []
    blockers: dict[str, int] = {}
    near = near_pairs(robot, model) if args.hulls else {}
    n_hull_acc = n_hull_bad = 0
    t = clock()
    while n_feas < args.feasible and draws < args.max_draws:
        q = rng.uniform(robot.lower, robot.upper, size=(20000, robot.nq))
        draws += len(q)
        states = compute_body_states(robot.model, q, jacobian=False)
        cheap = model.compute_from_states(q, states, jacobian=False, kinds=("joint", "incidence"))
        q = q[cheap.feasible][: max(args.feasible - n_feas, 0) * 2 + 50]
        if len(q) == 0:
            continue
        mesh = check_design_meshes(robot, q, scene.cell, tracker_position=tracker, reflector_offsets=offsets,
                                   beam_radius=fs.beam_radius, excluded_pairs=excluded,
                                   clearance=fs.margins.clearance, geometry_model=geom)
        res = model.compute_from_states(q, compute_body_states(robot.model, q, jacobian=False), jacobian=False,
                                        kinds=geo_kinds)
        ok = res.feasible
        if near:
            # the near pairs' capsule rows replaced by the convex-hull distance of their meshes
            hull = hull_distances(robot, geom, q, list(near), args.hulls) - fs.margins.clearance
            rows = [r for rs in near.values() for r in rs]
            keep = np.ones(res.values.shape[1], dtype=bool)
            keep[rows] = False  # pair rows come first among the self/obstacle/beam rows
            ok_hull = np.all(res.values[:, keep] >= -1e-6, axis=1) & np.all(hull >= 0.0, axis=1)
            n_hull_acc += int((mesh.feasible & ok_hull).sum())
            n_hull_bad += int((~mesh.feasible & ok_hull).sum())
        n_feas += int(mesh.feasible.sum())
        n_acc += int((mesh.feasible & ok).sum())
        n_rej += int((~mesh.feasible).sum())
        for i in np.flatnonzero(mesh.feasible & ~ok):
            label = res.labels[int(np.argmin(res.values[i]))].replace(".a|", "|").replace(".b|", "|")
            blockers[label] = blockers.get(label, 0) + 1
        wrong = np.flatnonzero(~mesh.feasible & ok)
        n_bad += len(wrong)
        for i in wrong[:5]:
            bad.append(f"q = {np.round(np.rad2deg(q[i]), 1).tolist()} deg: mesh {mesh.colliding_pairs[i][:3]}, "
                       f"min mesh distance {mesh.min_distance[i] * 1e3:.1f} mm")
    elapsed = since(t)
    print(f"{draws} draws, {n_feas + n_rej} pass joints and incidence, checked in {elapsed[0]:.1f} s wall / "
          f"{elapsed[1]:.1f} s CPU")
    print(f"mesh-feasible {n_feas}: the model accepts {n_acc} = {100.0 * n_acc / max(n_feas, 1):.1f} % "
          "(target >= 90 %)")
    top = sorted(blockers.items(), key=lambda kv: -kv[1])[:6]
    print("  most violated row where the model rejects a mesh-feasible one: "
          + "; ".join(f"{k} {v}" for k, v in top))
    print(f"mesh-rejected {n_rej}: the model accepts {n_bad} (must be 0)")
    for line in bad:
        print("  ACCEPTED BUT MESH-INFEASIBLE", line)
    if near:
        print(f"with convex pieces of the meshes ({args.hulls} slabs per link) for the {len(near)} near self pairs (<= 3 joints apart: "
              f"{', '.join('/'.join(p) for p in near)}): accepts {100.0 * n_hull_acc / max(n_feas, 1):.1f} % "
              f"of the mesh-feasible, {n_hull_bad} mesh-rejected")
    q60 = sample_feasible(model, 60, 0)
    t = clock()
    for _ in range(5):
        model.compute(q60)
    per = since(t)
    print(f"values + Jacobian, 60 poses [ms]: {per[0] / 5 * 1e3:.1f} wall / {per[1] / 5 * 1e3:.1f} CPU")
    t = clock()
    sample_feasible(model, 60, 1)
    samp = since(t)
    print(f"60 feasible poses sampled (seed 1) [s]: {samp[0]:.2f} wall / {samp[1]:.2f} CPU")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=list(CELLS), choices=list(CELLS))
    parser.add_argument("--feasible", type=int, default=2000)
    parser.add_argument("--max-draws", type=int, default=20_000_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--single", action="store_true", help="one capsule per link, no mesh pairs")
    parser.add_argument("--split-primitives", action="store_true",
                        help="one capsule per primitive for links without meshes (LinkFitSettings.split_primitives)")
    parser.add_argument("--hulls", type=int, default=0, metavar="SLABS",
                        help="also measure, for the near self pairs, the distance of convex pieces of the meshes "
                             "(SLABS slabs per link) in place of their capsules: what would close the gap")
    parser.add_argument("--no-scene-exclusions", action="store_true", help="ignore the scenes' excluded_pairs")
    args = parser.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, "
          f"pin {pin.__version__}")
    for name in args.cells:
        run_cell(name, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
