"""The result of a design optimisation, and its files.

``DIR/design.yaml`` holds the scene, the joint names, the configurations (rad
and deg), the criterion values, the KPI standard deviations, the constraint
margins and the solver record; ``DIR/design.csv`` the plain joint values
(header = URDF joint names, one row per pose, rad). Both are written
atomically (:mod:`calib_oed.io.atomic`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from calib_oed.exceptions import MeasurementFileError
from calib_oed.feasibility.margins import KindMargin, format_margins
from calib_oed.io.atomic import atomic_write_text
from calib_oed.io.design_file import read_design_csv, write_design_csv
from calib_oed.model.robot import Robot
from calib_oed.scene.yaml_file import MAX_YAML_BYTES, load_yaml_file


def _finite(value):
    """JSON/YAML-safe: NaN and inf become None, numpy scalars plain floats."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    return value


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
            ``"given+sqp"``, ``"exchange"`` (selection from a candidate pool
            only), ``"heuristic"`` (random feasible poses) or ``"given"``.
        certificate: The optimality certificate of the design
            (:func:`calib_oed.oed.certificate.certify`): ``efficiency`` (<= 1),
            ``lower_bound`` (the criterion no feasible design of n poses can
            beat, in the criterion's unit), ``scope``, ``seconds``; or
            ``skipped`` with the reason; {} when not computed.
        joint_window: The joint ranges the design could use
            (:meth:`calib_oed.feasibility.window.JointWindow.summary`, degrees), or "".
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
        counts = self.multiplicity
        if len(counts) < self.n:
            lines.append(f"  {len(counts)} distinct poses for {self.n} measurements: "
                         f"{sum(c > 1 for c in counts)} measured more than once (at most {max(counts)} times)")
        if self.solver.get("status"):
            lines.append(f"  solver: {self.solver.get('status')}, {self.solver.get('iterations')} "
                         f"iterations, {self.solver.get('message', '')}")
        if self.interrupted:
            lines.append("  INTERRUPTED: the best feasible design found before Ctrl-C "
                         "(not converged)")
        lines.append(self.efficiency_line())
        lines.append(format_margins(list(self.margins)))
        return "\n".join(lines)

    def efficiency_line(self) -> str:
        """The certificate in one line: the efficiency, the bound, or why there is none."""
        cert = self.certificate
        if self.efficiency is not None:
            return (f"  efficiency: {100 * self.efficiency:.1f} % of the best any {self.n}-pose "
                    f"feasible design could reach (certified lower bound "
                    f"{cert['lower_bound']:.4g} against {self.value:.4g}, criterion "
                    f"{self.criterion!r}; certificate {cert.get('seconds', 0.0):.1f} s"
                    + ("" if cert.get("search_complete", True) else
                       "; its search for better poses hit its round limit, so the bound is only "
                       "as good as the poses it found") + ")")
        if cert.get("skipped"):
            return f"  efficiency: not certified ({cert['skipped']})"
        return "  efficiency: not certified"

    def to_dict(self) -> dict:
        """A plain, YAML/JSON-safe record (SI configurations plus degrees)."""
        return _finite({
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
            "solver": self.solver,
        })


def write_design(folder: str | os.PathLike, design: Design, robot: Robot) -> dict[str, Path]:
    """Write ``design.yaml`` and ``design.csv`` into ``folder`` (created if needed)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data = design.to_dict()
    data = {"format": data.pop("format"), "scene": data.pop("scene"), "robot": robot.name, **data}
    text = yaml.safe_dump(data, sort_keys=False, width=120)
    yaml_path = atomic_write_text(folder / "design.yaml", text)
    csv_path = write_design_csv(
        folder / "design.csv", robot, design.q,
        comment=f"scene {design.scene}: {design.criterion}-optimal design of {design.n} poses",
    )
    return {"yaml": yaml_path, "csv": csv_path}


def read_design_file(path: str | os.PathLike, robot: Robot, check_limits: bool = True,
                     controller=None) -> np.ndarray:
    """Configurations (n, nq) [rad] of a design file, in ``robot``'s joint order.

    Accepts what :func:`write_design` writes: ``design.yaml`` (its
    ``joint_names`` and ``configurations_rad``) or a design CSV (header = joint
    names, rad), recognised by the suffix (``.yaml``/``.yml``, else CSV). A CSV in
    controller joint values (``# joints: controller <name>``) is mapped to URDF joints
    with ``controller``, the scene's :class:`~calib_oed.model.controller.ControllerConvention`.

    Raises:
        MeasurementFileError: unreadable file, not a calib_oed design, joint
            names that are not the robot's, bad or out-of-limit values.
    """
    path = Path(path)
    if path.is_dir():
        raise MeasurementFileError(str(path), [(None, "is a folder; give its design.yaml or design.csv")],
                                   kind="design file")
    if path.suffix.lower() not in (".yaml", ".yml"):
        return read_design_csv(path, robot, check_limits=check_limits, controller=controller)
    source = str(path)

    def fail(message: str) -> MeasurementFileError:
        return MeasurementFileError(source, [(None, message)], kind="design file")

    try:
        data = load_yaml_file(path, "design file", MAX_YAML_BYTES)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise fail(f"cannot read the design YAML ({exc})") from exc
    if not isinstance(data, dict) or not str(data.get("format", "")).startswith("calib_oed design"):
        raise fail("not a calib_oed design YAML (expected 'format: calib_oed design v1', "
                   "'joint_names' and 'configurations_rad', as `calib-oed design -o DIR` writes)")
    if "robot" in data and str(data["robot"]).lower() != robot.name.lower():
        raise fail(f"a design of robot {data['robot']!r}, not of this scene's robot {robot.name!r}")
    names = data.get("joint_names")
    rows = data.get("configurations_rad")
    if not isinstance(names, list) or sorted(map(str, names)) != sorted(robot.joint_names):
        raise fail(f"joint_names {names} are not the robot's joints {list(robot.joint_names)}")
    try:
        q = np.array(rows, dtype=float)
    except (TypeError, ValueError) as exc:
        raise fail(f"configurations_rad is not a table of numbers ({exc})") from exc
    if q.ndim != 2 or q.shape[0] < 1 or q.shape[1] != len(names):
        raise fail(f"configurations_rad must be n >= 1 rows of {len(names)} values, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise fail("configurations_rad holds NaN or infinite values")
    q = q[:, [list(map(str, names)).index(j) for j in robot.joint_names]]
    if check_limits:
        bad = np.argwhere((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))
        if bad.size:
            raise MeasurementFileError(source, [
                (None, f"pose {k}: {robot.joint_names[i]} = {q[k, i]:.6g} outside the limits "
                       f"[{robot.lower[i]:.6g}, {robot.upper[i]:.6g}] (rad, or m if prismatic)")
                for k, i in bad], kind="design file")
    return q


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
    lines = [f"{'criterion':10s} " + " ".join(f"{n:>{width}s}" for n in names)]
    for key in keys:
        lines.append(f"{key:10s} " + " ".join(f"{designs[n].criteria.get(key, float('nan')):>{width}.5g}"
                                              for n in names))
    lines.append(f"{'n poses':10s} " + " ".join(f"{designs[n].n:>{width}d}" for n in names))
    return "\n".join(lines)
