r"""Which capsule pairs are checked, and why the others are not.

Candidates (paper §2.2): every pair of robot capsules (the reflector's capsule
counts as part of the tool link) except those on the same body, on adjacent
bodies, on two fixed bodies, or on a link pair the scene excludes; every moving
robot capsule against every obstacle capsule and half-space; every laser beam
against every robot capsule except those of the body carrying the reflector,
and against every obstacle.

A seeded sampling pass (uniform in the joint limits) then drops candidates
that cannot matter: clearance never below ``prune_distance``, clearance
constant (e.g. a link turning about the floor normal against the floor), or
overlapping in every sample (a capsule model too coarse to separate them:
reported loudly, since such a pair could never be satisfied). Sampling cannot
prove a pair harmless; the drop is reported with the sampled range so a user
can see it, and the independent mesh check (:mod:`calib_oed.feasibility.mesh_check`)
catches what the capsule model misses.

Self pairs checked on convex pieces of the link geometry
(:mod:`calib_oed.feasibility.hulls`, one row per link pair instead of the capsule
rows): with ``link_fit: hulls`` every pair of links at most three joints apart,
and with every fit to the URDF geometry a link pair whose capsules the sampling
pass never finds separated by the margin (their rows would reject every
configuration). The pieces' rows get the same sampling pass: never closer than
``prune_distance``, or never separated by the margin (a housing), drops them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from calib_oed.exceptions import UnknownLinkError
from calib_oed.feasibility.capsule_rows import CapsulePairRows, HalfspaceRows
from calib_oed.feasibility.constraints import FeasibilityModel, SegmentTable, build_segments
from calib_oed.feasibility.hull_rows import HullRows
from calib_oed.feasibility.shapes import Capsule, Cell, FeasibilitySettings
from calib_oed.feasibility.solid_rows import SolidRows
from calib_oed.feasibility.solids import solid_candidates
from calib_oed.model.robot import Robot


@dataclass(frozen=True)
class DroppedPair:
    """A candidate pair that is not checked.

    Attributes:
        label: ``"kind:segment|segment"``.
        reason: Why (``"adjacent links"``, ``"never closer than 100 mm"``, ...).
        min_clearance: Smallest sampled clearance [m] (NaN if not sampled).
        max_clearance: Largest sampled clearance [m] (NaN if not sampled).
        links: The two robot links of a self capsule pair the sampling pass dropped
            (``None`` otherwise).
    """

    label: str
    reason: str
    min_clearance: float = float("nan")
    max_clearance: float = float("nan")
    links: tuple[str, ...] | None = None


@dataclass(frozen=True)
class PairReport:
    """The pair selection, for reports.

    Attributes:
        checked: Labels of the checked capsule and half-space pairs.
        dropped: Pairs not checked, with reasons.
        n_links: Robot links with capsules (n of the paper's count).
        samples: Size of the sampling pass (0: no pruning).
        seed: Its seed.
    """

    checked: tuple[str, ...]
    dropped: tuple[DroppedPair, ...]
    n_links: int
    samples: int
    seed: int
    counts: dict = field(default_factory=dict)
    window: str = ""

    @property
    def paper_count(self) -> int:
        """Self-collision pairs by the paper's formula :math:`n(n-1)/2 - (n-1)`."""
        n = self.n_links
        return n * (n - 1) // 2 - (n - 1)

    def summary(self) -> str:
        lines = [f"checked pairs per pose: {len(self.checked)}; constraint rows per pose: "
                 + ", ".join(f"{k} {v}" for k, v in self.counts.items())
                 + " (a half-space pair gives a row per capsule end, one for a capsule of zero length)",
                 f"paper formula n(n-1)/2-(n-1) for n={self.n_links} links: {self.paper_count} self pairs"]
        if self.window:
            lines.append(self.window)
        by_reason: dict[str, int] = {}
        for d in self.dropped:
            key = d.reason.split(" (")[0]
            by_reason[key] = by_reason.get(key, 0) + 1
        for reason, count in by_reason.items():
            lines.append(f"dropped {count}: {reason}")
        for d in self.dropped:
            if d.reason.startswith(("overlapping", "never separated")):
                lines.append(f"  WARNING {d.label}: {d.reason}")
        return "\n".join(lines)


def _candidates(robot: Robot, seg: SegmentTable, cell: Cell, excluded: Sequence[tuple[str, str]],
                mesh_dropped: Sequence = ()):
    parents = robot.model.parents
    tool_body = int(robot.model.frames[robot.tool_frame_id].parentJoint)
    excl = {frozenset(p) for p in excluded}
    on_meshes = {frozenset((p.link_a, p.link_b)): p for p in mesh_dropped}
    ignored = {o.name: o.ignore_links for o in (*cell.capsules, *cell.halfspaces)}
    pairs, kinds, hs_pairs, hs_kinds, dropped = [], [], [], [], []
    body_roles = ("robot", "reflector")
    ns = len(seg)
    for i in range(ns):
        for j in range(i + 1, ns):
            ri, rj = seg.roles[i], seg.roles[j]
            bi, bj = int(seg.body_a[i]), int(seg.body_a[j])
            label_ij = f"{seg.names[i]}|{seg.names[j]}"
            if ri in body_roles and rj in body_roles:
                reason = None
                if bi == bj:
                    reason = "same body"
                elif parents[bi] == bj or parents[bj] == bi:
                    reason = "adjacent links"
                elif frozenset((seg.links[i], seg.links[j])) in excl:
                    reason = "excluded by the scene"
                elif frozenset((seg.links[i], seg.links[j])) in on_meshes:
                    mp = on_meshes[frozenset((seg.links[i], seg.links[j]))]
                    dropped.append(DroppedPair(f"self:{label_ij}", mp.reason, mp.min_clearance, mp.max_clearance))
                    continue
                if reason:
                    dropped.append(DroppedPair(f"self:{label_ij}", reason))
                else:
                    pairs.append((i, j))
                    kinds.append("self")
            elif {ri, rj} == {"obstacle"} or {ri, rj} == {"beam"}:
                continue
            elif "obstacle" in (ri, rj) and "beam" not in (ri, rj):
                body = bi if ri != "obstacle" else bj
                obst, link = (j, seg.links[i]) if ri != "obstacle" else (i, seg.links[j])
                if body == 0:
                    dropped.append(DroppedPair(f"obstacle:{label_ij}", "both fixed"))
                elif link in ignored.get(seg.names[obst], ()):
                    dropped.append(DroppedPair(f"obstacle:{label_ij}", "ignore_links of the obstacle"))
                else:
                    pairs.append((i, j))
                    kinds.append("obstacle")
            else:  # a beam and a robot/reflector capsule or an obstacle
                other = j if ri == "beam" else i
                if seg.roles[other] != "obstacle" and int(seg.body_a[other]) == tool_body:
                    dropped.append(DroppedPair(f"beam:{label_ij}", "carries the reflector"))
                else:
                    pairs.append((i, j) if ri == "beam" else (j, i))
                    kinds.append("beam")
    for i in range(ns):
        for h, hs in enumerate(cell.halfspaces):
            role = seg.roles[i]
            if role == "obstacle":
                continue
            if role != "beam" and int(seg.body_a[i]) == 0:
                dropped.append(DroppedPair(f"obstacle:{seg.names[i]}|{hs.name}", "both fixed"))
                continue
            if role != "beam" and seg.links[i] in hs.ignore_links:
                dropped.append(DroppedPair(f"obstacle:{seg.names[i]}|{hs.name}", "ignore_links of the obstacle"))
                continue
            hs_pairs.append((i, h))
            hs_kinds.append("beam" if role == "beam" else "obstacle")
    return pairs, kinds, hs_pairs, hs_kinds, dropped


def _hull_link_pairs(robot: Robot, seg: SegmentTable, pairs, kinds, hi: np.ndarray,
                     settings: FeasibilitySettings) -> dict[frozenset, str]:
    """Link pairs whose self rows are checked on convex pieces, and why: with
    ``link_fit: hulls`` those at most three joints apart; with every fit those with a
    capsule pair never separated by the margin in the sampling pass (``hi`` its
    largest clearance [m], NaN without the pass)."""
    from calib_oed.feasibility.mesh_pairs import _path_joints

    parents, margin = list(robot.model.parents), settings.margins.clearance
    out: dict[frozenset, str] = {}
    for k, (i, j) in enumerate(pairs):
        if kinds[k] != "self" or seg.roles[i] != "robot" or seg.roles[j] != "robot":
            continue
        key = frozenset((seg.links[i], seg.links[j]))
        joints = len(_path_joints(parents, int(seg.body_a[i]), int(seg.body_a[j])))
        if settings.link_fit == "hulls" and joints <= 3:
            out[key] = f"links {joints} joints apart"
        elif hi[k] < margin and key not in out:
            out[key] = (f"their capsules {seg.names[i]}, {seg.names[j]} are never separated by the "
                        f"{margin * 1e3:.0f} mm margin (largest clearance {hi[k] * 1e3:.1f} mm)")
    return out


def _prune_hulls(hulls, robot: Robot, q: np.ndarray, settings: FeasibilitySettings):
    """The sampling pass on convex-piece rows: the link pairs kept, and the dropped ones
    (never closer than the prune distance, or never separated by the margin: a housing
    the pieces, like the meshes they enclose, cannot clear)."""
    from calib_oed.feasibility.bodies import compute_body_states

    dist = hulls.closest(compute_body_states(robot.model, q, jacobian=False)).dist
    lo, hi = dist.min(axis=0), dist.max(axis=0)
    margin, n = settings.margins.clearance, len(q)
    kept, dropped = [], []
    for h, (label, pair) in enumerate(zip(hulls.labels, hulls.link_pairs, strict=True)):
        span = f"clearance {lo[h] * 1e3:.1f} to {hi[h] * 1e3:.1f} mm"
        if hi[h] <= margin:
            reason = (f"never separated by the {margin * 1e3:.0f} mm margin on convex pieces of the link "
                      f"geometry in {n} samples ({span}): a housing?")
        elif lo[h] > settings.prune_distance:
            reason = f"never closer than {settings.prune_distance * 1e3:.0f} mm in {n} samples ({span})"
        else:
            kept.append(pair)
            continue
        dropped.append(DroppedPair(label, reason, float(lo[h]), float(hi[h])))
    return kept, dropped


def build_feasibility_model(
    robot: Robot,
    cell: Cell,
    settings: FeasibilitySettings,
    tracker_position: np.ndarray,
    reflector_offsets: np.ndarray,
    reflector_names: Sequence[str] | None = None,
    capsules: Sequence[Capsule] | None = None,
    prune: bool = True,
    reflector_normals: np.ndarray | None = None,
    reflector_aims: Sequence[str] | None = None,
    mesh_pairs: bool | None = None,
    hulls: bool | None = None,
) -> tuple[FeasibilityModel, PairReport]:
    """Assemble the feasibility model of a cell and report the pair selection.

    Args:
        robot: The robot.
        cell: Obstacles.
        settings: Limits, margins, exclusions, pruning pass.
        tracker_position: Tracker origin in the world [m].
        reflector_offsets: Reflector offsets in the tool frame [m], (k, 3).
        reflector_names: Their names (default ``reflector0..``).
        capsules: Robot capsules (link frames); default: the scene's table or
            the capsules fitted to the URDF collision geometry, one per link or,
            with ``settings.link_fit == "hulls"``, several
            (:func:`calib_oed.feasibility.link_fit.fitted_robot_capsules`).
        prune: Run the sampling pass that drops pairs that cannot matter.
        reflector_normals: Reflector axes in the tool frame, (k, 3) (default tool z).
        reflector_aims: ``"fixed"`` or ``"manual"`` per reflector (default all fixed): a
            manually aimed reflector has no incidence row (its beam rows stay).
        mesh_pairs: Drop the self pairs decided on the collision meshes
            (:mod:`calib_oed.feasibility.mesh_pairs`); default: with the ``hulls``
            fit to the URDF geometry (no ``capsules``, no scene table).
        hulls: Check on convex pieces of the link geometry
            (:mod:`calib_oed.feasibility.hulls`) the self pairs whose capsules the
            pruning pass never finds separated by the margin and, with
            ``settings.link_fit == "hulls"``, every self pair of links at most three
            joints apart; default: when the capsules are fitted to the URDF geometry.
    """
    reflector_offsets = np.asarray(reflector_offsets, dtype=float).reshape(-1, 3)
    if reflector_names is None:
        reflector_names = [f"reflector{j}" for j in range(len(reflector_offsets))]
    from calib_oed.feasibility.capsules import link_names, robot_capsules
    from calib_oed.feasibility.link_fit import fitted_robot_capsules
    from calib_oed.feasibility.mesh_pairs import dropped_mesh_pairs

    split = settings.link_fit == "hulls"
    fitted = capsules is None and settings.robot_capsules is None
    if mesh_pairs is None:
        mesh_pairs = fitted and split
    if hulls is None:
        hulls = fitted
    if capsules is None:
        capsules = fitted_robot_capsules(robot, settings) if split else robot_capsules(robot, settings)
    links = set(link_names(robot))
    for pair in settings.excluded_pairs:
        for name in pair:
            if name not in links:
                raise UnknownLinkError(name, sorted(links))
    seg = build_segments(robot, capsules, cell, settings, tracker_position, reflector_offsets, reflector_names)
    on_meshes = dropped_mesh_pairs(robot, settings.margins.clearance) if mesh_pairs else ()
    pairs, kinds, hs_pairs, hs_kinds, dropped = _candidates(robot, seg, cell, settings.excluded_pairs, on_meshes)
    clearance = settings.margins.clearance
    solid_pairs, solid_kinds, _ = solid_candidates(seg, cell)
    candidates = (SolidRows(seg, cell, solid_pairs, solid_kinds, clearance),
                  CapsulePairRows(seg, pairs, kinds, clearance),
                  HalfspaceRows(seg, cell, hs_pairs, hs_kinds, clearance))
    args = (robot, seg, cell, settings, tracker_position, reflector_offsets, reflector_names, reflector_normals)
    model = FeasibilityModel(*args, families=candidates, reflector_aims=reflector_aims)
    n_links = len({c.frame for c in capsules})
    samples = int(settings.prune_samples) if prune else 0
    ranges, reasons = [], []
    if samples > 0:
        q = robot.random_configurations(samples, settings.prune_seed)
        values = model.compute_values(q)
    for family in candidates:
        if samples > 0:
            clear = family.pair_clearance(values[:, model.row_slice(family)], clearance)
            lo, hi = clear.min(axis=0), clear.max(axis=0)
            why = [family.prune_reason(lo[k], hi[k], samples, settings.prune_distance) for k in range(lo.size)]
        else:
            lo = hi = np.full(len(family.pair_labels), np.nan)
            why = [None] * lo.size
        ranges.append((lo, hi))
        reasons.append(why)
    capsule_pairs, (_, hi_pairs), pair_reasons = candidates[1], ranges[1], reasons[1]
    on_pieces = _hull_link_pairs(robot, seg, pairs, kinds, hi_pairs, settings) if hulls else {}
    converted: set[frozenset] = set()
    for k, (i, j) in enumerate(capsule_pairs.pairs):
        key = frozenset((seg.links[i], seg.links[j]))
        if kinds[k] == "self" and key in on_pieces and not (pair_reasons[k] or "").startswith("never closer"):
            converted.add(key)
            pair_reasons[k] = f"checked on convex pieces of the link geometry: {on_pieces[key]}"
    kept = []
    for family, (lo, hi), why in zip(candidates, ranges, reasons, strict=True):
        links = family.pair_links()
        for k, reason in enumerate(why):
            if reason:
                dropped.append(DroppedPair(family.pair_labels[k], reason, float(lo[k]), float(hi[k]),
                                           None if links[k] is None else tuple(sorted(links[k]))))
        kept.append(family.subset(np.array([r is None for r in why], dtype=bool)))
    if converted:
        from calib_oed.feasibility.capsules import load_collision_model
        from calib_oed.feasibility.hulls import HullPairs, link_pieces

        order = {n: i for i, n in enumerate(link_names(robot))}
        chosen = sorted((tuple(sorted(p, key=order.__getitem__)) for p in converted),
                        key=lambda p: (order[p[0]], order[p[1]]))
        pieces = link_pieces(robot, load_collision_model(robot), links={n for p in chosen for n in p})
        if samples > 0:
            chosen, hull_dropped = _prune_hulls(HullPairs(pieces, chosen), robot, q, settings)
            dropped += hull_dropped
        kept.insert(1, HullRows(HullPairs(pieces, chosen), clearance))
    model = FeasibilityModel(*args, families=kept, reflector_aims=reflector_aims)
    counts = {k: v for k, v in model.count_per_pose().items()}
    checked = tuple(dict.fromkeys(
        lbl for f in model.families for lbl, kind in zip(f.row_pair_labels, f.kinds, strict=True)
        if kind in ("self", "obstacle", "beam")
    ))
    report = PairReport(checked, tuple(dropped), n_links, samples, int(settings.prune_seed), counts)
    return model, report


def feasibility_from_scene(scene, prune: bool = True) -> tuple[FeasibilityModel, PairReport]:
    """The feasibility model of a :class:`calib_oed.scene.records.Scene` (its cell and settings),
    on the robot limited to the design joint window (:mod:`calib_oed.feasibility.window`)."""
    from calib_oed.feasibility.window import scene_window, windowed_robot

    window = scene_window(scene)
    model, report = build_feasibility_model(
        windowed_robot(scene.robot, window),
        scene.cell,
        scene.feasibility,
        scene.tracker.placement().translation,
        np.array([r.offset for r in scene.reflectors]),
        [r.name for r in scene.reflectors],
        prune=prune,
        reflector_normals=np.array([r.normal for r in scene.reflectors]),
        reflector_aims=[r.aim for r in scene.reflectors],
    )
    return model, replace(report, window=window.summary())
