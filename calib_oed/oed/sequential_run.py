r"""A simulated sequential calibration to a precision target, and its comparison with fixed designs.

:func:`run_sequential` drives a :class:`~calib_oed.oed.sequential.SequentialDesigner`
against a simulated robot: identify from all data so far, stop when the
predicted KPI standard deviation :math:`\sigma_i = \sqrt{\mathrm{tr}(C_{s,ii})/3}`
[mm] at every working configuration is at most the target, otherwise measure
the proposed batch. :func:`measurements_needed` finds how many poses a fixed
KPI-optimal or heuristic design needs for the same target. The records are
:class:`SequentialStep`, :class:`MeasurementsNeeded` and :class:`SequentialResult`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from calib_oed.calibration.identification import identify
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.calibration.workflow import Setup, heuristic_design, tcp_errors
from calib_oed.exceptions import SequentialError
from calib_oed.oed.design import design as optimal_design
from calib_oed.oed.sequential import SequentialDesigner
from calib_oed.solver.sqp import SQPSettings

#: Designs of step 0 (:func:`run_sequential`).
INITIAL_DESIGNS = ("heuristic", "optimal")

#: Default grid of design sizes for :func:`measurements_needed`.
DEFAULT_GRID = tuple(range(10, 125, 5))


# ---------------------------------------------------------------- records
@dataclass(frozen=True, eq=False)
class SequentialStep:
    """The state after one identification.

    Attributes:
        n_measurements: Configurations measured so far.
        sigma_mm: Predicted KPI σ per working configuration at the estimate, (t,) [mm].
        tcp_error_mm: Actual KPI error against the simulated truth, (t,) [mm].
        n_added: Configurations added in this step (the initial design in step 0).
        method: ``"initial"``, ``"sqp"`` or ``"exchange"``.
        feasible: Every added configuration satisfies every feasibility row.
        seconds: Wall time of the proposal [s] (0 for the initial design).
    """

    n_measurements: int
    sigma_mm: np.ndarray
    tcp_error_mm: np.ndarray
    n_added: int
    method: str
    feasible: bool
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {"n_measurements": self.n_measurements, "sigma_mm": self.sigma_mm.tolist(),
                "sigma_max_mm": float(self.sigma_mm.max()), "tcp_error_mm": self.tcp_error_mm.tolist(),
                "n_added": self.n_added, "method": self.method, "feasible": self.feasible,
                "seconds": self.seconds}


@dataclass(frozen=True)
class MeasurementsNeeded:
    """The smallest design size on a grid that reaches the target.

    Attributes:
        method: ``"fixed KPI-optimal"`` or ``"heuristic"``.
        n: Smallest grid size with predicted σ ≤ target; None if none on the grid.
        sigma_mm: Largest predicted σ [mm] of each grid size evaluated, ``{n: σ}``.
    """

    method: str
    n: int | None
    sigma_mm: dict

    def to_dict(self) -> dict:
        return {"method": self.method, "n": self.n,
                "sigma_mm": {str(k): float(v) for k, v in self.sigma_mm.items()}}


def _needed(n) -> str:
    return "not reached on the grid" if n is None else str(n)


@dataclass(frozen=True, eq=False)
class SequentialResult:
    """A simulated sequential calibration and its comparison.

    Attributes:
        scene: Scene name.
        target_sigma_mm: The target [mm].
        batch, initial: Batch size and initial design size.
        initial_design: ``"heuristic"`` (random feasible poses) or ``"optimal"``
            (the fixed ``criterion``-optimal design of ``initial`` poses at nominal).
        criterion: The design criterion.
        truth_seed, seed: Seeds of the simulated robot and noise, and of the designs.
        steps: One :class:`SequentialStep` per identification.
        q: All measured configurations, (N, nq) [rad], in measurement order.
        p_true, p_estimate: Simulated truth and final estimate, (n_p,) [SI].
        comparison: Fixed designs' :class:`MeasurementsNeeded` (empty if not asked).
        reference: Predicted KPI σ [mm] at the final estimate of the fixed
            ``reference_n``-pose designs, ``{"fixed KPI-optimal": σ, "heuristic": σ}``
            (empty if not asked).
        reference_n: Their size (the paper's 60).
    """

    scene: str
    target_sigma_mm: float
    batch: int
    initial: int
    criterion: str
    truth_seed: int
    seed: int
    steps: tuple[SequentialStep, ...]
    q: np.ndarray
    p_true: np.ndarray
    p_estimate: np.ndarray
    comparison: tuple[MeasurementsNeeded, ...] = ()
    initial_design: str = "heuristic"
    reference: dict = field(default_factory=dict)
    reference_n: int | None = None

    @property
    def n_measurements(self) -> int:
        return self.steps[-1].n_measurements

    @property
    def reached(self) -> bool:
        return bool(self.steps[-1].sigma_mm.max() <= self.target_sigma_mm)

    def check(self) -> list[str]:
        """Inconsistencies of the run (empty if none): counts, feasibility, monotone σ, stopping."""
        problems = []
        sig = [float(s.sigma_mm.max()) for s in self.steps]
        counts = [s.n_measurements for s in self.steps]
        if counts != list(np.cumsum([s.n_added for s in self.steps])) or counts[-1] != len(self.q):
            problems.append(f"measurement counts {counts} do not add up to {len(self.q)} configurations")
        if not all(s.feasible for s in self.steps):
            problems.append("a batch is not feasible")
        for a, b, n in zip(sig[:-1], sig[1:], counts[1:], strict=True):
            if b > a:
                problems.append(f"predicted sigma rose from {a:.6g} to {b:.6g} mm at {n} measurements")
        if any(x <= self.target_sigma_mm for x in sig[:-1]):
            problems.append("the run continued after reaching the target")
        return problems

    def to_dict(self) -> dict:
        return {
            "scene": self.scene, "target_sigma_mm": self.target_sigma_mm, "batch": self.batch,
            "initial": self.initial, "initial_design": self.initial_design, "criterion": self.criterion, "truth_seed": self.truth_seed,
            "seed": self.seed, "reached": self.reached, "n_measurements": self.n_measurements,
            "steps": [s.to_dict() for s in self.steps],
            "measurements_needed": {"sequential": self.n_measurements if self.reached else None,
                                    **{c.method: c.n for c in self.comparison}},
            "comparison": [c.to_dict() for c in self.comparison],
            "reference": {"n": self.reference_n, "sigma_mm": dict(self.reference)},
            "q_rad": self.q.tolist(), "check": self.check(),
        }

    def summary(self) -> str:
        lines = [f"sequential calibration of {self.scene}: target KPI sigma {self.target_sigma_mm:g} mm, "
                 f"initial {self.initial_design} design {self.initial}, batches of {self.batch} ({self.criterion})",
                 f"{'N':>5} {'sigma max [mm]':>15} {'TCP error max [mm]':>19} {'added by':>9}"]
        for s in self.steps:
            lines.append(f"{s.n_measurements:>5} {s.sigma_mm.max():>15.5f} {s.tcp_error_mm.max():>19.5f} "
                         f"{s.method:>9}")
        lines.append(f"measurements to reach sigma <= {self.target_sigma_mm:g} mm:")
        lines.append(f"  sequential          {_needed(self.n_measurements if self.reached else None)}")
        for c in self.comparison:
            lines.append(f"  {c.method:<19} {_needed(c.n)}")
        if self.reference:
            lines.append(f"fixed {self.reference_n}-pose designs at the final estimate: "
                         + ", ".join(f"{k} sigma {v:.5f} mm" for k, v in self.reference.items()))
        problems = self.check()
        if problems:
            lines.append("CHECK FAILED: " + "; ".join(problems))
        return "\n".join(lines)


# ---------------------------------------------------------------- drivers
def measurements_needed(setup: Setup, target_sigma_mm: float, method: str, *,
                        grid: Sequence[int] = DEFAULT_GRID, p=None, seed: int = 0,
                        settings: SQPSettings | None = None) -> MeasurementsNeeded:
    """The smallest ``n`` on ``grid`` (ascending) whose fixed design reaches the target at ``p``.

    ``method``: ``"heuristic"`` (the first n poses of one seeded heuristic
    design, so the sizes are nested) or ``"fixed KPI-optimal"``
    (:func:`calib_oed.oed.design.design`, criterion ``kpi``, heuristic start
    ``seed``, designed at nominal as before any measurement).
    """
    methods = ("heuristic", "fixed KPI-optimal")
    if method not in methods:
        raise SequentialError("method", method, f"must be one of {', '.join(methods)}")
    grid = sorted(int(n) for n in grid)
    if not grid or grid[0] < 1:
        raise SequentialError("grid", grid, "must be a non-empty list of sizes >= 1")
    sigmas = {}
    q_heur = heuristic_design(setup, grid[-1], seed) if method == "heuristic" else None
    for n in grid:
        q = q_heur[:n] if q_heur is not None else optimal_design(setup, n, "kpi", seed=seed, settings=settings,
                                                                 certificate=False).q
        sigmas[n] = float(setup.problem.kpi_sigma(q, p).max() * 1e3)
        if sigmas[n] <= target_sigma_mm:
            return MeasurementsNeeded(method, n, sigmas)
    return MeasurementsNeeded(method, None, sigmas)


def run_sequential(setup: Setup, target_sigma_mm: float, *, batch: int = 5, initial: int = 15,
                   truth_seed: int = 0, max_measurements: int = 120, criterion: str = "kpi",
                   settings: SQPSettings | None = None, seed: int = 0, follow_pose: bool = False,
                   compare: bool = True, grid: Sequence[int] = DEFAULT_GRID,
                   compare_settings: SQPSettings | None = None,
                   callback: Callable[[SequentialStep], None] | None = None,
                   initial_design: str = "heuristic", reference_n: int | None = 60) -> SequentialResult:
    """Sequential calibration of a simulated robot until the predicted KPI σ reaches the target.

    The true robot is the one of
    :func:`calib_oed.calibration.workflow.simulated_measurements` with ``truth_seed``;
    every batch is measured with fresh noise. Step 0 measures the heuristic
    design of ``initial`` poses (``seed``); each step identifies from all
    data so far, stops if the predicted σ at the estimate is at most the
    target or ``max_measurements`` are measured, and otherwise measures the
    next batch proposed at the estimate.

    Args:
        follow_pose: Start each batch's SQP near the last measured pose.
        compare: Also find the sizes a fixed KPI-optimal and the heuristic
            design need (:func:`measurements_needed`, σ at the final
            estimate; the heuristic is the continuation of the initial design).
        compare_settings: SQP settings of the fixed KPI-optimal designs.
        callback: Called with each :class:`SequentialStep` as it is made (progress).
        initial_design: Step 0's design of ``initial`` poses: ``"heuristic"``
            (random feasible poses of ``seed``) or ``"optimal"`` (the
            ``criterion``-optimal design at nominal, SQP with ``compare_settings``
            from the heuristic start of ``seed``).
        reference_n: With ``compare``, also the predicted σ at the final
            estimate of a fixed KPI-optimal and a heuristic design of this
            many poses (None: not computed).
    """
    designer = SequentialDesigner(setup, target_sigma_mm, batch=batch, criterion=criterion,
                                  settings=settings, seed=seed)
    problem, space = setup.problem, setup.problem.space
    free = problem.identifiability.free_indices
    d = sum(m.dim for m in problem.models)
    if int(initial) != initial or initial * d < len(free):
        raise SequentialError("initial", initial, f"must be an integer >= {-(-len(free) // d)} "
                              f"({len(free)} free parameters, {d} values per pose)")
    if max_measurements < initial:
        raise SequentialError("max_measurements", max_measurements, f"must be >= initial = {initial}")
    rng = np.random.default_rng(truth_seed)  # the truth of workflow.simulated_measurements
    p_true = draw_true_parameters(space, free, rng)
    if initial_design not in INITIAL_DESIGNS:
        raise SequentialError("initial_design", initial_design, f"must be one of {', '.join(INITIAL_DESIGNS)}")
    q_all = (heuristic_design(setup, int(initial), seed) if initial_design == "heuristic" else
             np.array(optimal_design(setup, int(initial), criterion, seed=seed, settings=compare_settings,
                                     certificate=False).q))
    blocks = simulate_observations(space, problem.models, q_all, p_true, rng)
    added, method, feasible, seconds = len(q_all), "initial", True, 0.0
    steps = []
    while True:
        p_hat = np.asarray(identify(space, blocks, problem.identifiability).p)
        sigma = designer.predicted_sigma_mm(q_all, p_hat)
        error = np.linalg.norm(tcp_errors(setup, p_true, p_hat, problem.kpi.frame), axis=1) * 1e3
        steps.append(SequentialStep(len(q_all), sigma, error, added, method, feasible, seconds))
        if callback is not None:
            callback(steps[-1])
        if sigma.max() <= designer.target_sigma_mm or len(q_all) >= max_measurements:
            break
        prop = designer.plan(q_all, p_hat, q_all[-1] if follow_pose else None,
                             k=min(designer.batch, max_measurements - len(q_all)))
        feasible = bool(setup.feasibility.compute(prop.q, jacobian=False).feasible.all())
        added, method, seconds = len(prop.q), prop.method, prop.seconds
        blocks = blocks + simulate_observations(space, problem.models, prop.q, p_true, rng)
        q_all = np.vstack([q_all, prop.q])
    comparison = ()
    if compare:
        comparison = tuple(
            measurements_needed(setup, target_sigma_mm, m, grid=grid, p=p_hat, seed=seed,
                                settings=compare_settings)
            for m in ("fixed KPI-optimal", "heuristic"))
    reference = {}
    if compare and reference_n:
        fixed = {"fixed KPI-optimal": optimal_design(setup, int(reference_n), "kpi", seed=seed,
                                                     settings=compare_settings, certificate=False).q,
                 "heuristic": heuristic_design(setup, int(reference_n), seed)}
        reference = {k: float(problem.kpi_sigma(q, p_hat).max() * 1e3) for k, q in fixed.items()}
    q_all.setflags(write=False)
    return SequentialResult(setup.scene.name, float(target_sigma_mm), int(batch), int(initial),
                            criterion, int(truth_seed), int(seed), tuple(steps), q_all, p_true,
                            p_hat, comparison, initial_design, reference,
                            int(reference_n) if reference else None)
