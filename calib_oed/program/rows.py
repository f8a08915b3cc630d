r"""The rows the continuous check evaluates, split into cheap rows and rows on convex pieces.

The collision rows of a move (:mod:`calib_oed.program.continuous`) come from two
feasibility models of the scene: the design's (every collision row it keeps) and,
for the pairs its sampling pass dropped as never close, the model without the pass.
Most rows are capsule distances, half-spaces and solids, vectorised over all samples
at once. Rows on convex pieces of the link geometry (``hull_pairs``,
:mod:`calib_oed.feasibility.hulls`) call coal per sample and link pair: on ur5_table
with ``link_fit: hulls`` they are 95 % of an evaluation. The bisection only needs a
row's value at a new midpoint where that row is not yet certified on the interval
being split (a bound that holds on an interval holds on its halves), so
:class:`CollisionRows` evaluates the cheap rows of every sample and the rows on
convex pieces only for the (sample, row) pairs asked for.

The cheap rows are those of a twin of each model, built with the same capsule,
half-space and solid pairs and no convex pieces; the twin's labels must equal the
model's without the convex-piece rows (else the model is evaluated whole and
nothing is deferred). Values are the model's own: :math:`g = d - m_d` [m], the
convex-piece distance less the clearance margin, as
:meth:`calib_oed.feasibility.constraints.FeasibilityModel.compute_from_states`.
"""

from __future__ import annotations

import numpy as np

from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.constraints import FeasibilityModel

COLLISION_KINDS = ("self", "obstacle")
SIGHT_KINDS = ("beam", "incidence")
ASKED = COLLISION_KINDS + SIGHT_KINDS


def base_label(label: str) -> str:
    """A row label without its half-space end marker (``.a|``, ``.b|``): the pair label."""
    return label.replace(".a|", "|").replace(".b|", "|")


def _twin(model: FeasibilityModel) -> FeasibilityModel | None:
    """``model`` without its convex-piece rows (``None`` if it has none, or if the twin's
    rows are not the model's other rows in the same order)."""
    if len(model.hull_pairs) == 0:
        return None
    twin = FeasibilityModel(
        model.robot, model.segments, model.pairs, model.pair_kinds, model.halfspace_pairs,
        model.halfspace_kinds, model.cell, model.settings, model.tracker_position,
        model.reflector_offsets, model.reflector_names, reflector_normals=model.reflector_normals,
        solid_pairs=model.solid_pairs.pairs, solid_kinds=model.solid_kinds,
        reflector_aims=model.reflector_aims)
    hulls = set(model.hull_pairs.labels)
    rest = [(k, lbl) for k, lbl in zip(model.kinds, model.labels, strict=True) if lbl not in hulls]
    return twin if rest == list(zip(twin.kinds, twin.labels, strict=True)) else None


def _hull_links(label: str) -> frozenset[str]:
    """The two links of a convex-piece row ``self:<link_a>|<link_b>``."""
    return frozenset(label.split(":", 1)[1].split("|"))


def _link_pairs(model: FeasibilityModel, labels: frozenset[str]) -> set[frozenset[str]]:
    """The robot link pairs of the self capsule pairs among ``labels`` (``self:A|B``, A and B
    capsule names of ``model``'s segments)."""
    link = {str(n): str(lk) for n, lk, role in zip(model.segments.names, model.segments.links,
                                                   model.segments.roles, strict=True)
            if role in ("robot", "reflector")}
    out = set()
    for label in labels:
        kind, _, body = label.partition(":")
        a, _, b = body.partition("|")
        if kind == "self" and a in link and b in link:
            out.add(frozenset((link[a], link[b])))
    return out


class _Source:
    """The columns one model contributes: cheap ones (from the twin or the whole model) and
    convex-piece rows (``hull``: indices into ``model.hull_pairs``)."""

    def __init__(self, model: FeasibilityModel, keep):
        self.model, self.twin = model, _twin(model)
        cheap_model = self.twin or model
        mask = cheap_model.row_mask(ASKED)
        kinds = [k for k, m in zip(cheap_model.kinds, mask, strict=True) if m]
        labels = [lbl for lbl, m in zip(cheap_model.labels, mask, strict=True) if m]
        hull_labels = set(model.hull_pairs.labels) if self.twin is not None else set()
        self.cheap_cols = np.array([r for r, (k, lbl) in enumerate(zip(kinds, labels, strict=True))
                                    if lbl not in hull_labels and keep(k, lbl)], dtype=int)
        self.cheap_labels = [labels[r] for r in self.cheap_cols]
        self.sight_cols = np.array([r for r, k in enumerate(kinds) if k in SIGHT_KINDS], dtype=int)
        self.sight_labels = [labels[r] for r in self.sight_cols]
        self.hull = np.array([h for h, lbl in enumerate(model.hull_pairs.labels)
                              if lbl in hull_labels and keep("self", lbl)], dtype=int)
        self.hull_labels = [model.hull_pairs.labels[h] for h in self.hull]

    def cheap(self, q: np.ndarray, states: BodyStates) -> np.ndarray:
        model = self.twin or self.model
        return model.compute_from_states(q, states, jacobian=False, kinds=ASKED).values

    def hull_values(self, states: BodyStates, rows: np.ndarray) -> np.ndarray:
        """Convex-piece rows ``rows`` (indices into ``hull_pairs``) at every pose of ``states``."""
        clearance = self.model.settings.margins.clearance
        return self.model.hull_pairs.closest(states, rows).dist - clearance


class CollisionRows:
    """The collision and line-of-sight rows of the continuous check.

    Columns: the design's cheap collision rows, the extra model's cheap rows, the design's
    convex-piece rows, the extra model's convex-piece rows (``labels``); the first
    ``n_cheap`` are evaluated at every sample, the rest on request (:meth:`evaluate`).

    Args:
        feasibility: The design's model.
        ignore: Pair labels not checked.
        extra: The model without the sampling pass, or ``None``.
        extra_rows: Pair labels of ``extra`` checked too (those the pass dropped as far).
    """

    def __init__(self, feasibility: FeasibilityModel, ignore: frozenset[str] = frozenset(),
                 extra: FeasibilityModel | None = None, extra_rows: frozenset[str] = frozenset()):
        def design_keep(kind, label):
            return kind in COLLISION_KINDS and base_label(label) not in ignore

        self.design = _Source(feasibility, design_keep)
        have = {base_label(lbl) for lbl in self.design.cheap_labels + self.design.hull_labels}

        far_links = _link_pairs(extra, extra_rows) if extra is not None else set()
        hull_labels = set(extra.hull_pairs.labels) if extra is not None else set()

        def extra_keep(kind, label):
            b = base_label(label)
            if kind not in COLLISION_KINDS or b in have or b in ignore:
                return False
            # a far capsule pair whose links the model without the pass checks on convex pieces
            return b in extra_rows or (label in hull_labels and _hull_links(label) in far_links)

        self.extra = _Source(extra, extra_keep) if extra is not None else None
        sources = [self.design] + ([self.extra] if self.extra is not None else [])
        cheap = [lbl for s in sources for lbl in s.cheap_labels]
        hull = [lbl for s in sources for lbl in s.hull_labels]
        self.labels = tuple(cheap + hull)
        self.n_cheap = len(cheap)
        self.sight_labels = tuple(self.design.sight_labels)
        # which source and hull row each deferred column is
        self._deferred = [(s, int(h)) for s in sources for h in s.hull]

    @property
    def n(self) -> int:
        return len(self.labels)

    def evaluate(self, q: np.ndarray, states: BodyStates, need: np.ndarray | None = None):
        """Collision rows (n, m) [m] and line-of-sight rows (n, m_s) at configurations ``q``
        with body states ``states``; a deferred column is evaluated where ``need`` (n, m - n_cheap)
        is True (default: everywhere) and NaN elsewhere."""
        n = len(q)
        values = self.design.cheap(q, states)
        parts = [values[:, self.design.cheap_cols]]
        sight = values[:, self.design.sight_cols]
        if self.extra is not None and len(self.extra.cheap_cols):
            parts.append(self.extra.cheap(q, states)[:, self.extra.cheap_cols])
        deferred = np.full((n, len(self._deferred)), np.nan)
        if need is None or need.all():  # every deferred row at every sample: one call per source
            done = 0
            for source in (self.design, self.extra):
                if source is not None and len(source.hull):
                    deferred[:, done:done + len(source.hull)] = source.hull_values(states, source.hull)
                    done += len(source.hull)
            return np.concatenate(parts + [deferred], axis=1), sight
        for col, (source, h) in enumerate(self._deferred):
            idx = np.flatnonzero(need[:, col])
            if idx.size == n:
                deferred[:, col] = source.hull_values(states, np.array([h]))[:, 0]
            elif idx.size:
                deferred[idx, col] = source.hull_values(states.take(idx), np.array([h]))[:, 0]
        return np.concatenate(parts + [deferred], axis=1), sight
