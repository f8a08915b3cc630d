r"""The OED problem (paper eq. 24a–24e) as a nonlinear program in :math:`x = \mathrm{vec}(q)`.

.. math::
    \min_{q_1..q_n}\; \phi(q)/|\phi(q^0)| \quad\text{s.t.}\quad
    g(q_j) \ge 0,\quad q^{\min} + m_q \le q_j \le q^{\max} - m_q,\quad j = 1..n,

with :math:`\phi` a :class:`~calib_oed.oed.objective.DesignObjective`
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

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.constraints import FeasibilityModel
from calib_oed.feasibility.hull_pieces import hull_row_pieces
from calib_oed.feasibility.hull_rows import HullRows
from calib_oed.oed.objective import DesignObjective
from calib_oed.solver.result import StructuredHessian

#: Constraint kinds of the design problem, with and without collision avoidance.
COLLISION_KINDS = ("incidence", "self", "obstacle", "beam")
NO_COLLISION_KINDS = ("incidence",)


class DesignProblem:
    """Objective, constraints and bounds of an n-pose design, for :func:`calib_oed.solver.sqp.solve_sqp`.

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
        self.n_values = 0
        self._states: list[tuple[bytes, object]] = []  # the last body states with Jacobians, by q

    def _body_states(self, q: np.ndarray, compute: bool = True):
        """Body states with Jacobians of ``q`` (n, nq): those of the last two designs evaluated when
        ``q`` is one of them, bit for bit (an accepted trial point's curvature and row pieces),
        else computed (``compute``) or ``None``."""
        key = np.ascontiguousarray(q).tobytes()
        for k, states in self._states:
            if k == key:
                return states
        if not compute:
            return None
        states = compute_body_states(self.feasibility.robot.model, q, jacobian=True)
        self._states = [(key, states), *self._states[:1]]
        return states

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

    def compute_values(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        r""":math:`\phi/\phi^0` and the stacked constraint values (n·m,) without derivatives: the
        SQP's trial points (``values`` of :func:`~calib_oed.solver.sqp.solve_sqp`)."""
        self.n_values += 1
        value = self.objective.compute_value(self.configurations(x)) / self.scale
        return value, self.compute_constraint_rows(x, jacobian=False)[0].ravel()

    def compute_lagrangian_hessian(self, x: np.ndarray, lam: np.ndarray) -> StructuredHessian | None:
        r"""The exact Hessian of :math:`L = \phi/s - \lambda^\top g` in factored form, or None.

        Per pose :math:`j` the block
        :math:`\partial^2\phi/\partial q_j^2|_{\text{rows}}/s - \sum_i \lambda_{ji}\nabla^2 g_{ji}`
        (the criterion's curvature through pose j's rows, derivations §13, and
        the constraint curvature of :meth:`~calib_oed.feasibility.constraints.FeasibilityModel.compute_lagrangian_hessian`),
        plus the exact coupling through :math:`M^{-1}` as :math:`U U^\top / s`.
        None when the criterion has no exact Hessian (E, O1..O5, joint compliance).

        Args:
            x: The design (n·nq,) [rad].
            lam: Multipliers of the stacked rows (n·m,), >= 0, in the order of
                :meth:`compute_constraints`.
        """
        q = self.configurations(x)
        obj = self.objective.compute_hessian(q)
        if obj is None:
            return None
        blocks = obj.blocks / self.scale
        curvature = self.compute_constraint_curvature(x, lam)
        if curvature is not None:
            blocks = blocks - curvature
        low = None if obj.low_rank is None else obj.low_rank / np.sqrt(self.scale)
        return StructuredHessian(blocks, low)

    def compute_constraint_curvature(self, x: np.ndarray, lam: np.ndarray) -> np.ndarray | None:
        r""":math:`\sum_i \lambda_{ji}\nabla^2 g_{ji}` per pose, (n, nq, nq), or None when every :math:`\lambda = 0`.

        Args:
            x: The design (n·nq,) [rad].
            lam: Multipliers of the stacked rows (n·m,), >= 0, in the order of
                :meth:`compute_constraints` (units of the objective per row unit).
        """
        lam = np.asarray(lam, dtype=float)
        if not (lam.size and np.any(lam)):
            return None
        q = self.configurations(x)
        return self.feasibility.compute_lagrangian_hessian(
            q, lam.reshape(self.n, -1), kinds=self.kinds, states=self._body_states(q, compute=False))

    def compute_constraint_rows(self, x: np.ndarray, jacobian: bool = True):
        """Constraint values (n, m) and Jacobian (n, m, nq) or None."""
        q = self.configurations(x)
        states = self._body_states(q) if jacobian else compute_body_states(self.feasibility.robot.model, q,
                                                                           jacobian=False)
        res = self.feasibility.compute_from_states(q, states, jacobian, kinds=self.kinds)
        return res.values, res.jacobian

    def compute_constraints(self, x: np.ndarray) -> tuple[np.ndarray, scipy.sparse.csr_matrix]:
        """Stacked values :math:`g` (n·m,) and the block-diagonal Jacobian (n·m, n·nq), CSR."""
        self.n_constraints += 1
        values, jac = self.compute_constraint_rows(x, jacobian=True)
        n, m, nq = jac.shape
        bsr = scipy.sparse.bsr_matrix((jac, np.arange(n), np.arange(n + 1)), shape=(n * m, n * nq))
        return values.ravel(), bsr.tocsr()

    def compute_row_pieces(self, x: np.ndarray, rows: np.ndarray):
        """The smooth pieces of kinked convex-piece rows among the stacked ``rows``, for the SQP.

        ``(rows_k, values, G)``: the stacked row of each piece, its value [m] and
        gradient (k, n·nq) (:mod:`calib_oed.feasibility.hull_pieces`,
        :mod:`calib_oed.solver.pieces`).
        """
        family = self.feasibility.family(HullRows)
        none = (np.zeros(0, dtype=int), np.zeros(0), scipy.sparse.csr_matrix((0, self.n * self.nq)))
        if family is None or not len(family) or "self" not in self.kinds:
            return none
        hull = family.hulls
        full = np.flatnonzero(self.feasibility.row_mask(self.kinds))  # design-local -> model row
        m = full.size
        rows = np.asarray(rows, dtype=int)
        first = self.feasibility.row_slice(family).start
        h = full[rows % m] - first
        mine = (h >= 0) & (h < len(hull))
        if not mine.any():
            return none
        poses, at = np.unique(rows[mine] // m, return_inverse=True)
        q = self.configurations(x)
        known = self._body_states(q, compute=False)
        states = known.take(poses) if known is not None else compute_body_states(
            self.feasibility.robot.model, q[poses], jacobian=True)
        pieces = hull_row_pieces(hull, states, at, h[mine], self.feasibility.settings.margins.clearance)
        pose = poses[pieces.pose]
        local = first + pieces.row  # model row -> design-local row
        stacked = pose * m + np.searchsorted(full, local)
        k, nq = pose.size, self.nq
        cols = (pose[:, None] * nq + np.arange(nq)[None]).ravel()
        grads = scipy.sparse.csr_matrix((pieces.jacobian.ravel(), cols, np.arange(0, k * nq + 1, nq)),
                                        shape=(k, self.n * nq))
        return stacked, pieces.values, grads

    def max_violation(self, x: np.ndarray) -> float:
        """Largest violation of the constraints and bounds (>= 0) [m, rad, cos]."""
        values, _ = self.compute_constraint_rows(x, jacobian=False)
        x = np.asarray(x, dtype=float)
        return float(max(0.0, -values.min(), (self.lower - x).max(), (x - self.upper).max()))


class WorstCaseDesignProblem:
    r"""The worst-case (max) KPI design in epigraph form, for :func:`calib_oed.solver.sqp.solve_sqp`.

    With :math:`v_i(q) = \mathrm{tr}(G_i C(q) G_i^\top)/3` the variance of KPI
    point :math:`i` [mm²] (:math:`G_i` its three rows of the unit-scaled KPI
    Jacobian), :math:`\min_q \max_i v_i(q)` is not smooth; its epigraph form is

    .. math::
        \min_{q,\,t}\; t \quad\text{s.t.}\quad t - v_i(q)/s \ge 0\ (i = 1..T),\quad
        g(q_j) \ge 0,\quad q^{\min} + m_q \le q_j \le q^{\max} - m_q,\quad t \ge 0,

    in :math:`x = (\mathrm{vec}(q), t)`, every row smooth, :math:`s` the
    start's :math:`\max_i v_i` (so :math:`t^0 = 1`). The gradient of each
    :math:`v_i` is the A-criterion's on :math:`G_i` (``DesignObjective``:
    :math:`\partial v_i/\partial M = -C G_i^\top G_i C/3`), all points at once:
    with :math:`Y = C G^\top`,
    :math:`\partial v_i/\partial q_{j,k} = -\tfrac23 \sum_{c \in i}
    (\tilde F_j Y_c)\cdot(\partial_k \tilde F_j\, Y_c)`.

    The Jacobian is the feasibility rows' block diagonal with a zero
    :math:`t` column, plus :math:`T` dense epigraph rows; CSR. The extra
    variable does not fit per-pose Hessian blocks: the SQP uses one dense
    BFGS matrix (``block_size=None``).

    Args:
        objective: Any :class:`DesignObjective` of the problem (its rows and
            KPI Jacobian are used; its criterion is not).
        feasibility: The scene's constraints.
        n: Number of poses.
        collisions: As :class:`DesignProblem`.
        scale: :math:`s` [mm²], > 0.
    """

    def __init__(self, objective: DesignObjective, feasibility: FeasibilityModel, n: int, *,
                 collisions: bool = True, scale: float = 1.0):
        self.base = DesignProblem(objective, feasibility, n, collisions=collisions, scale=scale)
        self.objective = objective
        self.kpi_jacobian = objective.kpi_jacobian()  # (3T, n_f)
        self.n_points = self.kpi_jacobian.shape[0] // 3
        self.n, self.nq, self.scale = self.base.n, self.base.nq, self.base.scale
        self.lower = np.append(self.base.lower, 0.0)
        self.upper = np.append(self.base.upper, np.inf)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint limits with their margin [rad], and :math:`t \\ge 0`; each (n·nq + 1,)."""
        return self.lower, self.upper

    def configurations(self, x: np.ndarray) -> np.ndarray:
        """The design (n, nq) of a variable vector (n·nq + 1,)."""
        return self.base.configurations(np.asarray(x, dtype=float)[:-1])

    def start(self, q0: np.ndarray) -> np.ndarray:
        """:math:`x^0 = (\\mathrm{vec}(q^0), \\max_i v_i(q^0)/s)`: feasible for the epigraph rows."""
        v, _ = self.compute_point_variances(q0, gradient=False)
        return np.append(np.asarray(q0, dtype=float).ravel(), v.max() / self.scale)

    def compute_point_variances(self, q: np.ndarray, gradient: bool = True):
        r""":math:`v_i(q)` [mm²] (T,) and, if asked, :math:`\partial v_i/\partial q` (T, n, nv)."""
        obj = self.objective
        g = self.kpi_jacobian
        if not gradient:
            return obj.kpi_point_variances(q), None
        rows, d_rows, info = obj._first_order(q)
        y = np.linalg.solve(info, g.T)  # C G^T (n_f, 3T)
        v = np.sum(g.T * y, axis=0).reshape(-1, 3).sum(axis=1) / 3.0
        a = rows @ y  # (n, d, 3T)
        b = np.einsum("jdfk,fc->jdkc", d_rows, y)  # (n, d, nv, 3T)
        dv = np.einsum("jdc,jdkc->cjk", a, b)  # (3T, n, nv)
        dv = -2.0 / 3.0 * dv.reshape(self.n_points, 3, *dv.shape[1:]).sum(axis=1)
        return v, dv

    def compute_objective(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """:math:`t` and its gradient :math:`e_t`."""
        grad = np.zeros(np.size(x))
        grad[-1] = 1.0
        return float(x[-1]), grad

    def compute_constraints(self, x: np.ndarray) -> tuple[np.ndarray, scipy.sparse.csr_matrix]:
        """Feasibility rows then epigraph rows :math:`t - v_i/s`, and their Jacobian (CSR)."""
        x = np.asarray(x, dtype=float)
        c_f, a_f = self.base.compute_constraints(x[:-1])
        v, dv = self.compute_point_variances(self.configurations(x))
        c_e = x[-1] - v / self.scale
        a_e = np.hstack([-dv.reshape(self.n_points, -1) / self.scale, np.ones((self.n_points, 1))])
        jac = scipy.sparse.vstack([
            scipy.sparse.hstack([a_f, scipy.sparse.csr_matrix((a_f.shape[0], 1))]),
            scipy.sparse.csr_matrix(a_e),
        ]).tocsr()
        return np.concatenate([c_f, c_e]), jac

    def max_violation(self, x: np.ndarray) -> float:
        """Largest violation of the feasibility rows and joint bounds (the epigraph rows excluded)."""
        return self.base.max_violation(np.asarray(x, dtype=float)[:-1])
