r"""Sequential (online) calibration to a precision target (the paper's outlook, §4).

After :math:`N` measured configurations :math:`q_1..q_N` and the current
estimate :math:`\hat p`, the next batch of :math:`k` configurations solves the
design problem (24a)–(24e) with the information already measured as a fixed
prior, evaluated at :math:`\hat p`:

.. math::
    \min_{x_1..x_k}\ \Phi\Big(M_0 + \sum_{j=1}^{k}\tilde F_j^\top(\hat p, x_j)\,\tilde F_j(\hat p, x_j)\Big),
    \qquad M_0 = \sum_{i=1}^{N}\tilde F_i^\top(\hat p, q_i)\,\tilde F_i(\hat p, q_i),

subject to every feasibility row and the joint limits with their margins
(:class:`~calib_oed.oed.objective.DesignObjective` with ``p`` and
``prior``, :class:`~calib_oed.oed.problem.DesignProblem`,
:func:`~calib_oed.solver.sqp.solve_sqp`). The SQP starts from the exchange
algorithm's best ``k`` of a feasible candidate pool (random feasible poses, or
feasible poses near the robot's current pose when one is given), so the
proposal is never worse than the best pool batch; if the SQP's last iterate is
worse or not feasible, the start is returned.

The calibration stops when the predicted KPI standard deviation
:math:`\sigma_i = \sqrt{\mathrm{tr}(C_{s,ii})/3}` [mm] at every working
configuration :math:`i` is at most the target (:meth:`SequentialDesigner.done`).

This module owns :class:`SequentialDesigner`, the step-by-step API a cell
controller calls, and its :class:`Proposal`;
:func:`calib_oed.oed.sequential_run.run_sequential` runs it against a simulated
robot (identify, propose, measure, repeat) and compares the number of
measurements with a fixed KPI-optimal design and the heuristic design
(:func:`calib_oed.oed.sequential_run.measurements_needed`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from calib_oed.calibration.workflow import Setup
from calib_oed.exceptions import SequentialError
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed.criteria import CRITERIA
from calib_oed.oed.design import optimise_from
from calib_oed.oed.exchange import exchange_design
from calib_oed.oed.objective import DesignObjective
from calib_oed.solver.sqp import SQPSettings

#: SQP settings of one batch (a few poses on top of a prior: short runs suffice).
SEQUENTIAL_SQP = SQPSettings(max_iterations=40)


@dataclass(frozen=True, eq=False)
class Proposal:
    """One proposed batch.

    Attributes:
        q: The batch, (k, nq) [rad], feasible.
        value: Criterion of measured poses plus the batch at the estimate (``kpi``: mm²).
        start_value: The same for the exchange start of the SQP.
        method: ``"sqp"`` or ``"exchange"`` (the SQP did not improve on its start).
        solver: Status and iterations of the SQP.
        seconds: Wall time [s].
    """

    q: np.ndarray
    value: float
    start_value: float
    method: str
    solver: dict
    seconds: float


#: Feasible candidates the exchange start of a proposal chooses from.
POOL = 300
#: Half-width [rad] of the box around the current pose the near candidates are drawn from.
NEIGHBOURHOOD_RAD = 0.5


class SequentialDesigner:
    """Chooses the next batch of measurement configurations, step by step.

    Args:
        setup: The scene's problem and feasibility model.
        target_sigma_mm: Stop when every working configuration's predicted
            KPI σ is at most this [mm], > 0.
        batch: Poses per proposal, >= 1.
        criterion: A name of :data:`calib_oed.oed.criteria.CRITERIA` (default the
            paper's ``kpi``).
        settings: SQP settings of a batch (default :data:`SEQUENTIAL_SQP`).
        seed: Seed of the candidate pools (proposal ``m`` uses ``seed + m``).
    """

    def __init__(self, setup: Setup, target_sigma_mm: float, *, batch: int = 5,
                 criterion: str = "kpi", settings: SQPSettings | None = None, seed: int = 0):
        if not (np.isfinite(target_sigma_mm) and target_sigma_mm > 0):
            raise SequentialError("target_sigma_mm", target_sigma_mm, "must be finite and > 0 [mm]")
        if int(batch) != batch or batch < 1:
            raise SequentialError("batch", batch, "must be an integer >= 1")
        if criterion not in CRITERIA:
            raise SequentialError("criterion", criterion, f"must be one of {', '.join(CRITERIA)}")
        if batch > POOL:
            raise SequentialError("batch", batch, f"must be at most the candidate pool, {POOL}")
        self.setup = setup
        self.problem = setup.problem
        self.target_sigma_mm = float(target_sigma_mm)
        self.batch = int(batch)
        self.criterion = criterion
        self.settings = settings or SEQUENTIAL_SQP
        self.seed = int(seed)
        self.n_proposals = 0

    # ------------------------------------------------------------ prediction
    def _measured(self, q) -> np.ndarray:
        nq = self.problem.robot.nq
        q = np.zeros((0, nq)) if q is None else np.asarray(q, dtype=float).reshape(-1, nq)
        return self.problem.robot.check_configurations(q, "measured configurations") if len(q) else q

    def prior_information(self, q_measured, p_estimate=None) -> np.ndarray | None:
        r""":math:`M_0` of the measured configurations at the estimate, (n_f, n_f); None if none."""
        q = self._measured(q_measured)
        if not len(q):
            return None
        blocks = DesignObjective(self.problem, self.criterion, p=p_estimate).compute_blocks(q)
        flat = blocks.reshape(-1, blocks.shape[-1])
        return flat.T @ flat

    def objective(self, q_measured, p_estimate=None) -> DesignObjective:
        """The criterion of a new batch, with the measured configurations as prior, at the estimate."""
        return DesignObjective(self.problem, self.criterion, p=p_estimate,
                               prior=self.prior_information(q_measured, p_estimate))

    def predicted_sigma_mm(self, q_all, p_estimate=None) -> np.ndarray:
        r"""Predicted KPI σ per working configuration, :math:`\sqrt{\mathrm{tr}(C_{s,i})/3}`, (t,) [mm]."""
        return self.problem.kpi_sigma(self._measured(q_all), p_estimate) * 1e3

    def done(self, q_all, p_estimate=None) -> bool:
        """Whether every working configuration's predicted σ is at most the target."""
        return bool(self.predicted_sigma_mm(q_all, p_estimate).max() <= self.target_sigma_mm)

    # ------------------------------------------------------------ candidates
    def near_candidates(self, pose, n: int, rng) -> np.ndarray:
        """Up to ``n`` feasible configurations uniform in a box of :data:`NEIGHBOURHOOD_RAD` around ``pose``."""
        feas = self.setup.feasibility
        robot = feas.robot
        pose = robot.check_configurations(np.atleast_2d(pose), "current pose")[0]
        margin = feas.settings.margins.joint
        lo = np.maximum(robot.lower + margin, pose - NEIGHBOURHOOD_RAD)
        hi = np.minimum(robot.upper - margin, pose + NEIGHBOURHOOD_RAD)
        hi = np.maximum(hi, lo)
        found, count = [], 0
        for _ in range(20):
            q = rng.uniform(lo, hi, size=(4096, robot.nq))
            states = compute_body_states(robot.model, q, jacobian=False)
            cheap = feas.compute_from_states(q, states, jacobian=False, kinds=("joint", "incidence"))
            idx = np.flatnonzero(cheap.feasible)
            if idx.size:
                full = feas.compute_from_states(q[idx], states.take(idx), jacobian=False)
                found.append(q[idx[full.feasible]])
                count += int(full.feasible.sum())
            if count >= n:
                break
        return np.concatenate(found)[:n] if found else np.zeros((0, robot.nq))

    def candidates(self, current_pose=None, rng=None) -> np.ndarray:
        """The start pool: near the current pose if given (topped up uniformly), else uniform feasible."""
        rng = np.random.default_rng(rng)
        near = (self.near_candidates(current_pose, POOL, rng) if current_pose is not None
                else np.zeros((0, self.problem.robot.nq)))
        if len(near) >= max(2 * self.batch, POOL // 2):
            return near
        uniform = sample_feasible(self.setup.feasibility, POOL - len(near), rng)
        return np.vstack([near, uniform])

    # ------------------------------------------------------------ proposal
    def plan(self, q_measured, p_estimate=None, current_pose=None, k: int | None = None) -> Proposal:
        """The next batch with its record (see :meth:`propose`)."""
        t0 = time.perf_counter()
        k = self.batch if k is None else k
        if int(k) != k or k < 1:
            raise SequentialError("k", k, "must be an integer >= 1")
        k = int(k)
        q_measured = self._measured(q_measured)
        objective = self.objective(q_measured, p_estimate)
        d = sum(m.dim for m in self.problem.models)
        if objective.prior is None and k * d < objective.n_free:
            raise SequentialError("k", k, f"without measured configurations a batch needs at least "
                                  f"{-(-objective.n_free // d)} poses for {objective.n_free} free parameters")
        seed = self.seed + self.n_proposals
        self.n_proposals += 1
        pool = self.candidates(current_pose, seed)
        with threadpool_limits(limits=1):
            start = exchange_design(objective.compute_blocks(pool), k, objective.criterion,
                                    rng=seed, prior=objective.prior)
            q0 = pool[np.asarray(start.indices)]
            value, q, phi0, result = optimise_from(objective, self.setup.feasibility, q0,
                                                   settings=self.settings)
        feasible = bool(self.setup.feasibility.compute(q, jacobian=False).feasible.all())
        method = "sqp"
        if not feasible or not value <= phi0:
            q, value, method = q0, phi0, "exchange"
        q.setflags(write=False)
        solver = {"status": result.status.name.lower() if hasattr(result.status, "name")
                  else str(result.status), "iterations": int(result.iterations)}
        return Proposal(q, float(value), float(phi0), method, solver, time.perf_counter() - t0)

    def propose(self, q_measured, p_estimate=None, current_pose=None, k: int | None = None) -> np.ndarray:
        """The next batch of ``k`` (default ``batch``) feasible configurations, (k, nq) [rad].

        Args:
            q_measured: Configurations measured so far, (N, nq) [rad] (N may be 0).
            p_estimate: Current estimate (n_p,) [SI]; None: nominal.
            current_pose: The robot's configuration now (nq,) [rad]: the SQP
                starts from poses near it.
            k: Batch size (default ``batch``).
        """
        return self.plan(q_measured, p_estimate, current_pose, k).q

