"""The result of a design optimisation, and its files.

``DIR/design.yaml`` holds the scene, the joint names, the configurations (rad
and deg), the criterion values, the KPI standard deviations, the constraint
margins and the solver record; ``DIR/design.csv`` the plain joint values
(header = URDF joint names, one row per pose, rad); ``DIR/timing.yaml`` the
run's wall and CPU times (every ``seconds``, ``cpu_seconds``, ``time`` and
``times`` entry, at the same place in the record), which depend on the
machine and its load, so that the design files of one seed are the same bytes
in every run. All are written atomically (:mod:`calib_oed.io.atomic`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from calib_oed.feasibility.margins import KindMargin, format_margins
from calib_oed.io.atomic import atomic_write_text
from calib_oed.io.design_file import write_design_csv
from calib_oed.model.robot import Robot
from calib_oed.oed.positions import POSITION_TOL
from calib_oed.values import plain


@dataclass(frozen=True, eq=False)
class Design:
    """An optimised (or baseline) design of measurement configurations.

    Attributes:
        scene: Scene name.
        joint_names: URDF joint names, the columns of ``q``.
        q: Configurations (n, nq) [rad].
        criterion: Name of the criterion optimised (``"heuristic"`` for none).
        value: Its value at ``q`` (the criterion's unit, e.g. mm² for ``kpi``).
        start_value: Its value at the start design.
        criteria: Value of every criterion at ``q`` (``kpi`` and ``params`` in
            mm², ``D`` log det C, ``E`` mm², ``O1..O5`` the indices).
        kpi_sigma_mm: :math:`\\sqrt{\\mathrm{tr}\\,C_{s,i}/3}` per working configuration [mm].
        kpi_names: Names of the working configurations.
        margins: Tightest constraint of each kind.
        feasible: Every constraint of the full feasibility model holds.
        solver: The solver record (:meth:`calib_oed.solver.sqp.SQPResult.to_dict`), or {}.
        seconds: Wall time of the optimisation [s].
        seed: Seed of the start design.
        collisions: Whether collision constraints were imposed.
        method: How it was obtained: ``"exchange+sqp"`` (the default pipeline:
            exchange start refined by the SQP), ``"heuristic+sqp"``,
            ``"given+sqp"``, ``"staged+sqp"`` (a large ``kpi_model`` design from a smaller one
            measured twice, :mod:`calib_oed.oed.staged`), ``"exchange"`` (selection from a candidate pool
            only), ``"heuristic"`` (random feasible poses) or ``"given"``.
        certificate: The optimality certificate of the design
            (:func:`calib_oed.oed.certificate.certify`): ``efficiency`` (<= 1),
            ``lower_bound`` (the criterion no feasible design of n poses can
            beat, in the criterion's unit), ``scope``, ``seconds``; or
            ``skipped`` with the reason; {} when not computed.
        joint_window: The joint ranges the design could use
            (:meth:`calib_oed.feasibility.window.JointWindow.summary`, degrees), or "".
        position_multiplicity: How often each distinct arm position is measured
            (reflector positions in the world frame within ``position_tolerance``,
            :mod:`calib_oed.oed.positions`), order of first occurrence; () when not computed.
        position_tolerance: The tolerance of ``position_multiplicity`` [m].
    """

    scene: str
    joint_names: tuple[str, ...]
    q: np.ndarray
    criterion: str
    value: float
    start_value: float
    criteria: dict[str, float]
    kpi_sigma_mm: np.ndarray
    kpi_names: tuple[str, ...]
    margins: tuple[KindMargin, ...]
    feasible: bool
    solver: dict = field(default_factory=dict)
    seconds: float = 0.0
    seed: int | None = None
    collisions: bool = True
    method: str = "sqp"
    certificate: dict = field(default_factory=dict)
    joint_window: str = ""
    position_multiplicity: tuple[int, ...] = ()
    position_tolerance: float = POSITION_TOL

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    @property
    def efficiency(self) -> float | None:
        """Efficiency against the certified lower bound (<= 1), or None without a certificate."""
        value = self.certificate.get("efficiency")
        return None if value is None else float(value)

    @property
    def interrupted(self) -> bool:
        """A Ctrl-C (or SIGTERM) stopped the pipeline: the best feasible design so far."""
        return bool(self.solver.get("interrupted", False))

    @property
    def multiplicity(self) -> list[int]:
        """How often each distinct configuration is measured (order of first occurrence)."""
        from calib_oed.oed.starts import multiplicities

        return multiplicities(self.q)

    @property
    def distinct_positions(self) -> int | None:
        """Number of distinct arm positions (reflectors more than ``position_tolerance`` apart), or None."""
        return len(self.position_multiplicity) if self.position_multiplicity else None

    @property
    def kpi_variance(self) -> float:
        """The paper's KPI criterion: average variance of the KPI coordinates [mm²]."""
        return float(self.criteria["kpi"])

    @property
    def kpi_max_variance(self) -> float:
        r"""Worst-case KPI variance :math:`\max_i \sigma_i^2` over the KPI points [mm²]."""
        return float(np.max(self.kpi_sigma_mm) ** 2)

    @property
    def kpi_worst(self) -> str:
        """Name of the KPI point with the largest variance."""
        return self.kpi_names[int(np.argmax(self.kpi_sigma_mm))]

    def summary(self) -> str:
        """A short report for the terminal."""
        lines = [
            f"{self.method} design of {self.n} poses for scene {self.scene!r}, "
            f"criterion {self.criterion!r}"
            f"{'' if self.collisions else ' (no collision constraints)'}",
            f"  criterion value {self.value:.6g} (start {self.start_value:.6g}), "
            f"{self.seconds:.2f} s",
            f"  KPI average variance {self.kpi_variance:.4g} mm²; KPI sigma per axis "
            + ", ".join(f"{n} {s:.5f} mm" for n, s in zip(self.kpi_names, self.kpi_sigma_mm,
                                                          strict=True)),
            f"  feasible: {self.feasible}",
        ]
        if len(self.kpi_names) > 1:
            lines.insert(3, f"  {len(self.kpi_names)} KPI points: mean variance {self.kpi_variance:.4g} mm² "
                         f"(weighted as the scene says), max {self.kpi_max_variance:.4g} mm² "
                         f"(sigma {np.sqrt(self.kpi_max_variance):.5f} mm) at {self.kpi_worst}")
        lines.append(self.distinct_line())
        for stage in (self.solver.get("staged") or {}).get("stages", ()):  # oed/staged.py
            lines.append(f"  start: the {stage['poses']}-pose design (value {stage['value']:.6g}, "
                         f"{stage['iterations']} iterations) measured twice, the copy moved "
                         f"({stage['exact_copies']} poses copied exactly)")
        if self.solver.get("status"):
            lines.append(f"  solver: {self.solver.get('status')}, {self.solver.get('iterations')} "
                         f"iterations, {self.solver.get('message', '')}")
        if self.interrupted:
            lines.append("  INTERRUPTED: the best feasible design found before Ctrl-C "
                         "(not converged)")
        lines.append(self.efficiency_line())
        lines.append(format_margins(list(self.margins)))
        return "\n".join(lines)

    def distinct_line(self) -> str:
        """Distinct joint vectors and distinct arm positions (reflector positions) in one line."""
        counts = self.multiplicity
        text = f"  {len(counts)} distinct poses (joint vectors) for {self.n} measurements"
        if len(counts) < self.n:
            text += (f", {sum(c > 1 for c in counts)} measured more than once "
                     f"(at most {max(counts)} times)")
        if self.position_multiplicity:
            text += (f"; {self.distinct_positions} distinct arm positions (reflectors more than "
                     f"{1e3 * self.position_tolerance:g} mm apart)")
        return text

    def efficiency_line(self) -> str:
        """The certificate in one line: the efficiency, the bound, or why there is none."""
        cert = self.certificate
        if self.efficiency is not None:
            return (f"  efficiency: {100 * self.efficiency:.1f} % of the best any {self.n}-pose "
                    f"feasible design could reach (certified lower bound "
                    f"{cert['lower_bound']:.4g} against {self.value:.4g}, criterion "
                    f"{self.criterion!r}; certificate {cert.get('seconds', 0.0):.1f} s"
                    + ("" if cert.get("search_complete", True) else
                       f"; its search for better poses ended early ({cert.get('search_end', 'round limit')}), "
                       "so the bound is only as good as the poses it found") + ")")
        gap = cert.get("multistart")
        if gap and len(gap["starts"]) > 1:  # a criterion without a bound: the best of several starts
            return (f"  efficiency: not certified (no lower bound for {self.criterion!r}); the best of "
                    f"{len(gap['starts'])} starts, the first start {100 * gap['first_start_gap']:.1f} % above "
                    f"it, the worst {100 * gap['max_gap']:.1f} %")
        if cert.get("skipped"):
            return f"  efficiency: not certified ({cert['skipped']})"
        return "  efficiency: not certified"

    def to_dict(self) -> dict:
        """A plain, YAML/JSON-safe record (SI configurations plus degrees)."""
        return plain({
            "format": "calib_oed design v1",
            "scene": self.scene,
            "criterion": self.criterion,
            "method": self.method,
            "collisions": self.collisions,
            "seed": self.seed,
            "n": self.n,
            "joint_names": list(self.joint_names),
            "configurations_rad": self.q.tolist(),
            "configurations_deg": np.degrees(self.q).round(6).tolist(),
            "value": self.value,
            "start_value": self.start_value,
            "criteria": dict(self.criteria),
            "kpi_sigma_mm": dict(zip(self.kpi_names, self.kpi_sigma_mm.tolist(), strict=True)),
            "kpi_max_variance_mm2": self.kpi_max_variance,
            "kpi_worst": self.kpi_worst,
            "feasible": self.feasible,
            "interrupted": self.interrupted,
            "margins": [vars(m) for m in self.margins],
            "seconds": self.seconds,
            "efficiency": self.efficiency,
            "certificate": dict(self.certificate),
            "joint_window": self.joint_window,
            "distinct_poses": len(self.multiplicity),
            "multiplicity": self.multiplicity,
            "distinct_positions": self.distinct_positions,
            "position_tolerance_mm": 1e3 * self.position_tolerance,
            "position_multiplicity": list(self.position_multiplicity),
            "solver": self.solver,
        })


#: Keys of a design record that hold wall or CPU times (they go to ``timing.yaml``).
TIMING_KEYS = frozenset({"seconds", "cpu_seconds", "time", "times"})


def split_timing(record):
    """``(content, timing)``: the record without its :data:`TIMING_KEYS` entries, and those
    entries alone at the same place (dicts and lists kept where they hold one); ``None``
    for a part with nothing in it."""
    if isinstance(record, dict):
        content, timing = {}, {}
        for key, value in record.items():
            if key in TIMING_KEYS:
                timing[key] = value
                continue
            content[key], t = split_timing(value)
            if t is not None:
                timing[key] = t
        return content, (timing or None)
    if isinstance(record, list):
        parts = [split_timing(v) for v in record]
        timing = [t for _, t in parts]
        return [c for c, _ in parts], (timing if any(t is not None for t in timing) else None)
    return record, None


def write_design(folder: str | os.PathLike, design: Design, robot: Robot) -> dict[str, Path]:
    """Write ``design.yaml``, ``design.csv`` and ``timing.yaml`` into ``folder`` (created if needed).

    ``design.yaml`` and ``design.csv`` depend only on the input (scene, options,
    seed): the same bytes in every run on one machine; the times go to ``timing.yaml``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    content, timing = split_timing(design.to_dict())
    content = {"format": content.pop("format"), "scene": content.pop("scene"), "robot": robot.name, **content}
    text = yaml.safe_dump(content, sort_keys=False, width=120)
    yaml_path = atomic_write_text(folder / "design.yaml", text)
    timing_path = atomic_write_text(folder / "timing.yaml", yaml.safe_dump(timing or {}, sort_keys=False, width=120))
    csv_path = write_design_csv(
        folder / "design.csv", robot, design.q,
        comment=f"scene {design.scene}: {design.criterion}-optimal design of {design.n} poses",
    )
    return {"yaml": yaml_path, "csv": csv_path, "timing": timing_path}


def design_label(path: str | os.PathLike) -> str:
    """A short name of a design file for tables: its folder for ``DIR/design.*``, else its stem."""
    path = Path(path)
    return path.parent.name or path.stem if path.stem == "design" else path.stem


def format_design_table(designs: dict[str, Design]) -> str:
    """Designs side by side: KPI average variance [mm²], KPI σ [mm], ratio to the first, time."""
    names = list(designs)
    ref = designs[names[0]].kpi_variance
    timed = any(d.seconds > 0 for d in designs.values())  # designs read from files have no time
    lines = [f"{'design':14s} {'KPI avg var':>12s} {'KPI sigma':>10s} {'vs ' + names[0]:>14s} "
             f"{'feasible':>8s}" + (f" {'time':>8s}" if timed else ""),
             f"{'':14s} {'[mm²]':>12s} {'[mm]':>10s} {'':>14s} {'':>8s}" + (f" {'[s]':>8s}" if timed else "")]
    for name in names:
        d = designs[name]
        lines.append(f"{name:14s} {d.kpi_variance:12.4e} {np.sqrt(d.kpi_variance):10.5f} "
                     f"{d.kpi_variance / ref:13.1%} {str(d.feasible):>8s}"
                     + (f" {d.seconds:8.2f}" if timed else ""))
    return "\n".join(lines)


def format_criteria_table(designs: dict[str, Design]) -> str:
    """Every criterion value of each design, one column per design.

    ``kpi`` and ``params`` are average variances [mm², parameters in mm and
    mrad], ``D`` log det C, ``E`` the largest eigenvalue [mm²], ``O1..O5`` the
    observability indices (larger is better).
    """
    names = list(designs)
    keys = list(designs[names[0]].criteria)
    width = max(12, *(len(n) for n in names))
    lines = [f"{'criterion':10s} " + " ".join(f"{n:>{width}s}" for n in names) + "  unit"]
    for key in keys:
        lines.append(f"{key:10s} " + " ".join(f"{designs[n].criteria.get(key, float('nan')):>{width}.5g}"
                                              for n in names) + f"  {_CRITERION_UNITS.get(key, '')}")
    lines.append(f"{'n poses':10s} " + " ".join(f"{designs[n].n:>{width}d}" for n in names))
    return "\n".join(lines)


#: What each criterion value of :func:`format_criteria_table` is measured in.
_CRITERION_UNITS = {
    "kpi": "mm² (mean KPI variance, noise only)", "params": "mm², mrad² (mean parameter variance)",
    "D": "log det C (mm, mrad)", "E": "mm² (largest eigenvalue of C)",
    "kpi_model": "mm² (mean squared KPI error per axis, with model error)",
    "kpi_kriging": "mm² (the same, with the fitted model error compensated)",
    **{f"O{k}": "(larger is better)" for k in range(1, 6)},
}
