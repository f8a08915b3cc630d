r"""Figures of designs, identifications and studies (matplotlib, no window).

Every function returns a new :class:`matplotlib.figure.Figure`, built
without ``pyplot`` (no global figure registry, nothing to close, no display):
write it with :func:`save_figure`, which renders with Agg (PNG), or the SVG
and PDF backends. Lengths are plotted in mm; inputs are SI (m, m²) unless an
argument says otherwise.

- :func:`plot_kpi_ellipsoids` / :func:`plot_covariance_ellipses`: the paper's
  Figure 7, the 95 % confidence region of the KPI (TCP position at a
  working configuration) of several designs, projected onto the xy, xz and
  yz planes. Drawn are the *marginal* ellipses
  :math:`\{y : y^\top C_{JJ}^{-1} y \le \chi^2_2(\mathrm{level})\}` of the two
  plotted coordinates :math:`J` (each holds them with probability
  ``level``; :meth:`calib_oed.calibration.confidence.ConfidenceEllipsoid.marginal`),
  centred at 0, the deviation from the estimate.
- :func:`pose_contributions` / :func:`plot_pose_contributions`: what each
  pose of a design adds to the criterion.
- :func:`plot_residuals`: residuals of an identification and their histogram
  against the standard normal density.
- :func:`plot_improvement_distribution`: the paper's Figure 8, the
  distribution over many robots of a design's improvement.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import scipy.stats
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from calib_oed.calibration.confidence import ConfidenceEllipsoid
from calib_oed.calibration.identification_result import IdentificationResult
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.exceptions import ExportError, NonFiniteError, NotIdentifiableError, ShapeError
from calib_oed.io.atomic import atomic_write
from calib_oed.oed.criteria import Criterion, DCriterion, ObservabilityIndex
from calib_oed.oed.objective import DesignObjective

#: Millimetres per metre, milliradians per radian.
MM_PER_M = 1e3
MRAD_PER_RAD = 1e3
#: File suffixes :func:`save_figure` writes, and the matplotlib format of each.
FIGURE_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}
#: Kinds of per-pose contribution (:func:`pose_contributions`).
CONTRIBUTION_KINDS = ("leave_one_out", "sensitivity")
#: Coordinate planes of :func:`plot_covariance_ellipses`: name and the two axes.
PLANES = (("xy", (0, 1)), ("xz", (0, 2)), ("yz", (1, 2)))
#: Normalised residuals beyond this [sigma] are counted in the edge bins of the histogram.
HISTOGRAM_LIMIT = 6.0


def _colors(n: int) -> list:
    """``n`` distinct colours of matplotlib's default cycle (tab10, repeated)."""
    return [f"C{k % 10}" for k in range(n)]


def _problem(problem_or_setup) -> CalibrationProblem:
    """The calibration problem of a problem or of a :class:`calib_oed.calibration.workflow.Setup`."""
    problem = getattr(problem_or_setup, "problem", problem_or_setup)
    if not isinstance(problem, CalibrationProblem):
        raise TypeError("expected a CalibrationProblem or a workflow Setup, got "
                        f"{type(problem_or_setup).__name__}")
    return problem


# ------------------------------------------------------ confidence ellipses
def plot_covariance_ellipses(
    covariances: Mapping[str, np.ndarray],
    *,
    level: float = 0.95,
    title: str | None = None,
) -> Figure:
    r"""Marginal confidence ellipses of 3-D positions in the xy, xz and yz planes, in mm.

    One closed curve per entry, centred at 0 (deviation from the estimate),
    :math:`\{y : y^\top C_{JJ}^{-1} y \le \chi^2_2(\mathrm{level})\}` for the
    coordinate pairs :math:`J` of :data:`PLANES`; its extent along axis
    :math:`k` is :math:`\sqrt{\chi^2_2(\mathrm{level})\,C_{kk}}`. The legend
    gives each entry's :math:`\sigma = \sqrt{\mathrm{tr}(C)/3}` [mm].

    Args:
        covariances: Name (e.g. ``"KPI-optimal"``) to covariance :math:`C`,
            (3, 3) [m²], symmetric positive definite.
        level: Confidence level in (0, 1).
        title: Figure title (default: says what is drawn).

    Returns:
        A figure with three axes, ``fig.axes`` in the order of :data:`PLANES`;
        each curve is a line whose ``gid`` is the entry's name.

    Raises:
        ShapeError: a covariance is not (3, 3).
        NotPositiveDefiniteError, NonFiniteError, ConfidenceLevelError: from
            :class:`~calib_oed.calibration.confidence.ConfidenceEllipsoid`.
    """
    if not covariances:
        raise ValueError("covariances: give at least one name -> (3, 3) covariance [m^2]")
    ellipsoids = []
    for name, cov in covariances.items():
        cov = np.asarray(cov, dtype=float)
        if cov.shape != (3, 3):
            raise ShapeError(f"covariance of {name!r}", "(3, 3) [m^2]", cov.shape)
        ellipsoids.append(ConfidenceEllipsoid(np.zeros(3), cov, level, str(name)))
    fig = Figure(figsize=(12.5, 4.8), layout="constrained")
    axes = fig.subplots(1, 3)
    colors = _colors(len(ellipsoids))
    for ax, (plane, dims) in zip(axes, PLANES, strict=True):
        for e, color in zip(ellipsoids, colors, strict=True):
            sigma_mm = math.sqrt(np.trace(e.covariance) / 3.0) * MM_PER_M
            xy = e.projection(dims, kind="marginal").boundary(361) * MM_PER_M
            ax.plot(xy[:, 0], xy[:, 1], color=color, lw=1.6, gid=e.name,
                    label=f"{e.name}: \u03c3 = {sigma_mm:#.3g} mm")
        ax.plot([0.0], [0.0], "+", color="0.3", ms=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(f"\u0394{plane[0]} [mm]")
        ax.set_ylabel(f"\u0394{plane[1]} [mm]")
        ax.set_title(f"{plane} plane: marginal {level:.0%} region")
        ax.grid(True, alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 4),
               title="design: KPI \u03c3 = \u221a(tr C/3)")
    fig.suptitle(title or f"{level:.0%} confidence regions, deviation from the estimate "
                 f"(marginal ellipses, \u03c7\u00b2 with 2 degrees of freedom)")
    return fig


def plot_kpi_ellipsoids(
    problem,
    designs: Mapping[str, np.ndarray],
    *,
    kpi_index: int = 0,
    level: float = 0.95,
) -> Figure:
    r"""The paper's Figure 7: KPI confidence regions of several designs, in mm.

    For each design :math:`q`, the 3×3 block of working configuration
    ``kpi_index`` of :math:`C_s(q)` (``problem.kpi_covariance``, [m²]) is drawn
    by :func:`plot_covariance_ellipses` (marginal ellipses in the xy, xz and yz
    planes of the world frame). To plot covariances you already have, call
    that function directly.

    Args:
        problem: A :class:`~calib_oed.calibration.problem.CalibrationProblem` (or a
            :class:`~calib_oed.calibration.workflow.Setup`).
        designs: Name (``"heuristic"``, ``"KPI-optimal"``, ...) to
            configurations (n, nq) [rad], or to a record with a ``q``
            attribute (:class:`~calib_oed.oed.result.Design`).
        kpi_index: Which working configuration, 0 .. t-1.
        level: Confidence level in (0, 1).

    Raises:
        ValueError: ``kpi_index`` out of range (the message lists the
            working configurations).
    """
    problem = _problem(problem)
    names = problem.kpi.names
    if isinstance(kpi_index, bool) or not isinstance(kpi_index, (int, np.integer)) \
            or not 0 <= kpi_index < len(names):
        valid = ", ".join(f"{i} ({n})" for i, n in enumerate(names))
        raise ValueError(f"kpi_index {kpi_index!r}: the working configurations are {valid}")
    k = 3 * int(kpi_index)
    covariances = {}
    for name, q in designs.items():
        c_s = problem.kpi_covariance(np.asarray(getattr(q, "q", q), dtype=float))
        covariances[name] = c_s[k : k + 3, k : k + 3]
    return plot_covariance_ellipses(
        covariances, level=level,
        title=f"KPI '{names[kpi_index]}' (TCP position, world frame): {level:.0%} confidence "
              "regions, deviation from the estimate (marginal ellipses, \u03c7\u00b2\u2082)",
    )


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
    *,
    sort: bool = False,
    sensitivity: bool = True,
) -> Figure:
    """Bar chart of :func:`pose_contributions` of design ``q``, in percent.

    Bars: the exact leave-one-out increase [%] per pose (hatched red bars at
    the top of the axis for poses without which the design is singular);
    black dots: the first-order estimate from the equivalence theorem [%].

    Args:
        objective_or_problem, q, criterion: As :func:`pose_contributions`.
        sort: Largest contribution first (tick labels keep the pose numbers);
            otherwise in pose order.
        sensitivity: Also draw the first-order estimate.

    Returns:
        A figure with one axis; bar ``i`` (left to right) has ``gid``
        ``"pose <j>"`` for pose ``j`` (0-based row of ``q``).
    """
    obj = _objective(objective_or_problem, criterion)
    crit = obj.criterion
    loo = pose_contributions(obj, q)
    first = pose_contributions(obj, q, kind="sensitivity") if sensitivity else None
    n = loo.size
    finite = np.isfinite(loo)
    order = np.argsort(-np.where(finite, loo, np.inf), kind="stable") if sort else np.arange(n)
    top = 100.0 * max(loo[finite].max() if finite.any() else 0.0,
                      first.max() if first is not None else 0.0)
    cap = 1.15 * top if top > 0 else 1.0
    heights = np.where(finite, 100.0 * loo, cap)[order]
    fig = Figure(figsize=(max(8.0, min(16.0, 0.22 * n + 3.0)), 5.0), layout="constrained")
    ax = fig.subplots()
    x = np.arange(n)
    bars = ax.bar(x, heights, color="C0")
    handles = [Patch(facecolor="C0", label="left out: exact increase")]
    for k, (rect, j) in enumerate(zip(bars, order, strict=True)):
        rect.set_gid(f"pose {j}")
        if not finite[j]:
            rect.set(color="C3", hatch="//", alpha=0.6)
            ax.text(k, cap, "\u221e", ha="center", va="bottom", color="C3")
    if not finite.all():
        handles.append(Patch(facecolor="C3", hatch="//", alpha=0.6,
                             label="left out: design singular (\u221e)"))
        ax.set_ylim(top=1.1 * cap)
    if first is not None:
        handles += ax.plot(x, 100.0 * first[order], "o", color="k", ms=3.5, gid="sensitivity",
                           label="first order: \u2212\u2202log Q/\u2202w (equivalence theorem)")
    ax.set_xticks(x, [str(j) for j in order], fontsize=7 if n > 30 else 9,
                  rotation=90 if n > 30 else 0)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xlabel("pose (row of the design)" + (", largest contribution first" if sort else ""))
    quantity = "det C" if isinstance(crit, DCriterion) else (
        f"1/{crit.name}" if isinstance(crit, ObservabilityIndex) else "the criterion")
    ax.set_ylabel(f"increase of {quantity} without the pose [%]")
    value = obj.compute_value(np.asarray(q, dtype=float))
    ax.set_title(f"Per-pose contributions to '{crit.name}', {crit.label}\n"
                 f"{n} poses, value {value:.4g}", fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    fig.legend(handles=handles, fontsize=8, loc="outside lower center", ncols=len(handles))
    return fig


# --------------------------------------------------------------- residuals
def _residual_components(result: IdentificationResult) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Positions (m, 3) [mm], rotations (m', 3) [mrad] or None, block offsets (k+1,) in rows."""
    pos, rot, offsets = [], [], [0]
    for k, raw in enumerate(result.block_residuals):
        d = raw.shape[1]
        if d not in (3, 6):
            raise ShapeError(f"residuals of block {k} ({result.block_names[k]})",
                             "(n, 3) position or (n, 6) pose", raw.shape)
        pos.append(raw[:, :3] * MM_PER_M)
        # rows without rotation components are NaN: matplotlib leaves them out
        rot.append(raw[:, 3:] * MRAD_PER_RAD if d == 6 else np.full((raw.shape[0], 3), np.nan))
        offsets.append(offsets[-1] + raw.shape[0])
    rot_all = np.vstack(rot)
    return np.vstack(pos), (None if np.all(np.isnan(rot_all)) else rot_all), np.array(offsets)


def plot_residuals(result: IdentificationResult) -> Figure:
    r"""Residuals of an identification: per measurement and as a histogram.

    Left: the raw residual components :math:`h - \eta` of every measurement,
    position x, y, z [mm] (and, for pose data, rotation [mrad] below), against
    the measurement index (blocks one after the other, separated by dotted
    lines); outliers (``result.outliers``) are circled in red. Right: the
    histogram of the weighted residuals :math:`r` (``result.residuals``,
    [σ]) with the expected counts of the standard normal density; values
    beyond ±:data:`HISTOGRAM_LIMIT` σ are counted in the edge bins, so the
    counts sum to ``result.residuals.size``.

    Returns:
        A figure; ``fig.axes``: position residuals, (rotation residuals),
        histogram (last). Outlier markers have ``gid`` ``"outliers"``.
    """
    pos, rot, offsets = _residual_components(result)
    out_rows = np.array([offsets[o.block] + o.row for o in result.outliers], dtype=int)
    fig = Figure(figsize=(13.0, 5.0 if rot is None else 7.0), layout="constrained")
    grid = fig.add_gridspec(1 if rot is None else 2, 2, width_ratios=(2.2, 1.0))
    scatter_axes = [fig.add_subplot(grid[0, 0])]
    if rot is not None:
        scatter_axes.append(fig.add_subplot(grid[1, 0], sharex=scatter_axes[0]))
    hist_ax = fig.add_subplot(grid[:, 1])
    index = np.arange(pos.shape[0])
    for ax, values, unit, what in zip(scatter_axes, (pos, rot), ("mm", "mrad"),
                                      ("position", "rotation"), strict=False):
        for c, axis in enumerate("xyz"):
            ax.plot(index, values[:, c], ".", ms=4, color=f"C{c}", label=axis)
        if out_rows.size:
            rows = np.repeat(out_rows, 3)
            ax.plot(rows, values[out_rows].ravel(), "o", mfc="none", mec="C3", ms=9, mew=1.4,
                    gid="outliers",
                    label=f"outlier (> {result.outlier_threshold:g} \u03c3)")
        for b, start in enumerate(offsets[:-1]):
            if len(offsets) > 2:
                ax.axvline(start - 0.5, color="0.5", ls=":", lw=1)
                ax.annotate(result.block_names[b], (start, 0.98), xycoords=("data", "axes fraction"),
                            va="top", fontsize=8, color="0.4")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_ylabel(f"{what} residual h \u2212 \u03b7 [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, ncols=4, loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False)
    scatter_axes[-1].set_xlabel("measurement index")
    scatter_axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    rms = "" if result.rms_mm is None else f"; position RMS {result.rms_mm:.4f} mm, max {result.max_mm:.4f} mm"
    if result.rms_mrad is not None:
        rms += f"; rotation RMS {result.rms_mrad:.4f} mrad, max {result.max_mrad:.4f} mrad"
    fig.suptitle(f"Identification residuals ({result.status.value}, {pos.shape[0]} measurements){rms}",
                 fontsize=11)

    r = np.asarray(result.residuals, dtype=float)
    m = r.size
    beyond = int(np.sum(np.abs(r) > HISTOGRAM_LIMIT))
    limit = min(HISTOGRAM_LIMIT, max(4.0, math.ceil(np.abs(r).max())))
    n_bins = int(np.clip(round(2.0 * np.sqrt(m)), 10, 60))
    edges = np.linspace(-limit, limit, n_bins + 1)
    hist_ax.hist(np.clip(r, -limit, limit), bins=edges, color="C0", alpha=0.7,
                 label=f"weighted residuals r ({m} values)")
    x = np.linspace(-limit, limit, 400)
    width = edges[1] - edges[0]
    hist_ax.plot(x, m * width * scipy.stats.norm.pdf(x), color="k", lw=1.5, gid="normal",
                 label="standard normal N(0, 1), expected counts")
    note = f"\u03c3\u0302\u2080 = {result.sigma0:.3f}, {len(result.outliers)} outlier(s)"
    if beyond:
        note += f"\n{beyond} value(s) beyond \u00b1{limit:g} \u03c3 counted in the edge bins"
    hist_ax.set_xlabel("normalised residual r = (h \u2212 \u03b7)/\u03c3 [\u03c3]")
    hist_ax.set_ylabel("count")
    hist_ax.set_title("Normalised residuals", fontsize=10)
    hist_ax.legend(fontsize=8, title=note, title_fontsize=8, loc="upper right")
    hist_ax.set_ylim(top=hist_ax.get_ylim()[1] * 1.4)
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


# ------------------------------------------------------------------ output
def save_figure(fig: Figure, path: str | os.PathLike, *, dpi: float = 150.0) -> Path:
    """Write ``fig`` to ``path`` as PNG, SVG or PDF (by suffix), atomically.

    The figure is rendered into a temporary file in the same folder, then
    renamed over ``path`` (as :func:`calib_oed.io.atomic.atomic_write_text`):
    a reader never sees a half-written file, and a failed render leaves
    neither the temporary file nor a changed ``path``. The figure stays open.

    Args:
        fig: The figure.
        path: Output file; its suffix (case-insensitive) is one of
            :data:`FIGURE_FORMATS`.
        dpi: Resolution of PNG output [dots per inch].

    Raises:
        ExportError: unknown suffix (the message lists the valid ones), the
            folder does not exist, or the file cannot be written.
    """
    path = Path(path)
    fmt = FIGURE_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ExportError(f"cannot write {path}: unknown figure format {path.suffix or '(no suffix)'!r}; "
                          f"valid suffixes are: {', '.join(map(repr, FIGURE_FORMATS))}")
    return atomic_write(path, lambda fh: fig.savefig(fh, format=fmt, dpi=dpi), binary=True)
