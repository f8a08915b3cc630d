r"""What a study produced: its result records and their file forms.

One :class:`DesignRow` per design of a case (a row of ``results.csv``,
:func:`rows_csv`), the designs kept for figures (:class:`StoredDesign`), a
case's result (:class:`CaseResult`, the content of ``OUT/cases/<case_id>.json``)
or its failure (:class:`CaseFailure`), and the whole study
(:class:`StudyResult`, whose :meth:`~StudyResult.summary` is ``summary.json``).
Improvements are :math:`100\,(1 - V_{\text{KPI-opt}}/V_{\text{other}})` [%]
(:func:`improvement_pct`), :math:`V` the KPI average variance [mm²].
:mod:`calib_oed.study.case` computes a case, :mod:`calib_oed.study.runner`
runs and stores them.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib_oed.solver.result import SQPStatus
from calib_oed.study.config import StudyCase, StudyConfig
from calib_oed.values import plain

__all__ = ["CaseFailure", "CaseResult", "DesignRow", "StoredDesign", "StudyResult",
           "improvement_pct"]

#: Design kinds of the table.
KINDS = ("heuristic", "heuristic_median", "optimal")
CASE_FILE_FORMAT = "calib_oed study case result v1"
SUMMARY_FORMAT = "calib_oed study summary v1"
IMPROVEMENT_CONVENTION = "100 * (1 - V_kpi_optimal / V_other), V = KPI average variance [mm^2]"


def improvement_pct(v_kpi: float, v_other: float) -> float:
    r"""Improvement of the KPI-optimal design over another, :math:`100\,(1 - V_{kpi}/V_{other})` [%]."""
    return 100.0 * (1.0 - float(v_kpi) / float(v_other))


@dataclass(frozen=True)
class DesignRow:
    """One row of ``results.csv``: one design of one case.

    Attributes:
        case_id, robot, scene: The case.
        lambda_mm, mu_mm: Upper-arm and forearm lengths of a notional arm [mm], else None.
        kind: ``heuristic`` (one seed), ``heuristic_median`` (the median over the
            seeds, value by value) or ``optimal`` (SQP).
        criterion: The criterion optimised (``""`` for heuristic rows).
        collisions: Whether collision constraints were imposed (heuristic designs
            satisfy all constraints: True).
        seed: Heuristic seed, or the seed of the start design.
        n: Poses.
        kpi_avg_variance_mm2: :math:`\\mathrm{tr}(C_s)/(3t)` [mm²], the tables' metric.
        kpi_sigma_mm: Largest per-working-configuration σ, :math:`\\sqrt{\\mathrm{tr}\\,C_{s,i}/3}` [mm].
        params_avg_variance: :math:`\\mathrm{tr}(C_p)/n_f` [mm², mrad² mixed].
        criterion_value, criterion_start_value: The optimised criterion at the
            design and at its start (its unit); heuristic rows: the KPI value.
        feasible: Every constraint of the full feasibility model holds.
        colliding_fraction: Fraction of poses with a collision row violated [1].
        iterations, status: SQP record (0 and ``""`` for heuristic rows).
        seconds: Wall time of the design [s].
        kpi_bound_mm2: The case's certified lower bound on :math:`V` for n
            feasible poses [mm²] (NaN without a certificate).
        kpi_efficiency: ``kpi_bound_mm2 / kpi_avg_variance_mm2`` [1] of a
            feasible design (NaN without a certificate or for an infeasible design).
        distinct_poses: Distinct joint vectors of the design (the median over the
            seeds for ``heuristic_median``; NaN in results stored before it was recorded).
        distinct_positions: Distinct arm positions, reflectors more than 1 mm apart
            (:mod:`calib_oed.oed.positions`; median and NaN as ``distinct_poses``).
    """

    case_id: str
    robot: str
    scene: str
    lambda_mm: int | None
    mu_mm: int | None
    kind: str
    criterion: str
    collisions: bool
    seed: int | None
    n: int
    kpi_avg_variance_mm2: float
    kpi_sigma_mm: float
    params_avg_variance: float
    criterion_value: float
    criterion_start_value: float
    feasible: bool
    colliding_fraction: float
    iterations: int
    status: str
    seconds: float
    kpi_bound_mm2: float = math.nan
    kpi_efficiency: float = math.nan
    distinct_poses: float = math.nan
    distinct_positions: float = math.nan

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def columns() -> list[str]:
        return [f.name for f in dataclasses.fields(DesignRow)]


@dataclass(frozen=True, eq=False)
class StoredDesign:
    """A design kept in the case file, for figures and re-evaluation.

    Attributes:
        label: ``heuristic_median`` or ``<criterion>-collisions`` / ``<criterion>-no_collisions``.
        joint_names: Columns of ``q``.
        q: Configurations (n, nq) [rad].
        seed: Heuristic seed or start seed.
        solver: The SQP record (:meth:`calib_oed.solver.sqp.SQPResult.to_dict`, without x), or {}.
    """

    label: str
    joint_names: tuple[str, ...]
    q: np.ndarray
    seed: int | None
    solver: dict

    def to_dict(self) -> dict:
        return {"label": self.label, "joint_names": list(self.joint_names),
                "configurations_rad": self.q.tolist(), "seed": self.seed,
                "solver": plain(self.solver)}

    @classmethod
    def from_dict(cls, data: dict) -> StoredDesign:
        return cls(data["label"], tuple(data["joint_names"]),
                   np.array(data["configurations_rad"], dtype=float), data["seed"],
                   data.get("solver") or {})


def design_label(criterion: str, collisions: bool) -> str:
    """Key of an optimised design in :attr:`CaseResult.designs`."""
    return f"{criterion}-{'collisions' if collisions else 'no_collisions'}"


@dataclass(frozen=True, eq=False)
class CaseResult:
    """Everything one case produced.

    Attributes:
        case: The case and its plan.
        rows: Table rows: every heuristic seed, the heuristic median, every optimised design.
        designs: Stored designs by label (the median-rank heuristic design, every optimised one).
        seconds: Wall time of the case [s].
        certificate: :meth:`calib_oed.oed.certificate.Certificate.to_dict` of the
            KPI-optimal design, or None (no certificate in the plan).
    """

    case: StudyCase
    rows: tuple[DesignRow, ...]
    designs: dict[str, StoredDesign]
    seconds: float
    certificate: dict | None = None

    @property
    def case_id(self) -> str:
        return self.case.case_id

    def row(self, kind: str, criterion: str = "", collisions: bool = True) -> DesignRow:
        """The row of a design: ``row("heuristic_median")``, ``row("optimal", "kpi", False)``."""
        for r in self.rows:
            if r.kind == kind and r.criterion == criterion and r.collisions == collisions:
                return r
        have = sorted({(r.kind, r.criterion, r.collisions) for r in self.rows if
                       r.kind != "heuristic"})
        raise KeyError(f"case {self.case_id}: no design ({kind!r}, {criterion!r}, "
                       f"collisions={collisions}); it has {have}")

    def check(self) -> CaseResult:
        """Consistency of the rows with the plan; raises ValueError."""
        plan = self.case.plan
        heur = [r for r in self.rows if r.kind == "heuristic"]
        if sorted(r.seed for r in heur) != sorted(plan.heuristic_seeds):
            raise ValueError(f"case {self.case_id}: heuristic seeds {[r.seed for r in heur]} "
                             f"are not the plan's {list(plan.heuristic_seeds)}")
        median = float(np.median([r.kpi_avg_variance_mm2 for r in heur]))
        if not math.isclose(self.row("heuristic_median").kpi_avg_variance_mm2, median,
                            rel_tol=1e-12):
            raise ValueError(f"case {self.case_id}: the heuristic median is not the median")
        for coll in plan.collisions:
            for crit in plan.criteria:
                self.row("optimal", crit, coll)
        if plan.certificate is not None:
            if self.certificate is None:
                raise ValueError(f"case {self.case_id}: the plan asks for a certificate; it has none")
            bound = self.certificate["bound"]
            above = [r for r in self.rows if r.feasible and
                     not r.kpi_avg_variance_mm2 >= bound * (1.0 - 1e-9)]
            if above:
                raise ValueError(f"case {self.case_id}: the certified bound {bound:.6g} mm² is above "
                                 f"the feasible design {above[0].kind} {above[0].criterion} "
                                 f"({above[0].kpi_avg_variance_mm2:.6g} mm²)")
        return self

    def to_dict(self) -> dict:
        return plain({"format": CASE_FILE_FORMAT, "case_id": self.case_id,
                       "config_hash": self.case.config_hash, "identity": self.case.identity(),
                       "spec": self.case.spec.to_dict(), "seconds": self.seconds,
                       "rows": [r.to_dict() for r in self.rows],
                       "designs": {k: d.to_dict() for k, d in self.designs.items()},
                       "certificate": self.certificate})

    @classmethod
    def from_dict(cls, data: dict, case: StudyCase) -> CaseResult:
        """Rebuild a stored result of ``case`` (its hash was checked by the caller)."""
        floats = {f.name for f in dataclasses.fields(DesignRow) if f.type == "float"}
        rows = tuple(DesignRow(**{k: math.nan if (v is None and k in floats) else v
                                  for k, v in r.items()}) for r in data["rows"])
        designs = {k: StoredDesign.from_dict(d) for k, d in data["designs"].items()}
        return cls(case, rows, designs, float(data["seconds"]), data.get("certificate")).check()


@dataclass(frozen=True)
class CaseFailure:
    """A case that raised; nothing is stored for it, so a rerun retries it."""

    case_id: str
    error: str
    traceback: str

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True, eq=False)
class StudyResult:
    """A study's results (complete, or partial when cases failed).

    Attributes:
        config: The configuration.
        out_dir: The output folder.
        cases: Successful cases, in configuration order.
        failures: Cases that raised.
        computed: Ids of the cases computed by this run.
        loaded: Ids of the cases loaded from ``out_dir/cases``.
        wall_seconds: Wall time of this run [s].
        n_jobs: Parallel jobs asked for (None: all local cores).
        scheduler: Dask scheduler address, or None (local joblib).
        machine: Platform, processor, CPU count, Python version.
        command: The command line that ran the study, for the report.
        runs: Every run on this output folder, oldest first (``runs.json``): its
            command, start time, wall time, cases computed and loaded, jobs and
            the machine's load average before and after, so that a resumed
            study keeps the timing of the runs that computed it.
    """

    config: StudyConfig
    out_dir: Path
    cases: tuple[CaseResult, ...]
    failures: tuple[CaseFailure, ...] = ()
    computed: tuple[str, ...] = ()
    loaded: tuple[str, ...] = ()
    wall_seconds: float = 0.0
    n_jobs: int | None = None
    scheduler: str | None = None
    machine: dict = dataclasses.field(default_factory=dict)
    command: str = ""
    runs: tuple[dict, ...] = ()

    def rows(self) -> list[DesignRow]:
        return [r for c in self.cases for r in c.rows]

    def clock_stopped(self) -> list[DesignRow]:
        """The designs the SQP's wall-clock limit (``sqp.time_limit``) stopped: their values
        depend on the machine's load, unlike those bounded by the iteration limit."""
        return [r for r in self.rows() if r.status == SQPStatus.TIME_LIMIT.value]

    def case(self, case_id: str) -> CaseResult:
        for c in self.cases:
            if c.case_id == case_id:
                return c
        raise KeyError(f"no case {case_id!r}; cases are: {[c.case_id for c in self.cases]}")

    def summary(self) -> dict:
        """The content of ``summary.json``."""
        return plain({
            "format": SUMMARY_FORMAT, "study": self.config.name,
            "config_source": self.config.source, "config": self.config.to_dict(),
            "command": self.command, "machine": self.machine, "n_jobs": self.n_jobs,
            "scheduler": self.scheduler, "wall_seconds": self.wall_seconds,
            "case_seconds_total": sum(c.seconds for c in self.cases),
            "n_cases": len(self.config.specs), "n_done": len(self.cases),
            "computed": list(self.computed), "loaded": list(self.loaded),
            "failures": [f.to_dict() for f in self.failures],
            "improvement_convention": IMPROVEMENT_CONVENTION,
            "cases": [case_summary(c) for c in self.cases],
        })


def case_summary(result: CaseResult) -> dict:
    """Per case: the KPI average variances [mm²], improvements [%] and colliding fractions."""
    plan, spec = result.case.plan, result.case.spec
    median = result.row("heuristic_median").kpi_avg_variance_mm2
    out = {"case_id": result.case_id, "robot": spec.robot, "scene": spec.scene_label,
           "lambda_mm": spec.lambda_mm, "mu_mm": spec.mu_mm, "seconds": result.seconds,
           "heuristic_median_mm2": median,
           "heuristic_mm2": [r.kpi_avg_variance_mm2 for r in result.rows if r.kind == "heuristic"]}
    for coll in plan.collisions:
        key = "collisions" if coll else "no_collisions"
        opt = {c: result.row("optimal", c, coll) for c in plan.criteria}
        block = {"optimal_mm2": {c: r.kpi_avg_variance_mm2 for c, r in opt.items()},
                 "colliding_fraction": {c: r.colliding_fraction for c, r in opt.items()},
                 "status": {c: r.status for c, r in opt.items()},
                 "iterations": {c: r.iterations for c, r in opt.items()}}
        if "kpi" in opt:
            v = opt["kpi"].kpi_avg_variance_mm2
            block["improvement_pct"] = {"vs_heuristic": improvement_pct(v, median)}
            if "params" in opt:
                block["improvement_pct"]["vs_params"] = improvement_pct(
                    v, opt["params"].kpi_avg_variance_mm2)
        out[key] = block
    return out


def rows_csv(rows: Sequence[DesignRow]) -> str:
    """The tidy table as CSV text (floats with 10 significant digits, None empty)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(DesignRow.columns())
    for r in rows:
        writer.writerow(["" if v is None else (f"{v:.10g}" if isinstance(v, float) else v)
                         for v in r.to_dict().values()])
    return buf.getvalue()
