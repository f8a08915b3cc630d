r"""Figures of designs and studies (matplotlib, no window).

Every function returns a new :class:`matplotlib.figure.Figure`, built
without ``pyplot``, to write with :func:`calib_oed.viz.plots.save_figure`.

- :func:`pose_contributions` / :func:`plot_pose_contributions`: what each
  pose of a design adds to the criterion.
- :func:`plot_improvement_distribution`: the paper's Figure 8, the
  distribution over many robots of a design's improvement.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from calib_oed.exceptions import NonFiniteError, NotIdentifiableError, ShapeError
from calib_oed.oed.criteria import DCriterion
from calib_oed.oed.criterion_base import Criterion
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.observability import ObservabilityIndex
from calib_oed.viz.plots import _colors, _problem

#: Kinds of per-pose contribution (:func:`pose_contributions`).
CONTRIBUTION_KINDS = ("leave_one_out", "sensitivity")


# ------------------------------------------------------ pose contributions
def _objective(objective_or_problem, criterion) -> DesignObjective:
    if isinstance(objective_or_problem, DesignObjective):
        obj = objective_or_problem
        if criterion is None:
            return obj
        return DesignObjective(obj.problem, criterion, p=obj.p, prior=obj.prior)
    return DesignObjective(_problem(objective_or_problem), "kpi" if criterion is None else criterion)


def _is_logarithmic(criterion: Criterion) -> bool:
    """Whether the criterion's value is a logarithm (D: log det C; O_k: -log O_k)."""
    return isinstance(criterion, (DCriterion, ObservabilityIndex))


def pose_contributions(
    objective_or_problem,
    q: np.ndarray,
    criterion: str | Criterion | None = None,
    *,
    kind: str = "leave_one_out",
) -> np.ndarray:
    r"""What each pose of design ``q`` contributes to the criterion, (n,), dimensionless.

    With the per-pose blocks :math:`\tilde F_i` and
    :math:`M = M_0 + \sum_i \tilde F_i^\top \tilde F_i`
    (:class:`~calib_oed.oed.objective.DesignObjective`), and :math:`Q` the
    criterion's quantity, :math:`Q = \phi` for variance criteria (``kpi``,
    ``params``, ``E``) and :math:`Q = e^\phi` for logarithmic ones
    (``D``: :math:`\det C`; ``O_k``: :math:`1/O_k`, for O1 without its
    :math:`1/\sqrt m`):

    - ``kind="leave_one_out"`` (exact): the relative increase
      :math:`Q(M_{-i})/Q(M) - 1` when pose :math:`i` is left out,
      :math:`M_{-i}` recomputed from the other poses' rows; ``inf`` when
      :math:`M_{-i}` is singular (the pose is indispensable).
    - ``kind="sensitivity"`` (equivalence theorem): with pose weights
      :math:`w_i` in :math:`M(w) = M_0 + \sum_i w_i\tilde F_i^\top\tilde F_i`,
      :math:`-\partial\log Q/\partial w_i` at :math:`w = 1`, that is
      :math:`-\mathrm{tr}(\Gamma\,\tilde F_i^\top\tilde F_i)/\phi` for variance
      criteria and :math:`-\mathrm{tr}(\Gamma\,\tilde F_i^\top\tilde F_i)` for
      logarithmic ones, :math:`\Gamma = \partial\phi/\partial M`. It is the
      first-order estimate of the leave-one-out value; for the convex A and D
      criteria leave-one-out :math:`\ge` sensitivity :math:`\ge 0`, and
      without a prior the sensitivities sum to 1 (A) or :math:`n_f` (D).
      O2 and O4 are not monotone in :math:`M`: their values can be negative.

    Args:
        objective_or_problem: A :class:`DesignObjective` (its criterion, parameters
            and prior), or a :class:`~calib_oed.calibration.problem.CalibrationProblem`
            / :class:`~calib_oed.calibration.workflow.Setup`.
        q: Design (n, nq) [rad].
        criterion: A criterion name (:data:`calib_oed.oed.criteria.CRITERIA`) or object;
            None: the objective's, or ``"kpi"`` for a problem.
        kind: One of :data:`CONTRIBUTION_KINDS`.

    Raises:
        NotIdentifiableError: the design itself is singular.
        ValueError: unknown ``kind``; a variance criterion with value <= 0.
    """
    if kind not in CONTRIBUTION_KINDS:
        raise ValueError(f"kind {kind!r}: valid kinds are {', '.join(map(repr, CONTRIBUTION_KINDS))}")
    obj = _objective(objective_or_problem, criterion)
    crit = obj.criterion
    q = np.asarray(q, dtype=float)
    value = obj.compute_value(q)  # names the parameters if the design is singular
    logarithmic = _is_logarithmic(crit)
    if not logarithmic and not value > 0.0:
        raise ValueError(f"criterion {crit.name}: relative contributions need a positive value, "
                         f"got {value:.6g}")
    blocks = obj.compute_blocks(q)
    n = blocks.shape[0]
    if kind == "sensitivity":
        gamma = crit.compute_gradient(obj.information(blocks))
        d_phi = np.einsum("jdf,fg,jdg->j", blocks, gamma, blocks)  # dphi/dw_j
        return -d_phi if logarithmic else -d_phi / value
    loo = np.full(n, np.inf)
    infos, kept = [], []
    for i in range(n):
        try:
            infos.append(obj.information(np.delete(blocks, i, axis=0)))
            kept.append(i)
        except NotIdentifiableError:  # fewer rows than free parameters without pose i
            pass
    if infos:
        values = crit.compute_values(np.stack(infos), singular="inf")
        loo[kept] = np.expm1(values - value) if logarithmic else values / value - 1.0
    return loo


def plot_pose_contributions(
    objective_or_problem,
    q: np.ndarray,
    criterion: str | Criterion | None = None,
) -> Figure:
    """Bar chart of :func:`pose_contributions` of design ``q``, in percent, in pose order.

    Bars: the exact leave-one-out increase [%] per pose (hatched red bars at
    the top of the axis for poses without which the design is singular);
    black dots: the first-order estimate from the equivalence theorem [%].

    Args:
        objective_or_problem, q, criterion: As :func:`pose_contributions`.

    Returns:
        A figure with one axis; bar ``i`` (left to right) has ``gid``
        ``"pose <j>"`` for pose ``j`` (0-based row of ``q``).
    """
    obj = _objective(objective_or_problem, criterion)
    crit = obj.criterion
    loo = pose_contributions(obj, q)
    first = pose_contributions(obj, q, kind="sensitivity")
    n = loo.size
    finite = np.isfinite(loo)
    top = 100.0 * max(loo[finite].max() if finite.any() else 0.0, first.max())
    cap = 1.15 * top if top > 0 else 1.0
    heights = np.where(finite, 100.0 * loo, cap)
    fig = Figure(figsize=(max(8.0, min(16.0, 0.22 * n + 3.0)), 5.0), layout="constrained")
    ax = fig.subplots()
    x = np.arange(n)
    bars = ax.bar(x, heights, color="C0")
    handles = [Patch(facecolor="C0", label="left out: exact increase")]
    for j, rect in enumerate(bars):
        rect.set_gid(f"pose {j}")
        if not finite[j]:
            rect.set(color="C3", hatch="//", alpha=0.6)
            ax.text(j, cap, "\u221e", ha="center", va="bottom", color="C3")
    if not finite.all():
        handles.append(Patch(facecolor="C3", hatch="//", alpha=0.6,
                             label="left out: design singular (\u221e)"))
        ax.set_ylim(top=1.1 * cap)
    handles += ax.plot(x, 100.0 * first, "o", color="k", ms=3.5, gid="sensitivity",
                       label="first order: \u2212\u2202log Q/\u2202w (equivalence theorem)")
    ax.set_xticks(x, [str(j) for j in x], fontsize=7 if n > 30 else 9,
                  rotation=90 if n > 30 else 0)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xlabel("pose (row of the design)")
    quantity = "det C" if isinstance(crit, DCriterion) else (
        f"1/{crit.name}" if isinstance(crit, ObservabilityIndex) else "the criterion")
    ax.set_ylabel(f"increase of {quantity} without the pose [%]")
    value = obj.compute_value(np.asarray(q, dtype=float))
    ax.set_title(f"Per-pose contributions to '{crit.name}', {crit.label}\n"
                 f"{n} poses, value {value:.4g}", fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    fig.legend(handles=handles, fontsize=8, loc="outside lower center", ncols=len(handles))
    return fig


# ------------------------------------------------------------ study figure
def plot_improvement_distribution(
    improvements: Mapping[str, Sequence[float]],
    *,
    xlabel: str = "improvement of KPI average variance [%]",
) -> Figure:
    """The paper's Figure 8: distribution over many robots of an improvement [%].

    One step histogram per comparison (e.g. ``"vs heuristic"``,
    ``"vs C_p-optimal"``), all on the same bins, with the mean (solid line)
    and median (dashed line) of each; 0 (no improvement) is marked grey.

    Args:
        improvements: Comparison name to improvements, one per robot [%].
        xlabel: Label of the horizontal axis.

    Returns:
        A figure with one axis; the mean and median lines have ``gid``
        ``"<name>: mean"`` and ``"<name>: median"``.

    Raises:
        ShapeError: a comparison has no values; NonFiniteError: NaN or inf.
    """
    if not improvements:
        raise ValueError("improvements: give at least one comparison name -> values [%]")
    data = {}
    for name, values in improvements.items():
        v = np.asarray(values, dtype=float).ravel()
        if v.size == 0:
            raise ShapeError(f"improvements {name!r}", "(N,) with N >= 1", v.shape)
        if not np.all(np.isfinite(v)):
            raise NonFiniteError(f"improvements {name!r}", np.flatnonzero(~np.isfinite(v)).tolist())
        data[str(name)] = v
    everything = np.concatenate(list(data.values()))
    n_max = max(v.size for v in data.values())
    edges = np.histogram_bin_edges(everything, bins=int(np.clip(round(np.sqrt(n_max) * 1.5), 8, 50)))
    fig = Figure(figsize=(8.0, 4.8), layout="constrained")
    ax = fig.subplots()
    for (name, v), color in zip(data.items(), _colors(len(data)), strict=True):
        mean, median = float(v.mean()), float(np.median(v))
        ax.hist(v, bins=edges, histtype="step", lw=1.8, color=color,
                label=f"{name} (N = {v.size}): mean {mean:.1f} %, median {median:.1f} %")
        ax.axvline(mean, color=color, lw=1.4, gid=f"{name}: mean")
        ax.axvline(median, color=color, lw=1.4, ls="--", gid=f"{name}: median")
    ax.axvline(0.0, color="0.6", lw=1.0, gid="zero", label="0: no improvement")
    ax.plot([], [], color="0.3", lw=1.4, label="mean")
    ax.plot([], [], color="0.3", lw=1.4, ls="--", label="median")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("number of robots")
    ax.set_title("Distribution of the improvement over robots", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return fig
