r"""Monte Carlo validation of the predicted KPI covariance.

Repeats :func:`calib_oed.calibration.simulation.simulate_calibration` N times and compares,
per working configuration :math:`i`, the empirical mean squared TCP error after
calibration with the prediction :math:`C_{s,i}` (paper §2.1):

- per axis: :math:`\overline{e_{i,x}^2}` against :math:`(C_{s,i})_{xx}` [mm²];
- ratio :math:`\overline{\lVert e_i\rVert^2} / \mathrm{tr}(C_{s,i})` (1 if the
  prediction is right; its standard error is printed);
- coverage of the :math:`1-\alpha` ellipsoid: the fraction of runs with
  :math:`e_i^\top C_{s,i}^{-1} e_i \le \chi^2_3(1-\alpha)` (paper eq. 8).

Each run draws its own truth and noise from ``SeedSequence(seed).spawn(N)``,
so results do not depend on how runs are spread over workers (joblib).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.stats
from joblib import Parallel, delayed
from tqdm import tqdm

from calib_oed.calibration.simulation import simulate_calibration


@dataclass(frozen=True, eq=False)
class MonteCarloResult:
    """Predicted against simulated KPI errors.

    Attributes:
        names: Working configuration names (t,).
        n_runs: Number of simulated calibrations.
        seed: The seed.
        level: Confidence level of the coverage check.
        predicted: :math:`C_s` blocks, (t, 3, 3) [m²].
        errors_before: KPI errors of the nominal model, (N, t, 3) [m].
        errors_after: KPI errors after calibration, (N, t, 3) [m].
        converged: Per run, whether the estimator converged (N,).
        wall_time: Seconds.
        n_jobs: Workers used.
    """

    names: tuple[str, ...]
    n_runs: int
    seed: int
    level: float
    predicted: np.ndarray
    errors_before: np.ndarray
    errors_after: np.ndarray
    converged: np.ndarray
    wall_time: float
    n_jobs: int

    @property
    def predicted_axis_msq(self) -> np.ndarray:
        """Predicted mean squared error per axis, (t, 3) [m²]."""
        return np.diagonal(self.predicted, axis1=1, axis2=2).copy()

    @property
    def empirical_axis_msq(self) -> np.ndarray:
        """Simulated mean squared error per axis after calibration, (t, 3) [m²]."""
        return np.mean(self.errors_after**2, axis=0)

    @property
    def ratio(self) -> np.ndarray:
        """Mean squared error / :math:`\\mathrm{tr}(C_s)`, per working configuration (t,)."""
        return np.mean(np.sum(self.errors_after**2, axis=2), axis=0) / np.trace(self.predicted, axis1=1, axis2=2)

    @property
    def ratio_standard_error(self) -> np.ndarray:
        """Standard error of :attr:`ratio` from the spread of the runs, (t,)."""
        sq = np.sum(self.errors_after**2, axis=2)
        return sq.std(axis=0, ddof=1) / np.sqrt(self.n_runs) / np.trace(self.predicted, axis1=1, axis2=2)

    @property
    def mahalanobis_squared(self) -> np.ndarray:
        """:math:`e^\\top C_s^{-1} e` per run and working configuration, (N, t)."""
        inv = np.linalg.inv(self.predicted)
        return np.einsum("nti,tij,ntj->nt", self.errors_after, inv, self.errors_after)

    @property
    def coverage(self) -> np.ndarray:
        """Fraction of runs inside the ``level`` ellipsoid, per working configuration (t,)."""
        bound = scipy.stats.chi2.ppf(self.level, 3)
        return np.mean(self.mahalanobis_squared <= bound, axis=0)

    @property
    def rms_before(self) -> np.ndarray:
        """RMS TCP error (3-D norm) of the nominal model, (t,) [m]."""
        return np.sqrt(np.mean(np.sum(self.errors_before**2, axis=2), axis=0))

    @property
    def rms_after(self) -> np.ndarray:
        """RMS TCP error (3-D norm) after calibration, (t,) [m]."""
        return np.sqrt(np.mean(np.sum(self.errors_after**2, axis=2), axis=0))

    @property
    def predicted_rms(self) -> np.ndarray:
        """Predicted RMS TCP error :math:`\\sqrt{\\mathrm{tr}(C_s)}`, (t,) [m]."""
        return np.sqrt(np.trace(self.predicted, axis1=1, axis2=2))

    def to_dict(self) -> dict:
        return {
            "n_runs": self.n_runs, "seed": self.seed, "level": self.level, "n_jobs": self.n_jobs,
            "wall_time_s": self.wall_time, "converged": int(self.converged.sum()),
            "working_configurations": [
                {
                    "name": name,
                    "rms_before_mm": float(self.rms_before[i] * 1e3),
                    "rms_after_mm": float(self.rms_after[i] * 1e3),
                    "predicted_rms_mm": float(self.predicted_rms[i] * 1e3),
                    "predicted_sigma_mm": float(self.predicted_rms[i] * 1e3 / np.sqrt(3)),
                    "predicted_axis_msq_mm2": (self.predicted_axis_msq[i] * 1e6).tolist(),
                    "empirical_axis_msq_mm2": (self.empirical_axis_msq[i] * 1e6).tolist(),
                    "ratio": float(self.ratio[i]),
                    "ratio_standard_error": float(self.ratio_standard_error[i]),
                    "coverage": float(self.coverage[i]),
                }
                for i, name in enumerate(self.names)
            ],
        }

    def summary(self) -> str:
        lines = [f"Monte Carlo: {self.n_runs} simulated calibrations (seed {self.seed}, "
                 f"{self.n_jobs} worker(s), {self.wall_time:.1f} s); "
                 f"{int(self.converged.sum())} converged"]
        for i, name in enumerate(self.names):
            lines += [
                f"  {name}:",
                f"    TCP RMS error before calibration   {self.rms_before[i] * 1e3:9.4f} mm",
                f"    TCP RMS error after calibration    {self.rms_after[i] * 1e3:9.4f} mm",
                f"    predicted sqrt(tr C_s)              {self.predicted_rms[i] * 1e3:9.4f} mm"
                f"  (sigma per axis {self.predicted_rms[i] * 1e3 / np.sqrt(3):.4f} mm)",
                "    mean squared error per axis x,y,z  "
                + "  ".join(f"{v * 1e6:.3e}" for v in self.empirical_axis_msq[i]) + " mm²",
                "    predicted diag(C_s)                "
                + "  ".join(f"{v * 1e6:.3e}" for v in self.predicted_axis_msq[i]) + " mm²",
                f"    ratio empirical/predicted           {self.ratio[i]:.3f} "
                f"± {2 * self.ratio_standard_error[i]:.3f} (2 s.e.)",
                f"    coverage of the {self.level:.0%} ellipsoid        {self.coverage[i]:.3f}",
            ]
        return "\n".join(lines)


def _run_chunk(problem, q, seeds):
    out = []
    for ss in seeds:
        trial = simulate_calibration(problem, q, np.random.default_rng(ss))
        out.append((trial.error_before, trial.error_after, trial.converged))
    return out


def monte_carlo(
    problem,
    q: np.ndarray,
    n_runs: int = 500,
    seed: int = 0,
    *,
    n_jobs: int = 2,
    level: float = 0.95,
    progress: bool = False,
) -> MonteCarloResult:
    """Simulate ``n_runs`` calibrations at design ``q`` and compare with the predicted :math:`C_s`.

    The true robots: the free parameters normal, 0.5 mm and 0.5 mrad
    (:func:`~calib_oed.calibration.simulation.simulate_calibration`).

    Args:
        problem: A :class:`calib_oed.calibration.problem.CalibrationProblem`.
        q: The design (n, nq) [rad].
        n_runs: Number of simulated calibrations (>= 2).
        seed: Seed of the runs.
        n_jobs: Parallel workers (joblib; 1 runs in this process).
        level: Confidence level of the ellipsoid coverage check.
        progress: Show a progress bar.
    """
    if int(n_runs) < 2:
        raise ValueError(f"n_runs must be >= 2, got {n_runs}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    q = problem.robot.check_configurations(q, "design")
    n_runs, n_jobs = int(n_runs), max(1, int(n_jobs))
    start = time.perf_counter()
    cs = problem.kpi_covariance(q)
    t = len(problem.kpi.names)
    predicted = np.array([cs[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(t)])
    seeds = np.random.SeedSequence(seed).spawn(n_runs)
    n_chunks = min(n_runs, 4 * n_jobs if n_jobs > 1 else max(1, n_runs // 25))
    chunks = [c for c in np.array_split(np.arange(n_runs), n_chunks) if c.size]
    if n_jobs == 1:
        results = (_run_chunk(problem, q, [seeds[i] for i in c]) for c in chunks)
    else:
        results = Parallel(n_jobs=n_jobs, return_as="generator")(
            delayed(_run_chunk)(problem, q, [seeds[i] for i in c]) for c in chunks
        )
    runs = []
    for chunk in tqdm(results, total=len(chunks), disable=not progress, desc="Monte Carlo", unit="chunk"):
        runs.extend(chunk)
    before = np.array([r[0] for r in runs])
    after = np.array([r[1] for r in runs])
    converged = np.array([r[2] for r in runs])
    return MonteCarloResult(tuple(problem.kpi.names), n_runs, int(seed), float(level), predicted,
                            before, after, converged, time.perf_counter() - start, n_jobs)
