r"""The paper's tables and figures from a study's results (:mod:`calib_oed.study.results`).

All values are the KPI average variance :math:`V = \mathrm{tr}(C_s)/(3t)` [mm²]
of a design; the heuristic baseline of a case is the median of
:math:`V` over its heuristic seeds. Improvements are

.. math::
    I = 100\,\bigl(1 - V_{\text{KPI-opt}} / V_{\text{other}}\bigr)\ [\%],

positive when the KPI-optimal design (A-criterion on :math:`C_s`) is better
than the other design (the heuristic median, or the C_p-optimal design: the
A-criterion on the scaled parameter covariance, the state of the art).

- :func:`case_table`: per case (the paper's Table 6 for the KUKA robots);
- :func:`minmax_table`: minimum and maximum over the cases (Table 7);
- :func:`means_table`: means over the cases, with and without collision
  avoidance (Table 8);
- :func:`colliding_table`: the fraction of colliding poses of designs
  optimised without collision constraints (the paper: 50–70 %);
- :func:`write_report`: ``report.md`` with all of them, the command, the
  machine and the wall time, and the figures: Figure 7 (KPI confidence
  ellipses of the heuristic, C_p-optimal and KPI-optimal designs of the
  ``kr16`` case, or of the first case) and Figure 8 (distribution of the
  improvements over the cases), via :mod:`calib_oed.viz.plots`
  and :mod:`calib_oed.viz.design_plots`.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from pathlib import Path

import numpy as np

from calib_oed.io.atomic import atomic_write_text
from calib_oed.study.results import (
    IMPROVEMENT_CONVENTION,
    CaseResult,
    StudyResult,
    design_label,
    improvement_pct,
)
from calib_oed.study.runner import read_study

__all__ = ["case_table", "colliding_table", "figure7_case", "means_table", "minmax_table",
           "study_tables", "write_report"]

#: Paper's numbers, for the comparison section (Jost et al. 2017, abstract and §3.4).
PAPER_CLAIMS = {
    "vs_heuristic": "40–44 %",
    "vs_params": "10–19 %",
    "colliding": "50–70 %",
}
#: Columns of :func:`case_table` and :func:`minmax_table` that are variances [mm²].
VARIANCE_COLUMNS = ("heuristic", "params", "kpi")
IMPROVEMENT_COLUMNS = ("vs_heuristic", "vs_params")
FIGURE7 = "figure7_kpi_ellipsoids.png"
FIGURE8 = "figure8_improvement.png"


def _value(case: CaseResult, criterion: str, collisions: bool) -> float:
    """V of the optimised design, NaN if the plan has no such design."""
    try:
        return case.row("optimal", criterion, collisions).kpi_avg_variance_mm2
    except KeyError:
        return math.nan


def case_table(result: StudyResult, collisions: bool = True) -> list[dict]:
    """Per case: ``heuristic``, ``params``, ``kpi`` [mm²] and ``vs_heuristic``, ``vs_params`` [%].

    Also ``case_id``, ``robot``, ``lambda_mm``, ``mu_mm``; with a certificate in
    the plan, ``bound`` (the certified lower bound on V for n feasible poses
    [mm²]) and ``efficiency``, ``params_efficiency``, ``heuristic_efficiency``
    (bound / V of the KPI-optimal, the C_p-optimal and the median heuristic
    design [1]).
    Missing designs and values are NaN.
    """
    rows = []
    for case in result.cases:
        heuristic = case.row("heuristic_median").kpi_avg_variance_mm2
        params, kpi = _value(case, "params", collisions), _value(case, "kpi", collisions)
        spec = case.case.spec
        efficiency = _efficiency(case, "kpi", collisions)
        rows.append({"case_id": case.case_id, "robot": spec.robot, "lambda_mm": spec.lambda_mm,
                     "mu_mm": spec.mu_mm, "heuristic": heuristic, "params": params, "kpi": kpi,
                     "vs_heuristic": improvement_pct(kpi, heuristic),
                     "vs_params": improvement_pct(kpi, params),
                     "bound": case.row("heuristic_median").kpi_bound_mm2, "efficiency": efficiency,
                     "params_efficiency": _efficiency(case, "params", collisions),
                     "heuristic_efficiency": case.row("heuristic_median").kpi_efficiency})
    return rows


def _efficiency(case: CaseResult, criterion: str, collisions: bool) -> float:
    """bound / V of the optimised design [1], NaN without a certificate or such a design."""
    try:
        return case.row("optimal", criterion, collisions).kpi_efficiency
    except KeyError:
        return math.nan


def minmax_table(result: StudyResult, collisions: bool = True) -> dict[str, dict[str, float]]:
    """``{"min": {...}, "max": {...}}`` over the cases of each column of :func:`case_table`."""
    rows = case_table(result, collisions)
    cols = (*VARIANCE_COLUMNS, *IMPROVEMENT_COLUMNS)
    return {stat: {c: float(fun([r[c] for r in rows])) if rows else math.nan for c in cols}
            for stat, fun in (("min", np.min), ("max", np.max))}


def means_table(result: StudyResult) -> dict[bool, dict[str, float]]:
    """Means over the cases of each column of :func:`case_table`, per collisions flag.

    The heuristic designs satisfy every constraint, so their mean is the same
    in both columns; the improvements are the means of the per-case improvements.
    """
    flags = result.config.plan.collisions
    return {flag: {c: float(np.mean([r[c] for r in case_table(result, flag)]))
                   if result.cases else math.nan
                   for c in (*VARIANCE_COLUMNS, *IMPROVEMENT_COLUMNS)} for flag in flags}


def colliding_table(result: StudyResult) -> dict[tuple[str, bool], dict[str, float]]:
    """Fraction of colliding poses [1] per (criterion, collisions): ``mean``, ``min``, ``max``."""
    plan = result.config.plan
    out = {}
    for flag in plan.collisions:
        for crit in plan.criteria:
            f = [c.row("optimal", crit, flag).colliding_fraction for c in result.cases]
            out[(crit, flag)] = ({"mean": float(np.mean(f)), "min": float(np.min(f)),
                                  "max": float(np.max(f))} if f else
                                 dict.fromkeys(("mean", "min", "max"), math.nan))
    return out


def study_tables(result: StudyResult) -> dict:
    """All tables as plain data (what ``report.md`` shows)."""
    flags = result.config.plan.collisions
    return {"cases": {flag: case_table(result, flag) for flag in flags},
            "minmax": {flag: minmax_table(result, flag) for flag in flags},
            "means": means_table(result), "colliding": colliding_table(result)}


# ---------------------------------------------------------------- formatting

def _v(x) -> str:
    """A variance [mm²]."""
    return "—" if x is None or not math.isfinite(x) else f"{x:.4g}"


def _p(x) -> str:
    """A percentage."""
    return "—" if x is None or not math.isfinite(x) else f"{x:.1f} %"


def _md(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _case_md(rows: list[dict]) -> str:
    notional = any(r["lambda_mm"] is not None for r in rows)
    header = ["arm", "λ [mm]", "μ [mm]"] if notional else ["robot", "case"]
    header += ["heuristic (median) [mm²]", "C_p-optimal [mm²]", "KPI-optimal [mm²]",
               "KPI-opt vs heuristic", "KPI-opt vs C_p-opt"]
    certified = any(math.isfinite(r.get("bound", math.nan)) for r in rows)
    if certified:
        header += ["lower bound [mm²]", "heuristic efficiency", "C_p-opt efficiency",
                   "KPI-opt efficiency"]
    body = []
    for r in rows:
        first = ([r["robot"], str(r["lambda_mm"] or "—"), str(r["mu_mm"] or "—")] if notional
                 else [r["robot"], r["case_id"]])
        cells = first + [_v(r["heuristic"]), _v(r["params"]), _v(r["kpi"]),
                         _p(r["vs_heuristic"]), _p(r["vs_params"])]
        if certified:
            cells += [_v(r["bound"]), *(_p(100.0 * r[k]) for k in
                                        ("heuristic_efficiency", "params_efficiency", "efficiency"))]
        body.append(cells)
    return _md(header, body)


def _minmax_md(table: dict) -> str:
    return _md(["over the cases", "heuristic (median) [mm²]", "C_p-optimal [mm²]",
                "KPI-optimal [mm²]", "KPI-opt vs heuristic", "KPI-opt vs C_p-opt"],
               [[stat, *(_v(t[c]) for c in VARIANCE_COLUMNS),
                 *(_p(t[c]) for c in IMPROVEMENT_COLUMNS)] for stat, t in table.items()])


def _means_md(table: dict[bool, dict]) -> str:
    flags = list(table)
    header = ["mean over the cases"] + [("with" if f else "without") + " collision avoidance"
                                        for f in flags]
    names = {"heuristic": "heuristic (median) [mm²]", "params": "C_p-optimal [mm²]",
             "kpi": "KPI-optimal [mm²]", "vs_heuristic": "KPI-opt vs heuristic (mean of cases)",
             "vs_params": "KPI-opt vs C_p-opt (mean of cases)"}
    rows = [[label, *((_v if key in VARIANCE_COLUMNS else _p)(table[f][key]) for f in flags)]
            for key, label in names.items()]
    return _md(header, rows)


def _colliding_md(table: dict) -> str:
    rows = [[{"params": "C_p-optimal", "kpi": "KPI-optimal"}.get(crit, crit),
             "with" if flag else "without", *(_p(100.0 * t[s]) for s in ("mean", "min", "max"))]
            for (crit, flag), t in table.items()]
    return _md(["design", "collision constraints", "colliding poses: mean", "min", "max"], rows)


def _solver_md(result: StudyResult) -> str:
    plan = result.config.plan
    rows = []
    for flag in plan.collisions:
        for crit in plan.criteria:
            rs = [c.row("optimal", crit, flag) for c in result.cases]
            if not rs:
                continue
            status = Counter(r.status for r in rs)
            rows.append([crit, "with" if flag else "without",
                         ", ".join(f"{k} {v}" for k, v in status.most_common()),
                         f"{np.median([r.iterations for r in rs]):.0f}",
                         f"{np.median([r.seconds for r in rs]):.1f}",
                         f"{max(r.seconds for r in rs):.1f}",
                         str(sum(r.feasible for r in rs))])
    return _md(["criterion", "collision constraints", "SQP status (cases)", "median iterations",
                "median time [s]", "max time [s]", "feasible designs"], rows)


def sigma_improvement_pct(variance_improvement_pct):
    """The improvement in the standard deviation, :math:`100(1-\\sqrt{V_1/V_0})`, from the
    improvement in the variance :math:`100(1 - V_1/V_0)` [%]. The paper's tables are
    variances, its headline percentages do not say which of the two they are."""
    return 100.0 * (1.0 - np.sqrt(1.0 - np.asarray(variance_improvement_pct, dtype=float) / 100.0))


def _claims_md(result: StudyResult, tables: dict) -> str:
    lines = []
    flags = result.config.plan.collisions
    if True in flags and result.cases:
        rows = tables["cases"][True]
        for key, what in (("vs_heuristic", "over the heuristic median"),
                          ("vs_params", "over the C_p-optimal design")):
            v = np.array([r[key] for r in rows if math.isfinite(r[key])])
            if v.size:
                s = sigma_improvement_pct(v)
                lines.append(f"- KPI-optimal {what} (with collision avoidance): paper "
                             f"{PAPER_CLAIMS[key]}; here {v.min():.1f} to {v.max():.1f} % "
                             f"(mean {v.mean():.1f} %, {v.size} cases) in the average variance; "
                             f"in the standard deviation sqrt(V), {s.min():.1f} to {s.max():.1f} % "
                             f"(mean {s.mean():.1f} %).")
    if False in flags and result.cases:
        for crit in result.config.plan.criteria:
            t = tables["colliding"][(crit, False)]
            name = {"params": "C_p-optimal", "kpi": "KPI-optimal"}.get(crit, f"{crit}-optimal")
            lines.append(f"- Colliding poses of the {name} designs without collision "
                         f"constraints: paper {PAPER_CLAIMS['colliding']}; here "
                         f"{100 * t['min']:.0f} to {100 * t['max']:.0f} % "
                         f"(mean {100 * t['mean']:.0f} %).")
    return "\n".join(lines)


def _provenance_md(result: StudyResult) -> str:
    """The command, machine, wall time, plan and conventions, as a bullet list."""
    config, plan, m = result.config, result.config.plan, result.machine
    limit = "none" if plan.time_limit is None else f"{plan.time_limit:g} s"
    jobs = result.n_jobs if result.n_jobs is not None else "all cores"
    dask = f", Dask scheduler {result.scheduler}" if result.scheduler else ""
    return "\n".join([
        f"- Command: `{result.command}`; this report: "
        f"`calib_oed.study.report.write_report(<output folder>)`.",
        f"- Machine: {m.get('platform', '?')}, {m.get('processor', '?')}, "
        f"{m.get('cpu_count', '?')} logical CPUs, Python {m.get('python', '?')}; "
        f"jobs {jobs}{dask}.",
        f"- Sum of the case times {sum(c.seconds for c in result.cases):.0f} s over "
        f"{len(result.cases)} of {len(config.specs)} cases. Runs on this folder (wall time; "
        "1-minute load average before and after, 2 = both cores busy):",
        *(_run_md(r) for r in (result.runs or ({"command": result.command, "wall_seconds":
                                                  result.wall_seconds,
                                                  "computed": len(result.computed),
                                                  "loaded": len(result.loaded)},))),
        f"- Plan per case: {plan.n} poses; heuristic designs of seeds "
        f"{', '.join(map(str, plan.heuristic_seeds))} (their median is the baseline); "
        f"optimised for {', '.join(plan.criteria)} with collision constraints "
        f"{' and '.join('on' if f else 'off' for f in plan.collisions)}, from the "
        f"{plan.start} start of seed {plan.seed}; SQP at most {plan.max_iterations} "
        f"iterations, time limit {limit} per design.",
        "- Metric: KPI average variance V = tr(C_s)/(3t) [mm²]; improvement "
        f"= {IMPROVEMENT_CONVENTION.split(',')[0]} [%], positive when the KPI-optimal design "
        "is better. C_p-optimal = A-criterion on the scaled parameter covariance (the state "
        "of the art), KPI-optimal = A-criterion on C_s. Heuristic designs satisfy every "
        "constraint, so their value is the same with and without collision avoidance.",
    ])


def _run_md(run: dict) -> str:
    load = run.get("load_average_1min") or {}
    load_text = (f"; load {load['before']:.1f} / {load['after']:.1f}" if load else "")
    return (f"  - {run.get('started', '?')}: `{run.get('command', '')}`, "
            f"{run.get('wall_seconds', 0.0):.0f} s, {run.get('computed', 0)} cases computed, "
            f"{run.get('loaded', 0)} loaded{load_text}")


def figure7_case(result: StudyResult) -> CaseResult | None:
    """The case of Figure 7: the ``kr16`` case if there is one, else the first."""
    for case in result.cases:
        if case.case.spec.robot == "kr16":
            return case
    return result.cases[0] if result.cases else None


def export_designs(case: CaseResult, folder: str | os.PathLike) -> dict[str, Path]:
    """The case's stored designs as design CSVs, ``folder/<label>.csv`` (joint names, rad).

    They feed the other commands, e.g. the Monte Carlo check of docs/study.md:
    ``calib-oed montecarlo fms_kr16 DIR/designs/<case>/kpi-collisions.csv -N 1000``.
    """
    from calib_oed.io.design_file import write_design_csv

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    robot = case.case.spec.load_scene().robot
    return {label: write_design_csv(folder / f"{label}.csv", robot, d.q,
                                    comment=f"study case {case.case_id}: {label} design")
            for label, d in case.designs.items()}


def _figures(result: StudyResult, folder: Path, tables: dict) -> dict[str, Path]:
    """Figure 7 and Figure 8 (needs calib_oed.viz.plots, calib_oed.viz.design_plots and matplotlib)."""
    from calib_oed.calibration.workflow import setup
    from calib_oed.viz.design_plots import plot_improvement_distribution
    from calib_oed.viz.plots import plot_kpi_ellipsoids, save_figure

    paths = {}
    case = figure7_case(result)
    plan = result.config.plan
    if case is not None:
        flag = True if True in plan.collisions else plan.collisions[0]
        names = {"params": "C_p-optimal", "kpi": "KPI-optimal"}
        seed = case.designs["heuristic_median"].seed
        designs = {f"heuristic (median, seed {seed})": case.designs["heuristic_median"].q}
        designs |= {names.get(c, c): case.designs[design_label(c, flag)].q for c in plan.criteria}
        fig = plot_kpi_ellipsoids(setup(case.case.spec.load_scene()), designs)
        fig.suptitle(f"{case.case.spec.robot} ({case.case.spec.scene_label}): "
                     + fig.get_suptitle(), fontsize=9)
        paths["figure7"] = save_figure(fig, folder / FIGURE7)
    if True in plan.collisions and result.cases:
        rows = tables["cases"][True]
        data = {label: [r[key] for r in rows if math.isfinite(r[key])]
                for key, label in (("vs_heuristic", "vs heuristic (median)"),
                                   ("vs_params", "vs C_p-optimal"))}
        data = {k: v for k, v in data.items() if v}
        if data:
            fig = plot_improvement_distribution(
                data, xlabel="improvement of the KPI-optimal design, "
                             "100 (1 - V_KPI-opt / V_other) [%]")
            paths["figure8"] = save_figure(fig, folder / FIGURE8)
    return paths


def write_report(
    result: StudyResult | str | os.PathLike,
    folder: str | os.PathLike | None = None,
    *,
    figures: bool = True,
) -> dict[str, Path]:
    """Write ``report.md`` (all tables) and the figures into ``folder``.

    Args:
        result: A study result, or its output folder (read with :func:`calib_oed.study.runner.read_study`).
        folder: Where to write (created); default the study's output folder.
        figures: Also draw Figure 7 and Figure 8 (needs :mod:`calib_oed.viz.plots` and
            :mod:`calib_oed.viz.design_plots`).

    Returns:
        ``{"report": path, "figure7": path, "figure8": path}`` (figures only if drawn).
    """
    if not isinstance(result, StudyResult):
        result = read_study(result)
    folder = Path(folder) if folder is not None else result.out_dir
    folder.mkdir(parents=True, exist_ok=True)
    tables = study_tables(result)
    paths = _figures(result, folder, tables) if figures else {}
    config, plan, n = result.config, result.config.plan, len(result.cases)
    parts = [f"# Study `{config.name}`", config.description, "## How this was made",
             _provenance_md(result)]
    if result.failures:
        parts += ["## Failed cases", "\n".join(f"- `{f.case_id}`: {f.error}"
                                               for f in result.failures)]
    if stopped := result.clock_stopped():
        parts += ["## Designs stopped by the wall clock (load-dependent)", (
            f"The SQP's time limit stopped {len(stopped)} designs: their values depend on the "
            "machine's load; rerun with `sqp: {time_limit: null}` for results that do not. "
            + ", ".join(f"`{r.case_id}` {design_label(r.criterion, r.collisions)}"
                        for r in stopped) + ".")]
    parts += ["## The paper's claims and ours", _claims_md(result, tables) or "(no cases)"]
    if plan.certificate is not None:
        cp = plan.certificate
        parts += ["## Optimality certificate", (
            f"Per case, a lower bound on V for any design of {plan.n} feasible poses: the "
            f"approximate (continuous-weight) KPI-optimal design on {cp.pool} random feasible "
            f"poses (seed {cp.seed}) plus the poses of every feasible design of the case, solved "
            "to a certified duality gap (equivalence theorem), with "
            + (f"{cp.local_starts} local maximisations of the sensitivity off the pool"
               if cp.local_starts else "no search off the pool")
            + " (`docs/oed.md`). The bound is checked to lie below every feasible design of the "
            "case; *efficiency* = bound / V: how close a design is to the best any design of "
            "as many poses could possibly be.")]
    many = n > 12
    if not many:
        for flag in plan.collisions:
            parts += [f"## Table 6: KPI average variance per case, "
                      f"{'with' if flag else 'without'} collision avoidance",
                      _case_md(tables["cases"][flag])]
    for flag in plan.collisions:
        parts += [f"## Table 7: minimum and maximum over the {n} cases, "
                  f"{'with' if flag else 'without'} collision avoidance",
                  _minmax_md(tables["minmax"][flag])]
    parts += [f"## Table 8: means over the {n} cases, with and without collision avoidance",
              _means_md(tables["means"]),
              "## Colliding poses (self, obstacle or beam rows violated)",
              _colliding_md(tables["colliding"]),
              "## Solver", _solver_md(result)]
    case = figure7_case(result)
    if case is not None:
        exported = export_designs(case, folder / "designs" / case.case_id)
        paths["designs"] = exported[next(iter(exported))].parent
        spec = case.case.spec
        example = ("" if spec.template is not None else
                   f" (for example `calib-oed montecarlo {spec.scene} "
                   f"designs/{case.case_id}/kpi-collisions.csv -N 1000`)")
        parts += [f"## Designs of case `{case.case_id}`",
                  f"As design CSVs in `designs/{case.case_id}/`: "
                  + ", ".join(f"`{p.name}`" for p in exported.values()) + example + "."]
    if paths.get("figure7"):
        parts += [f"## Figure 7: KPI confidence regions ({case.case.spec.robot})",
                  f"![Figure 7]({paths['figure7'].name})"]
    if paths.get("figure8"):
        parts += ["## Figure 8: improvement of the KPI-optimal design over the cases",
                  f"![Figure 8]({paths['figure8'].name})"]
    if many:
        for flag in plan.collisions:
            parts += [f"## All cases, {'with' if flag else 'without'} collision avoidance",
                      _case_md(tables["cases"][flag])]
    paths["report"] = atomic_write_text(folder / "report.md", "\n\n".join(p for p in parts if p)
                                        + "\n")
    return paths
