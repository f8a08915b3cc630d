"""Benchmark: the feasibility model against the exact mesh check, and the link geometry's tightness.

Run from the repository root (each cell alone, or all three):

    .venv/bin/python bench/bench_feasibility_mesh.py [--cells ur10 panda kr16] [--feasible 2000]
        [--fit before|single|split|hulls] [--slabs 4]

For each cell (bench/scenes/ur10_cell.yaml, bench/scenes/panda_cell.yaml, the
shipped fms_kr16): configurations are drawn uniformly in the joint limits
(seed 0) and those passing the joint and incidence rows (the same for both
models) are checked by

- the mesh check (coal on the URDF collision meshes, every robot-robot pair not
  adjacent, the cell's obstacles and half-spaces, the beams), clearance = the
  scene's margin, the scene's excluded pairs plus the pairs the meshes never
  separate, and
- the optimiser's model (self, obstacle and beam rows of ``build_feasibility_model``
  with the scene's settings and ``link_fit`` = ``--fit``),

until ``--feasible`` configurations are mesh-feasible. Printed: the share of
mesh-feasible configurations the model accepts (target >= 90 %), the number
of mesh-rejected ones it accepts (must be 0; each is listed), the volume ratio
capsules / convex hull per link, the time of one values + Jacobian evaluation
of 60 poses, the time to sample 60 feasible poses and the model build time
(fit, mesh pairs, convex pieces; first and cached). ``--fit before`` is one
capsule per link with no mesh pair decisions and no convex pieces (the model
before issue 17); ``--fit hulls`` (default) checks the self pairs of links at
most three joints apart on convex pieces (``--slabs`` per mesh link,
feasibility/hulls.py). Process CPU time is printed next to wall time (the
machine is shared).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from calib_oed.feasibility import hulls
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


def build(scene, fit: str, split_primitives: bool = False):
    """The model of ``scene`` with the link geometry ``fit``: ``before`` (one capsule per link, no
    mesh pair decisions, no convex pieces: the model before issue 17), ``split`` (the capsules and
    mesh pair decisions of ``hulls`` without its convex pieces), or a ``link_fit`` setting."""
    kwargs = {}
    if fit == "before":
        kwargs = {"capsules": fit_capsules(scene.robot), "mesh_pairs": False, "hulls": False}
    elif fit == "split":
        kwargs = {"hulls": False}
    if split_primitives:
        settings = LinkFitSettings(split_primitives=True)
        kwargs = {"capsules": fit_link_capsules(scene.robot, settings=settings), "mesh_pairs": True,
                  "hulls": True}
    feasibility = scene.feasibility
    if fit != "before":
        feasibility = dataclasses.replace(scene.feasibility, link_fit="hulls" if fit == "split" else fit)
    return build_feasibility_model(
        scene.robot, scene.cell, feasibility, scene.tracker.placement().translation,
        np.array([r.offset for r in scene.reflectors]), [r.name for r in scene.reflectors],
        reflector_normals=np.array([r.normal for r in scene.reflectors]), **kwargs)


def run_cell(name: str, args) -> None:
    scene = load_scene(str(CELLS[name]))
    if args.no_scene_exclusions:
        scene = dataclasses.replace(scene, feasibility=dataclasses.replace(scene.feasibility, excluded_pairs=()))
    robot, fs = scene.robot, scene.feasibility
    t = clock()
    model, report = build(scene, args.fit, args.split_primitives)
    first = since(t)
    t = clock()
    build(scene, args.fit, args.split_primitives)
    cached = since(t)
    geom = load_collision_model(robot)
    never = [(p.link_a, p.link_b) for p in dropped_mesh_pairs(robot, fs.margins.clearance)
             if p.decision == "never separated"]
    excluded = tuple(fs.excluded_pairs) + tuple(never)
    tracker = scene.tracker.placement().translation
    offsets = np.array([r.offset for r in scene.reflectors])
    print(f"\n== {name}: {scene.name} (link geometry: {args.fit}) ==")
    print(f"model build (fit, mesh pairs, pruning) [s]: first {first[0]:.2f} wall / {first[1]:.2f} CPU, "
          f"again {cached[0]:.2f} wall / {cached[1]:.2f} CPU; {len(model.segments)} segments, "
          f"rows per pose {model.count_per_pose()}")
    for d in report.dropped:
        if d.reason.startswith("meshes") or "convex" in d.reason:
            print(f"  dropped {d.label}: {d.reason}")
    print(f"  checked on convex pieces ({hulls.SLABS} slabs per mesh link): {', '.join(model.hull_pairs.labels)}")
    if args.fit != "before":
        print("link       capsules  volume ratio capsules/hull (one capsule before)")
        settings = LinkFitSettings(split_primitives=args.split_primitives)
        for f in fit_robot_links(robot, geom, settings):
            print(f"  {f.link:20s} {len(f.capsules)}  {f.ratio:5.2f}  ({f.single_ratio:5.2f})")
    rng = np.random.default_rng(args.seed)
    geo_kinds = ("self", "obstacle", "beam")
    n_feas = n_acc = n_rej = n_bad = draws = 0
    bad: list[str] = []
    blockers: dict[str, int] = {}
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


def vhacd_enclosure(names=("ur10", "panda"), hulls_per_link=4) -> None:
    """The alternative to slab hulls, a convex decomposition (V-HACD, the ``vhacdx`` package): how
    far do the mesh vertices lie outside its pieces? (Pieces must enclose the mesh: a vertex d
    outside lets a configuration d closer than the margin pass.)"""
    import vhacdx
    from scipy.spatial import ConvexHull

    from calib_oed import load_robot

    for name in names:
        robot = load_robot(name)
        for go in load_collision_model(robot).geometryObjects:
            g = go.geometry
            if not hasattr(g, "vertices"):
                continue
            v = np.asarray(g.vertices(), float).reshape(-1, 3)
            f = np.array([[g.tri_indices(i)[k] for k in range(3)] for i in range(g.num_tris)], dtype=np.uint32)
            t = clock()
            pieces = vhacdx.compute_vhacd(v, f, maxConvexHulls=hulls_per_link, resolution=100000)
            dt = since(t)
            out = np.full(len(v), np.inf)
            for hv, _ in pieces:
                eq = ConvexHull(hv).equations  # n^T x + c <= 0 inside; the max is a lower bound of the distance
                out = np.minimum(out, (v @ eq[:, :3].T + eq[:, 3]).max(axis=1))
            print(f"{name} {go.name}: {len(pieces)} V-HACD pieces, vertices > 1 mm outside {(out > 1e-3).sum()} "
                  f"of {len(v)}, worst {out.max() * 1e3:.1f} mm ({dt[1]:.2f} s CPU)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=list(CELLS), choices=list(CELLS))
    parser.add_argument("--feasible", type=int, default=2000)
    parser.add_argument("--max-draws", type=int, default=20_000_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fit", default="hulls", choices=("before", "single", "split", "hulls"),
                        help="link geometry: the scene setting link_fit, or 'before' (one capsule per link, "
                             "no mesh pair decisions, no convex pieces: the model before issue 17)")
    parser.add_argument("--split-primitives", action="store_true",
                        help="one capsule per primitive for links without meshes (LinkFitSettings.split_primitives)")
    parser.add_argument("--slabs", type=int, default=hulls.SLABS,
                        help="slabs per mesh link of the convex pieces (feasibility/hulls.py)")
    parser.add_argument("--no-scene-exclusions", action="store_true", help="ignore the scenes' excluded_pairs")
    parser.add_argument("--vhacd", action="store_true",
                        help="only measure how well a V-HACD convex decomposition encloses the ur10 and panda meshes")
    args = parser.parse_args(argv)
    if args.vhacd:
        vhacd_enclosure()
        return 0
    hulls.SLABS = args.slabs
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, "
          f"pin {pin.__version__}")
    for name in args.cells:
        run_cell(name, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
