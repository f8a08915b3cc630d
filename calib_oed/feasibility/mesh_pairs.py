r"""Self-collision pairs decided on the collision meshes.

Two links of a serial arm whose meshes are always within the clearance margin
of each other (a motor housing against the link it drives, links on one
joint's two sides) can never be separated: checking them would make every
configuration infeasible. Such pairs are found on the real geometry, not on
fitted capsules: for every two links on different, non-adjacent bodies
(adjacent bodies are dropped by rule in both models), the coal distance of
their meshes is computed over configurations sampled in the joint ranges.

Only the joints between the two links move one relative to the other, so the
samples are a seeded uniform draw over the whole joint box (uniform on those
joints) plus, when at most two joints lie between the two links, a grid over
their ranges (``grid`` values per joint, limits included; the other joints at
the first random sample's values). Two decisions drop a pair:

- *never separated*: its largest sampled clearance is at most the margin (a
  housing): checking it would reject every configuration;
- *never within the margin*: at most two joints between the links and its
  smallest clearance over the grid and the draw exceeds the margin by ``buffer``
  (5 mm): the meshes do not come near, while fitted capsules may overlap
  (a UR10's ``wrist_1_link`` against its ``wrist_3_link``: 18.3-20.1 mm on the
  meshes).

Every other pair comes within the margin in some samples and out of it in
others: it can collide, and it is always kept. A pair's sampling stops as
soon as no decision can drop it (seen beyond the margin and within
``margin + buffer``), so a kept pair's range covers only the samples taken. Sampling cannot prove a pair
harmless between the samples; the decision is reported with its clearance
range, and the benchmark ``bench/bench_feasibility_mesh.py`` measures on fresh
configurations that no configuration the mesh check rejects is accepted.

All lengths in [m]; reasons print mm.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from calib_oed.feasibility import fit_cache
from calib_oed.feasibility.capsules import link_names, load_collision_model
from calib_oed.feasibility.link_fit import LinkFitSettings, geometry_key

__all__ = ["MeshPairClearance", "dropped_mesh_pairs", "mesh_pair_clearances"]


@dataclass(frozen=True)
class MeshPairClearance:
    """The sampled mesh clearance of two links.

    Attributes:
        link_a, link_b: Link names (base to tip order).
        joints: Names of the joints between them.
        min_clearance: Smallest sampled distance of their meshes [m].
        max_clearance: Largest sampled distance [m].
        samples: Number of configurations sampled.
        margin: The clearance margin [m].
    """

    link_a: str
    link_b: str
    joints: tuple[str, ...]
    min_clearance: float
    max_clearance: float
    samples: int
    margin: float

    buffer: float = 0.005

    @property
    def separable(self) -> bool:
        """Whether some sample puts the meshes more than ``margin`` apart."""
        return self.max_clearance > self.margin

    @property
    def decision(self) -> str | None:
        """``"never separated"``, ``"never within the margin"`` (dropped), or ``None`` (kept)."""
        if not self.separable:
            return "never separated"
        if len(self.joints) <= 2 and self.min_clearance > self.margin + self.buffer:
            return "never within the margin"
        return None

    @property
    def reason(self) -> str:
        """Why the pair is dropped (or kept), in mm."""
        what = self.decision or "can collide"
        return (f"meshes {what} ({self.margin * 1e3:.0f} mm margin; mesh clearance "
                f"{self.min_clearance * 1e3:.1f} to {self.max_clearance * 1e3:.1f} mm "
                f"over {self.samples} samples of joints {', '.join(self.joints) or 'none'})")


def _path_joints(parents, i: int, j: int) -> list[int]:
    """Joints between bodies i and j (those moving one relative to the other)."""
    up_i, up_j = [i], [j]
    while up_i[-1] != 0:
        up_i.append(parents[up_i[-1]])
    while up_j[-1] != 0:
        up_j.append(parents[up_j[-1]])
    common = set(up_i) & set(up_j)
    return sorted(b for b in up_i + up_j if b not in common)


def mesh_pair_clearances(robot, geometry_model: pin.GeometryModel | None = None, margin: float = 0.010,
                         samples: int = 200, seed: int = 0, grid: int = 21,
                         buffer: float = 0.005) -> tuple[MeshPairClearance, ...]:
    """Sampled mesh clearances of every pair of links on different, non-adjacent bodies.

    Args:
        robot: The robot.
        geometry_model: Collision geometry (:func:`load_collision_model` if ``None``).
        margin: Clearance margin [m].
        samples: Uniform configurations (seeded). A pair's evaluation stops as soon
            as no decision can drop it (clearances both above the margin and within
            ``margin + buffer`` seen): its range is then over the samples evaluated.
        seed: Seed of the draw.
        grid: Grid values per joint when at most two joints lie between the links.
        buffer: Extra clearance [m] a pair must keep over the margin to be dropped
            as never within it.
    """
    geom = load_collision_model(robot) if geometry_model is None else geometry_model
    model = robot.model
    parents = list(model.parents)
    objs = list(geom.geometryObjects)
    links = [model.frames[go.parentFrame].name for go in objs]
    bodies = [int(go.parentJoint) for go in objs]
    by_link: dict[str, list[int]] = {}
    for k, name in enumerate(links):
        by_link.setdefault(name, []).append(k)
    order = [n for n in link_names(robot) if n in by_link]
    base = robot.random_configurations(int(samples), seed)
    data = model.createData()
    gdata = pin.GeometryData(geom)
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    out = []
    for la, lb in itertools.combinations(order, 2):
        ba, bb = bodies[by_link[la][0]], bodies[by_link[lb][0]]
        if ba == bb or parents[ba] == bb or parents[bb] == ba:
            continue
        path = _path_joints(parents, ba, bb)
        qs = [base]
        if 0 < len(path) <= 2:
            idx = [model.idx_qs[j] for j in path]
            levels = [np.linspace(robot.lower[i], robot.upper[i], int(grid)) for i in idx]
            combos = np.array(list(itertools.product(*levels)))
            extra = np.repeat(base[:1], len(combos), axis=0)
            extra[:, idx] = combos
            qs.append(extra)
        q = np.vstack(qs)
        lo, hi, count = np.inf, -np.inf, 0
        for qi in q:
            pin.forwardKinematics(model, data, qi)
            pin.updateGeometryPlacements(model, data, geom, gdata)
            best = np.inf
            for k in by_link[la]:
                for m in by_link[lb]:
                    res.clear()
                    d = coal.distance(objs[k].geometry, gdata.oMg[k], objs[m].geometry, gdata.oMg[m], req, res)
                    best = min(best, float(d))
            lo, hi, count = min(lo, best), max(hi, best), count + 1
            if hi > margin and (lo <= margin + buffer or len(path) > 2):
                break  # no decision can drop the pair any more: it is kept
        names = tuple(model.names[j] for j in path)
        out.append(MeshPairClearance(la, lb, names, float(lo), float(hi), count, float(margin), float(buffer)))
    return tuple(out)


_CACHE: dict[str, tuple[MeshPairClearance, ...]] = {}


def dropped_mesh_pairs(robot, margin: float = 0.010, samples: int = 200, seed: int = 0,
                       geometry_model: pin.GeometryModel | None = None) -> tuple[MeshPairClearance, ...]:
    """The pairs of :func:`mesh_pair_clearances` with a :attr:`~MeshPairClearance.decision`.

    Cached per URDF text, joint limits, geometry and arguments, in the process and
    on disk (:mod:`calib_oed.feasibility.fit_cache`).
    """
    geom = load_collision_model(robot) if geometry_model is None else geometry_model
    h = hashlib.sha256(repr((float(margin), int(samples), int(seed), 1)).encode())
    h.update(robot.urdf_text.encode())
    h.update(np.asarray(robot.lower, dtype=float).tobytes() + np.asarray(robot.upper, dtype=float).tobytes())
    h.update(geometry_key(robot, geom, LinkFitSettings()).encode())
    key = h.hexdigest()
    if key not in _CACHE:
        cached = fit_cache.load("mesh_pairs", key)
        if cached is not None:
            _CACHE[key] = tuple(MeshPairClearance(**{**e, "joints": tuple(e["joints"])}) for e in cached)
    if key not in _CACHE:
        _CACHE[key] = tuple(p for p in mesh_pair_clearances(robot, geom, margin, samples, seed)
                            if p.decision is not None)
        fit_cache.store("mesh_pairs", key, [dataclasses.asdict(p) for p in _CACHE[key]])
    return _CACHE[key]
