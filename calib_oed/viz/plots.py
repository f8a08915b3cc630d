r"""Figures of calibrations (matplotlib, no window), and writing any figure.

Every function returns a new :class:`matplotlib.figure.Figure`, built
without ``pyplot`` (no global figure registry, nothing to close, no display):
write it with :func:`save_figure`, which renders with Agg (PNG), or the SVG
and PDF backends. Lengths are plotted in mm; inputs are SI (m, m²) unless an
argument says otherwise.

- :func:`plot_kpi_ellipsoids`: the paper's
  Figure 7, the 95 % confidence region of the KPI (a tool point at every
  working configuration, in the world or tracker frame) of several designs,
  projected onto the xy, xz and yz planes. Drawn are the *marginal* ellipses
  :math:`\{y : y^\top C_{JJ}^{-1} y \le \chi^2_2(\mathrm{level})\}` of the two
  plotted coordinates :math:`J` (each holds them with probability
  ``level``; :meth:`calib_oed.calibration.confidence.ConfidenceEllipsoid.marginal`),
  centred at 0, the deviation from the estimate.
- :func:`plot_residuals`: residuals of an identification and their histogram
  against the standard normal density.

Figures of designs and studies: :mod:`calib_oed.viz.design_plots`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
import scipy.stats
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from calib_oed.calibration.confidence import ConfidenceEllipsoid
from calib_oed.calibration.identification_result import IdentificationResult
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.exceptions import ExportError, ShapeError
from calib_oed.io.atomic import atomic_write

#: Millimetres per metre, milliradians per radian.
MM_PER_M = 1e3
MRAD_PER_RAD = 1e3
#: File suffixes :func:`save_figure` writes, and the matplotlib format of each.
FIGURE_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}
#: Coordinate planes of :func:`plot_kpi_ellipsoids`: name and the two axes.
PLANES = (("xy", (0, 1)), ("xz", (0, 2)), ("yz", (1, 2)))
#: Most tick intervals per axis of an ellipse panel (at most TICK_BINS + 1 labels).
TICK_BINS = 4
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
class _Curve(NamedTuple):
    """One drawn ellipse: its ``gid``, legend label (None: not in the legend), colour, region."""

    gid: str
    label: str | None
    color: str
    ellipsoid: ConfidenceEllipsoid


def _sigma_mm(covariances: Sequence[np.ndarray]) -> float:
    r""":math:`\sigma = \sqrt{\sum_i \mathrm{tr}(C_i) / (3t)}` of t (3, 3) covariances [m²], in mm."""
    return math.sqrt(sum(np.trace(c) for c in covariances) / (3.0 * len(covariances))) * MM_PER_M


def _ellipse_figure(curves: Sequence[_Curve], level: float, title: str, legend_title: str) -> Figure:
    """Three panels (:data:`PLANES`), one line per curve and panel, a legend below them."""
    fig = Figure(figsize=(12.5, 4.8), layout="constrained")
    axes = fig.subplots(1, 3)
    for ax, (plane, dims) in zip(axes, PLANES, strict=True):
        for c in curves:
            xy = c.ellipsoid.projection(dims, kind="marginal").boundary(361) * MM_PER_M
            ax.plot(xy[:, 0], xy[:, 1], color=c.color, lw=1.6 if c.label else 1.0, gid=c.gid,
                    label=c.label if c.label else "_nolegend_")
        ax.plot([0.0], [0.0], "+", color="0.3", ms=8)
        ax.set_aspect("equal", adjustable="datalim")
        # at most 5 labelled ticks per axis: a panel is ~4 inches wide, and matplotlib's
        # automatic count (by font size only) lets labels like "-0.075" overlap
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(MaxNLocator(nbins=TICK_BINS, steps=[1, 2, 2.5, 5, 10]))
        ax.set_xlabel(f"\u0394{plane[0]} [mm]")
        ax.set_ylabel(f"\u0394{plane[1]} [mm]")
        ax.set_title(f"{plane} plane: marginal {level:.0%} region")
        ax.grid(True, alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 4), title=legend_title)
    fig.suptitle(title)
    return fig


def kpi_description(kpi, reflector_names: Sequence[str] | None = None) -> str:
    """What a KPI is and in which frame, in words: ``"TCP position, world frame"``,
    ``"centre of reflector 'smr0', tracker frame"``, ``"tool point (0, 0, 120) mm, world frame"``.

    Args:
        kpi: A :class:`~calib_oed.calibration.kpi.TcpKpi`.
        reflector_names: Names of the scene's reflectors (else they are numbered).
    """
    if kpi.reflector is not None:
        j = kpi.reflector
        named = reflector_names is not None and j < len(reflector_names)
        what = f"centre of reflector {reflector_names[j]!r}" if named else f"centre of reflector {j}"
    elif not np.any(kpi.point):
        what = "TCP position"
    else:
        what = "tool point ({}) mm".format(", ".join(f"{MM_PER_M * v:g}" for v in kpi.point))
    return f"{what}, {kpi.frame} frame"


def plot_kpi_ellipsoids(
    problem,
    designs: Mapping[str, np.ndarray],
    *,
    level: float = 0.95,
) -> Figure:
    r"""The paper's Figure 7: KPI confidence regions of several designs, in mm.

    For each design :math:`q` and KPI point :math:`i` (working configuration),
    the 3×3 block :math:`C_i` of :math:`C_s(q)` (``problem.kpi_covariance``,
    [m²], in the KPI's frame: world or tracker) is drawn as marginal ellipses
    in the xy, xz and yz planes, one line per point, in the design's colour. The legend gives per design
    :math:`\sigma = \sqrt{\sum_i \mathrm{tr}(C_i)/(3t)}` [mm] over its t drawn
    points; the title names the KPI point, its frame and the working configurations.

    Args:
        problem: A :class:`~calib_oed.calibration.problem.CalibrationProblem`, or a
            :class:`~calib_oed.calibration.workflow.Setup` (then reflectors are named).
        designs: Name (``"heuristic"``, ``"KPI-optimal"``, ...) to
            configurations (n, nq) [rad], or to a record with a ``q``
            attribute (:class:`~calib_oed.oed.result.Design`).
        level: Confidence level in (0, 1).

    Returns:
        A figure with three axes, ``fig.axes`` in the order of :data:`PLANES`; the
        line of design ``d`` at point ``w`` has ``gid`` ``d`` with one KPI point, else
        ``"d @ w"``.
    """
    scene = getattr(problem, "scene", None)
    reflector_names = [r.name for r in scene.reflectors] if scene is not None else None
    problem = _problem(problem)
    names = problem.kpi.names
    points = list(range(len(names)))
    if not designs:
        raise ValueError("designs: give at least one name -> configurations (n, nq) [rad]")
    curves = []
    for (design, q), color in zip(designs.items(), _colors(len(designs)), strict=True):
        c_s = problem.kpi_covariance(np.asarray(getattr(q, "q", q), dtype=float))
        blocks = [c_s[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in points]
        over = f" (RMS over {len(points)} points)" if len(points) > 1 else ""
        for k, (i, cov) in enumerate(zip(points, blocks, strict=True)):
            gid = str(design) if len(points) == 1 else f"{design} @ {names[i]}"
            label = f"{design}: \u03c3 = {_sigma_mm(blocks):#.3g} mm{over}" if k == 0 else None
            curves.append(_Curve(gid, label, color, ConfidenceEllipsoid(np.zeros(3), cov, level, gid)))
    shown = [names[i] for i in points]
    where = ", ".join(shown[:3]) + (f", \u2026 ({len(shown)} points)" if len(shown) > 3 else "")
    return _ellipse_figure(
        curves, level,
        f"KPI: {kpi_description(problem.kpi, reflector_names)}, at {where}\n{level:.0%} confidence "
        "regions, deviation from the estimate (marginal ellipses, \u03c7\u00b2\u2082)",
        "design: KPI \u03c3 = \u221a(mean tr C\u1d62/3)" if len(points) > 1 else "design: KPI \u03c3 = \u221a(tr C/3)")


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


def plot_residuals(result: IdentificationResult, flagged=None, flag_rule: str | None = None,
                   block_names=None) -> Figure:
    r"""Residuals of an identification: per measurement and as a histogram.

    Left: the raw residual components :math:`h - \eta` of every measurement,
    position x, y, z [mm] (and, for pose data, rotation [mrad] below), against
    the measurement index (blocks one after the other, separated by dotted
    lines, labelled ``block_names``: the scene's reflector names); the flagged
    measurements are circled in red: ``flagged`` ((block, row) pairs, the rule
    of the report, described by ``flag_rule``), or without it the plain fit's
    ``result.outliers``. Right: the
    histogram of the weighted residuals :math:`r` (``result.residuals``,
    [σ]) with the expected counts of the standard normal density; values
    beyond ±:data:`HISTOGRAM_LIMIT` σ are counted in the edge bins, so the
    counts sum to ``result.residuals.size``.

    Returns:
        A figure; ``fig.axes``: position residuals, (rotation residuals),
        histogram (last). Outlier markers have ``gid`` ``"outliers"``.
    """
    pos, rot, offsets = _residual_components(result)
    if flagged is None:
        flagged = [(o.block, o.row) for o in result.outliers]
        flag_rule = f"> {result.outlier_threshold:g} \u03c3"
    out_rows = np.array([offsets[b] + r for b, r in flagged], dtype=int)
    names = result.block_names if block_names is None else tuple(block_names)
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
                    label=f"flagged ({flag_rule}): {out_rows.size}")
        for b, start in enumerate(offsets[:-1]):
            if len(offsets) > 2:
                ax.axvline(start - 0.5, color="0.5", ls=":", lw=1)
                ax.annotate(names[b], (start, 0.98), xycoords=("data", "axes fraction"),
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
    note = f"\u03c3\u0302\u2080 = {result.sigma0:.3f}, {out_rows.size} flagged"
    if beyond:
        note += f"\n{beyond} value(s) beyond \u00b1{limit:g} \u03c3 counted in the edge bins"
    hist_ax.set_xlabel("normalised residual r = (h \u2212 \u03b7)/\u03c3 [\u03c3]")
    hist_ax.set_ylabel("count")
    hist_ax.set_title("Normalised residuals", fontsize=10)
    hist_ax.legend(fontsize=8, title=note, title_fontsize=8, loc="upper right")
    hist_ax.set_ylim(top=hist_ax.get_ylim()[1] * 1.4)
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
