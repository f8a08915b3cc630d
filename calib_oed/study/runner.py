r"""Running a study: every case, in parallel, resumable, into a tidy table.

A study (:class:`~calib_oed.study.config.StudyConfig`) is a list of cases (one
robot in one scene), each run by :func:`calib_oed.study.case.run_case`.
:func:`run_study` runs the cases with joblib (local processes) or on a Dask
cluster's workers when given a scheduler address, writes
each case's result to ``OUT/cases/<case_id>.json`` as soon as it arrives
(atomically), loads instead of recomputing the cases already there (after
checking their configuration hash), then writes ``OUT/results.csv`` (one row
per case × design) and ``OUT/summary.json`` (the records of
:mod:`calib_oed.study.results`). :mod:`calib_oed.study.report` turns them into
the paper's tables and figures.

**One owner per folder**: a run holds an exclusive lock on ``OUT/.study.lock``
(``fcntl.flock``, released when the process ends, also when it is killed); a
second process on the same folder stops with :class:`~calib_oed.exceptions.StudyLockError`
before it writes anything. **Only finished cases are stored**: a case whose design
was stopped by Ctrl-C or SIGTERM raises ``KeyboardInterrupt`` instead of returning
(:func:`~calib_oed.study.case.run_case`), a failed case is a
:class:`~calib_oed.study.results.CaseFailure` in ``summary.json``, never a case file,
so a resume computes both again. **On a cluster the cases run on its workers**:
each case is one task submitted with ``Client.submit`` (not joblib's dask backend,
which can run tasks inside the client without a word); a cluster without workers is
an error naming the scheduler.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import platform
import sys
import time
import traceback
from collections.abc import Iterator, Sequence
from contextlib import closing
from pathlib import Path

import joblib
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from calib_oed.exceptions import (
    OptionalDependencyError,
    StudyConfigError,
    StudyLockError,
    StudyResumeError,
)
from calib_oed.io.atomic import atomic_write_text
from calib_oed.study.case import run_case
from calib_oed.study.config import StudyCase, StudyConfig
from calib_oed.study.loader import study_config_from_dict
from calib_oed.study.results import (
    CASE_FILE_FORMAT,
    CaseFailure,
    CaseResult,
    StudyResult,
    rows_csv,
)

__all__ = ["read_study", "run_study"]


def _execute(case: StudyCase) -> CaseResult | CaseFailure:
    """Worker entry: :func:`~calib_oed.study.case.run_case` (looked up at call time), failures as records."""
    try:
        with threadpool_limits(limits=1):
            return run_case(case)
    except Exception as exc:  # a failed case must not stop the others; it is reported
        return CaseFailure(case.case_id, f"{type(exc).__name__}: {exc}", traceback.format_exc())


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


def machine_info() -> dict:
    """Platform, processor, logical CPUs and Python of this machine."""
    return {"platform": platform.platform(), "processor": platform.processor() or
            platform.machine(), "cpu_count": os.cpu_count(), "python": sys.version.split()[0]}


@contextlib.contextmanager
def folder_lock(out_dir: str | os.PathLike) -> Iterator[None]:
    """Hold the exclusive lock of a study folder (module docstring) for the block.

    Raises:
        StudyLockError: another process holds it.
    """
    path = Path(out_dir) / ".study.lock"
    with open(path, "a+", encoding="utf-8") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            raise StudyLockError(out_dir, handle.read().strip()) from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"pid {os.getpid()}\n")
        handle.flush()
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _cluster_results(todo: Sequence[StudyCase], scheduler: str) -> Iterator[CaseResult | CaseFailure]:
    """Case results in completion order, each case a task on the cluster's workers."""
    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise OptionalDependencyError("a study on a Dask cluster (--scheduler)",
                                      "dask.distributed", "dask") from exc
    with Client(scheduler) as client:  # closed on exit; the cluster stays
        if not client.scheduler_info().get("workers"):
            raise StudyConfigError(f"the Dask scheduler {scheduler} has no workers: start some "
                                   f"(`dask worker {scheduler}`) or run without --scheduler",
                                   key="--scheduler")
        futures = [client.submit(_execute, case, key=f"calib_oed-case-{case.case_id}", pure=False)
                   for case in todo]
        try:
            for future in as_completed(futures):
                yield future.result()
        finally:
            client.cancel(futures)


def _results(todo: Sequence[StudyCase], n_jobs: int | None, scheduler: str | None
             ) -> Iterator[CaseResult | CaseFailure]:
    """Case results in completion order, from local joblib workers or a Dask cluster."""
    if not todo:
        return
    if scheduler is not None:
        yield from _cluster_results(todo, scheduler)
        return
    parallel = joblib.Parallel(n_jobs=-1 if n_jobs is None else n_jobs, return_as="generator_unordered")
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
            cases run on that cluster's workers, one task each (``n_jobs`` is then not
            used). Needs the ``calib_oed[dask]`` extra.
        progress: Show a progress bar over the cases (tqdm, on stderr).
        command: The command line, recorded for the report (default: the
            equivalent ``calib-oed study`` command).

    Raises:
        StudyResumeError: a case file in ``out_dir`` was computed with other settings.
        StudyLockError: another process runs a study into ``out_dir``.
        StudyConfigError: the cluster at ``scheduler`` has no workers.
        OptionalDependencyError: ``scheduler`` given without dask.distributed installed.
    """
    t0 = time.perf_counter()
    started = time.strftime("%Y-%m-%d %H:%M:%S %Z")
    load_before = os.getloadavg()
    out = Path(out_dir)
    (out / "cases").mkdir(parents=True, exist_ok=True)
    with folder_lock(out):
        return _run_locked(config, out, n_jobs, scheduler, progress, command, t0, started, load_before)


def _run_locked(config, out, n_jobs, scheduler, progress, command, t0, started, load_before) -> StudyResult:
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
