r"""Running a study: every case's designs, in parallel, resumable, into a tidy table.

A study (:class:`~calib_oed.study.config.StudyConfig`) is a list of cases (one
robot in one scene) and the plan every case runs (:func:`run_case`):

1. the heuristic designs of all ``heuristic_seeds`` (random feasible poses,
   :func:`calib_oed.oed.design.heuristic_designs`) and their median KPI average
   variance;
2. for each ``collisions`` flag and each criterion, the SQP design
   (:func:`calib_oed.oed.design.design`) from the same start (the heuristic
   design of ``seed``, or the exchange start);
3. with a ``certificate`` in the plan, the optimality certificate of the
   KPI criterion for ``n`` poses (:func:`calib_oed.oed.certificate.certify`) on
   a random feasible pool plus the poses of every feasible design of the
   case, so that its lower bound holds for each of them (checked), and each
   feasible design's efficiency ``bound / V``.

Every design is evaluated on the KPI average variance
:math:`V = \mathrm{tr}(C_s)/(3t)` [mm²] (``Design.criteria["kpi"]``) and on
the full feasibility model: a pose *collides* if any self-collision, obstacle
or beam row is below :math:`-10^{-6}`
(:data:`calib_oed.feasibility.constraints.FEASIBILITY_TOL`); a design
optimised without collision constraints reports the fraction of its poses that
collide. Improvements are :math:`100\,(1 - V_{\text{KPI-opt}}/V_{\text{other}})` [%].

:func:`run_study` runs the cases with joblib (local processes, or a Dask
cluster through joblib's dask backend when given a scheduler address), writes
each case's result to ``OUT/cases/<case_id>.json`` as soon as it arrives
(atomically), loads instead of recomputing the cases already there (after
checking their configuration hash), then writes ``OUT/results.csv`` (one row
per case × design) and ``OUT/summary.json``. :mod:`calib_oed.study.report`
turns them into the paper's tables and figures.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import platform
import sys
import time
import traceback
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, closing
from dataclasses import dataclass
from pathlib import Path

import joblib
import numpy as np
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from calib_oed.calibration.workflow import setup
from calib_oed.exceptions import OptionalDependencyError, StudyResumeError
from calib_oed.feasibility.constraints import FEASIBILITY_TOL, FeasibilityModel
from calib_oed.io.atomic import atomic_write_text
from calib_oed.oed.design import design, heuristic_designs
from calib_oed.oed.problem import COLLISION_KINDS, NO_COLLISION_KINDS
from calib_oed.oed.result import Design
from calib_oed.study.config import StudyCase, StudyConfig, study_config_from_dict

__all__ = ["CaseFailure", "CaseResult", "DesignRow", "StoredDesign", "StudyResult",
           "colliding_poses", "improvement_pct", "read_study", "run_case", "run_study"]

#: Rows of the feasibility model that are collisions (self, obstacle, beam).
COLLISION_ROW_KINDS = tuple(k for k in COLLISION_KINDS if k not in NO_COLLISION_KINDS)
#: Design kinds of the table.
KINDS = ("heuristic", "heuristic_median", "optimal")
CASE_FILE_FORMAT = "calib_oed study case result v1"
SUMMARY_FORMAT = "calib_oed study summary v1"
IMPROVEMENT_CONVENTION = "100 * (1 - V_kpi_optimal / V_other), V = KPI average variance [mm^2]"


def improvement_pct(v_kpi: float, v_other: float) -> float:
    r"""Improvement of the KPI-optimal design over another, :math:`100\,(1 - V_{kpi}/V_{other})` [%]."""
    return 100.0 * (1.0 - float(v_kpi) / float(v_other))


def colliding_poses(feasibility: FeasibilityModel, q: np.ndarray) -> np.ndarray:
    """Which poses of ``q`` (n, nq) [rad] collide: a self, obstacle or beam row < -tol, (n,) bool."""
    res = feasibility.compute(q, jacobian=False)
    slices = feasibility.kind_slices()
    rows = np.concatenate([slices[k] for k in COLLISION_ROW_KINDS])
    if rows.size == 0:
        return np.zeros(len(q), dtype=bool)
    return res.values[:, rows].min(axis=1) < -FEASIBILITY_TOL


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
                "solver": _plain(self.solver)}

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
        return _plain({"format": CASE_FILE_FORMAT, "case_id": self.case_id,
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

    def case(self, case_id: str) -> CaseResult:
        for c in self.cases:
            if c.case_id == case_id:
                return c
        raise KeyError(f"no case {case_id!r}; cases are: {[c.case_id for c in self.cases]}")

    def summary(self) -> dict:
        """The content of ``summary.json``."""
        return _plain({
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


# ---------------------------------------------------------------- one case

def _row(case: StudyCase, d: Design, kind: str, criterion: str, collisions: bool, seed,
         colliding: float) -> DesignRow:
    spec = case.spec
    solver = d.solver or {}
    return DesignRow(
        case_id=spec.case_id, robot=spec.robot, scene=spec.scene_label,
        lambda_mm=spec.lambda_mm, mu_mm=spec.mu_mm, kind=kind, criterion=criterion,
        collisions=bool(collisions), seed=seed, n=d.n,
        kpi_avg_variance_mm2=d.kpi_variance, kpi_sigma_mm=float(np.max(d.kpi_sigma_mm)),
        params_avg_variance=float(d.criteria["params"]), criterion_value=float(d.value),
        criterion_start_value=float(d.start_value), feasible=bool(d.feasible),
        colliding_fraction=colliding, iterations=int(solver.get("iterations", 0)),
        status=str(solver.get("status", "")), seconds=float(d.seconds))


def run_case(case: StudyCase) -> CaseResult:
    """Heuristic designs, then every (collisions, criterion) SQP design of one case.

    The optimised designs all start from the same design: the heuristic
    design of ``plan.seed`` (``start: heuristic``) or the exchange algorithm's
    (``start: exchange``, per criterion). BLAS is pinned to one thread.
    """
    t0 = time.perf_counter()
    plan = case.plan
    with threadpool_limits(limits=1, user_api="blas"):
        s = setup(case.spec.load_scene())
        fm = s.feasibility
        names = tuple(s.problem.robot.joint_names)
        rows, heur = [], []
        for seed in plan.heuristic_seeds:
            t = time.perf_counter()
            d = heuristic_designs(s, plan.n, [seed])[0]
            d = dataclasses.replace(d, seconds=time.perf_counter() - t)
            heur.append(d)
            rows.append(_row(case, d, "heuristic", "", True, seed,
                             float(colliding_poses(fm, d.q).mean())))
        rows.append(_median_row(case, rows))
        values = [d.kpi_variance for d in heur]
        mid = heur[int(np.argsort(values)[(len(values) - 1) // 2])]  # the lower median
        designs = {"heuristic_median": StoredDesign("heuristic_median", names, mid.q, mid.seed,
                                                    {})}
        optimal: dict[str, Design] = {}
        start = plan.start
        if start == "heuristic" and plan.seed in plan.heuristic_seeds:
            start = heur[plan.heuristic_seeds.index(plan.seed)].q  # the same poses, not redrawn
        settings = plan.sqp_settings()
        for coll in plan.collisions:
            for crit in plan.criteria:
                d = design(s, plan.n, crit, start=start, seed=plan.seed, collisions=coll,
                           settings=settings)
                rows.append(_row(case, d, "optimal", crit, coll, plan.seed,
                                 float(colliding_poses(fm, d.q).mean())))
                label = design_label(crit, coll)
                designs[label] = StoredDesign(label, names, d.q, plan.seed, d.solver)
                optimal[label] = d
        certificate = None
        if plan.certificate is not None:
            rows, certificate = _certified_rows(s, plan, rows, heur, optimal)
    return CaseResult(case, tuple(rows), designs, time.perf_counter() - t0, certificate).check()


def _certified_rows(s, plan, rows, heuristic, optimal):
    """The case's certificate and its rows with the bound and the efficiencies.

    The pool is ``plan.certificate.pool`` random feasible poses plus the poses
    of every feasible design of the case, so the bound holds for each of them
    (:meth:`CaseResult.check` verifies it); the certificate is that of the
    KPI-optimal design (with collisions if planned, else the first).
    """
    from calib_oed.feasibility.sampling import sample_feasible
    from calib_oed.oed.certificate import certify

    cp = plan.certificate
    feasible = [d.q for d in (*heuristic, *optimal.values()) if d.feasible]
    pool = np.vstack([sample_feasible(s.feasibility, cp.pool, cp.seed, max_draws=50_000_000), *feasible])
    kpi = [optimal[k] for k in (design_label("kpi", True), design_label("kpi", False)) if k in optimal]
    q = kpi[0].q if kpi else next(iter(optimal.values())).q if optimal else heuristic[0].q
    cert = certify(s, q, "kpi", pool=pool, local_starts=cp.local_starts)
    rows = [dataclasses.replace(r, kpi_bound_mm2=cert.bound,
                                kpi_efficiency=cert.bound / r.kpi_avg_variance_mm2 if r.feasible
                                else math.nan) for r in rows]
    return rows, cert.to_dict()


def _median_row(case: StudyCase, rows: Sequence[DesignRow]) -> DesignRow:
    """The median over the heuristic rows, value by value (the tables' heuristic baseline)."""
    def med(key):
        return float(np.median([getattr(r, key) for r in rows]))

    first = rows[0]
    return dataclasses.replace(
        first, kind="heuristic_median", seed=None,
        kpi_avg_variance_mm2=med("kpi_avg_variance_mm2"), kpi_sigma_mm=med("kpi_sigma_mm"),
        params_avg_variance=med("params_avg_variance"), criterion_value=med("criterion_value"),
        criterion_start_value=med("criterion_start_value"),
        feasible=all(r.feasible for r in rows), colliding_fraction=med("colliding_fraction"),
        seconds=sum(r.seconds for r in rows))


def _execute(case: StudyCase) -> CaseResult | CaseFailure:
    """Worker entry: :func:`run_case` (looked up at call time), failures as records."""
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            return run_case(case)
    except Exception as exc:  # a failed case must not stop the others; it is reported
        return CaseFailure(case.case_id, f"{type(exc).__name__}: {exc}", traceback.format_exc())


# ---------------------------------------------------------------- files

def _plain(value):
    """JSON-safe: numpy to Python, NaN and inf to None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def case_path(out_dir: str | os.PathLike, case_id: str) -> Path:
    """``out_dir/cases/<case_id>.json``."""
    return Path(out_dir) / "cases" / f"{case_id}.json"


def load_case(path: Path, case: StudyCase) -> CaseResult:
    """A stored case result, after checking it was computed with ``case``'s settings.

    Raises:
        StudyResumeError: unreadable file or another configuration hash.
    """
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise StudyResumeError(path, [f"unreadable ({exc})"]) from exc
    if not isinstance(data, dict) or data.get("format") != CASE_FILE_FORMAT:
        raise StudyResumeError(path, [f"not a {CASE_FILE_FORMAT!r} file"])
    if data.get("config_hash") != case.config_hash:
        stored, now = data.get("identity") or {}, case.identity()
        diff = [f"{k}: {stored.get(k)!r} -> {now.get(k)!r}" for k in sorted({*stored, *now})
                if stored.get(k) != now.get(k)]
        raise StudyResumeError(path, diff or [f"hash {data.get('config_hash')} -> "
                                              f"{case.config_hash}"])
    try:
        return CaseResult.from_dict(data, case)
    except (KeyError, TypeError, ValueError) as exc:
        raise StudyResumeError(path, [f"inconsistent content ({exc})"]) from exc


def rows_csv(rows: Sequence[DesignRow]) -> str:
    """The tidy table as CSV text (floats with 10 significant digits, None empty)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(DesignRow.columns())
    for r in rows:
        writer.writerow(["" if v is None else (f"{v:.10g}" if isinstance(v, float) else v)
                         for v in r.to_dict().values()])
    return buf.getvalue()


def machine_info() -> dict:
    """Platform, processor, logical CPUs and Python of this machine."""
    return {"platform": platform.platform(), "processor": platform.processor() or
            platform.machine(), "cpu_count": os.cpu_count(), "python": sys.version.split()[0]}


# ---------------------------------------------------------------- the study

def _results(todo: Sequence[StudyCase], n_jobs: int | None, scheduler: str | None
             ) -> Iterator[CaseResult | CaseFailure]:
    """Case results in completion order, from local joblib workers or a Dask cluster."""
    if not todo:
        return
    with ExitStack() as stack:
        if scheduler is not None:
            try:
                from distributed import Client
            except ImportError as exc:
                raise OptionalDependencyError("a study on a Dask cluster (--scheduler)",
                                              "dask.distributed", "dask") from exc
            stack.enter_context(Client(scheduler))  # closed on exit; the cluster stays
            stack.enter_context(joblib.parallel_config(backend="dask"))
        parallel = joblib.Parallel(n_jobs=-1 if n_jobs is None else n_jobs,
                                   return_as="generator_unordered")
        yield from parallel(joblib.delayed(_execute)(case) for case in todo)


def run_study(
    config: StudyConfig,
    out_dir: str | os.PathLike,
    *,
    n_jobs: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    command: str | None = None,
) -> StudyResult:
    """Run (or resume) a study; write the case files, ``results.csv`` and ``summary.json``.

    Args:
        config: The study.
        out_dir: Output folder (created). Case files already in ``out_dir/cases``
            are loaded, not recomputed.
        n_jobs: Parallel cases (joblib ``n_jobs``); None: every local core, or
            every worker thread of the Dask cluster.
        scheduler: Address of a Dask scheduler (``tcp://host:8786``): the same
            cases run on that cluster through joblib's dask backend. Needs the
            ``calib_oed[dask]`` extra.
        progress: Show a progress bar over the cases (tqdm, on stderr).
        command: The command line, recorded for the report (default: the
            equivalent ``calib-oed study`` command).

    Raises:
        StudyResumeError: a case file in ``out_dir`` was computed with other settings.
        OptionalDependencyError: ``scheduler`` given without dask.distributed installed.
    """
    t0 = time.perf_counter()
    started = time.strftime("%Y-%m-%d %H:%M:%S %Z")
    load_before = os.getloadavg()
    out = Path(out_dir)
    (out / "cases").mkdir(parents=True, exist_ok=True)
    cases = config.cases()
    done: dict[str, CaseResult] = {}
    for case in cases:
        path = case_path(out, case.case_id)
        if path.exists():
            done[case.case_id] = load_case(path, case)
    loaded = tuple(done)
    todo = [c for c in cases if c.case_id not in done]
    failures, computed = [], []
    bar = tqdm(total=len(cases), initial=len(done), desc=config.name, unit="case",
               disable=not progress, file=sys.stderr)
    with bar, closing(_results(todo, n_jobs, scheduler)) as stream:
        for res in stream:  # completion order: each case is saved as soon as it arrives
            if isinstance(res, CaseFailure):
                failures.append(res)
            else:
                atomic_write_text(case_path(out, res.case_id),  # compact: ~200 kB a case
                                  json.dumps(res.to_dict(), separators=(",", ":")) + "\n")
                done[res.case_id] = res
                computed.append(res.case_id)
            bar.set_postfix_str(res.case_id, refresh=False)
            bar.update(1)
    if command is None:
        command = (f"calib-oed study {config.source or config.name} -o {out}"
                   + (f" --jobs {n_jobs}" if n_jobs is not None else "")
                   + (f" --scheduler {scheduler}" if scheduler else ""))
    wall = time.perf_counter() - t0
    runs = read_runs(out) + ({
        "command": command, "started": started, "wall_seconds": wall,
        "computed": len(computed), "loaded": len(loaded), "failed": len(failures),
        "n_jobs": n_jobs, "scheduler": scheduler,
        "load_average_1min": {"before": load_before[0], "after": os.getloadavg()[0]},
    },)
    atomic_write_text(out / "runs.json", json.dumps(list(runs), indent=1) + "\n")
    result = StudyResult(
        config=config, out_dir=out,
        cases=tuple(done[c.case_id] for c in cases if c.case_id in done),
        failures=tuple(failures), computed=tuple(computed), loaded=loaded,
        wall_seconds=wall, n_jobs=n_jobs, scheduler=scheduler,
        machine=machine_info(), command=command, runs=runs)
    atomic_write_text(out / "results.csv", rows_csv(result.rows()))
    atomic_write_text(out / "summary.json", json.dumps(result.summary(), indent=1) + "\n")
    return result


def read_runs(out_dir: str | os.PathLike) -> tuple[dict, ...]:
    """The run log ``runs.json`` of a study folder (empty if there is none yet)."""
    path = Path(out_dir) / "runs.json"
    if not path.exists():
        return ()
    return tuple(json.loads(path.read_text(encoding="utf-8")))


def read_study(out_dir: str | os.PathLike) -> StudyResult:
    """The results of a finished (or partial) study from its folder (``summary.json`` + cases).

    Raises:
        StudyResumeError: a case file does not match the stored configuration.
        FileNotFoundError: no ``summary.json`` in ``out_dir``.
    """
    out = Path(out_dir)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    config = study_config_from_dict(summary["config"], source=summary.get("config_source"))
    cases = tuple(load_case(case_path(out, c.case_id), c) for c in config.cases()
                  if case_path(out, c.case_id).exists())
    failures = tuple(CaseFailure(**f) for f in summary.get("failures", []))
    return StudyResult(config, out, cases, failures, tuple(summary.get("computed", [])),
                       tuple(summary.get("loaded", [])), float(summary.get("wall_seconds", 0.0)),
                       summary.get("n_jobs"), summary.get("scheduler"),
                       summary.get("machine", {}), summary.get("command", ""), read_runs(out))
