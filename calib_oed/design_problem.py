r"""The OED problem (paper eq. 24a–24e) as a nonlinear program in :math:`x = \mathrm{vec}(q)`.

.. math::
    \min_{q_1..q_n}\; \phi(q)/|\phi(q^0)| \quad\text{s.t.}\quad
    g(q_j) \ge 0,\quad q^{\min} + m_q \le q_j \le q^{\max} - m_q,\quad j = 1..n,

with :math:`\phi` a :class:`~calib_oed.design_objective.DesignObjective`
(divided by its value at the start so the solver sees O(1) numbers), and
:math:`g` the incidence, self-collision, obstacle and beam rows of the scene's
:class:`~calib_oed.feasibility.constraints.FeasibilityModel` (values in m and
cosine units, exact gradients). Joint limits with their margin :math:`m_q` are
simple bounds. Without collision constraints only the incidence rows remain
(the paper's comparison of designs optimised with and without them).

The Jacobian of :math:`g` is block diagonal (pose ``j``'s rows depend on
:math:`q_j` only) and returned sparse.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from calib_oed.design_objective import DesignObjective
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.constraints import FeasibilityModel

#: Constraint kinds of the design problem, with and without collision avoidance.
COLLISION_KINDS = ("incidence", "self", "obstacle", "beam")
NO_COLLISION_KINDS = ("incidence",)


class DesignProblem:
    """Objective, constraints and bounds of an n-pose design, for :func:`calib_oed.sqp.solve_sqp`.

    Args:
        objective: The criterion as a function of the design.
        feasibility: The scene's constraints.
        n: Number of poses.
        collisions: Include the capsule and beam rows (default) or only incidence.
        scale: The objective is divided by this (use the start's value).
    """

    def __init__(
        self,
        objective: DesignObjective,
        feasibility: FeasibilityModel,
        n: int,
        *,
        collisions: bool = True,
        scale: float = 1.0,
    ):
        if not np.isfinite(scale) or scale <= 0:
            raise ValueError(f"objective scale must be finite and > 0, got {scale}")
        self.objective = objective
        self.feasibility = feasibility
        self.n = int(n)
        self.nq = feasibility.robot.nq
        self.kinds = COLLISION_KINDS if collisions else NO_COLLISION_KINDS
        self.scale = float(scale)
        robot = feasibility.robot
        margin = feasibility.settings.margins.joint
        self.lower = np.tile(robot.lower + margin, self.n)
        self.upper = np.tile(robot.upper - margin, self.n)
        self.n_objective = 0
        self.n_constraints = 0

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint limits with their safety margin, each (n·nq,) [rad]."""
        return self.lower, self.upper

    def configurations(self, x: np.ndarray) -> np.ndarray:
        """The design (n, nq) of a variable vector (n·nq,)."""
        return np.asarray(x, dtype=float).reshape(self.n, self.nq)

    def compute_objective(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        r""":math:`\phi/\phi^0` and its gradient (n·nq,)."""
        self.n_objective += 1
        ev = self.objective.compute(self.configurations(x))
        return ev.value / self.scale, ev.gradient.ravel() / self.scale

    def compute_curvature(self, x: np.ndarray) -> np.ndarray | None:
        """The objective's exact curvature through M (scaled like the objective), or None.

        See :meth:`calib_oed.design_objective.DesignObjective.compute_curvature`.
        """
        h = self.objective.compute_curvature(self.configurations(x))
        return None if h is None else h / self.scale

    def compute_constraint_rows(self, x: np.ndarray, jacobian: bool = True):
        """Constraint values (n, m) and Jacobian (n, m, nq) or None."""
        q = self.configurations(x)
        states = compute_body_states(self.feasibility.robot.model, q, jacobian=jacobian)
        res = self.feasibility.compute_from_states(q, states, jacobian, kinds=self.kinds)
        return res.values, res.jacobian

    def compute_constraints(self, x: np.ndarray) -> tuple[np.ndarray, scipy.sparse.csr_matrix]:
        """Stacked values :math:`g` (n·m,) and the block-diagonal Jacobian (n·m, n·nq), CSR."""
        self.n_constraints += 1
        values, jac = self.compute_constraint_rows(x, jacobian=True)
        n, m, nq = jac.shape
        bsr = scipy.sparse.bsr_matrix((jac, np.arange(n), np.arange(n + 1)), shape=(n * m, n * nq))
        return values.ravel(), bsr.tocsr()

    def constraint_labels(self) -> list[str]:
        """Label of each stacked row, ``"pose j: <row label>"``."""
        rows = [lbl for k, lbl in zip(self.feasibility.kinds, self.feasibility.labels, strict=True)
                if k in self.kinds]
        return [f"pose {j}: {lbl}" for j in range(self.n) for lbl in rows]

    def max_violation(self, x: np.ndarray) -> float:
        """Largest violation of the constraints and bounds (>= 0) [m, rad, cos]."""
        values, _ = self.compute_constraint_rows(x, jacobian=False)
        x = np.asarray(x, dtype=float)
        return float(max(0.0, -values.min(), (self.lower - x).max(), (x - self.upper).max()))
