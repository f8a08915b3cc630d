r"""A design criterion as a function of the measurement configurations, with its exact gradient.

For a design :math:`q = (q_1, \dots, q_n)`, :math:`q_j \in \mathbb{R}^{n_v}`,
each pose contributes the rows

.. math::
    \tilde F_j(q_j) = \Sigma^{-1}\,\frac{\partial h}{\partial p_f}(p, q_j)\,D
    \in \mathbb{R}^{d \times n_f}

(:math:`\Sigma = \mathrm{diag}(\sigma)`; a model with a full error model,
``mdl.noise``, uses :math:`W(y_j) = \Sigma_j(q_j)^{-1/2}` in place of
:math:`\Sigma^{-1}`, and its q-derivatives include those of :math:`W`:
:mod:`calib_oed.oed.whitening`; models without it take the isotropic code
path unchanged)

of the weighted sensitivity on the free parameters :math:`p_f` (gauge rule),
unit-scaled by :math:`D = \mathrm{diag}(u_f)` so that parameters are in mm
and mrad (``ParameterSpace.unit_scale``). The information matrix and the
objective are

.. math::
    M(q) = M_0 + \sum_{j=1}^{n} \tilde F_j^\top \tilde F_j, \qquad
    \phi(q) = \Phi\big(M(q)\big)

with :math:`M_0` an optional prior (measurements already taken) and
:math:`\Phi` a :class:`calib_oed.oed.criterion_base.Criterion`. Because
:math:`\tilde F_j` depends on :math:`q_j` alone,

.. math::
    \frac{\partial\phi}{\partial q_{j,k}}
      = 2\,\mathrm{tr}\Big(\tilde F_j\,\frac{\partial\Phi}{\partial M}\,
        \frac{\partial \tilde F_j^\top}{\partial q_{j,k}}\Big),

and :math:`\partial\tilde F_j/\partial q_{j,k}` is the mixed derivative
:math:`\partial^2 h/\partial p\,\partial q` of the measurement models
(:meth:`calib_oed.measurement.MeasurementModel.compute_param_config_jacobian`),
batched over poses. Derivation: ``docs/derivations.md`` §11. The exact
Hessian for the A and D criteria (:meth:`DesignObjective.compute_hessian`,
per-pose blocks plus a low-rank coupling, :mod:`calib_oed.oed.hessian`) also
needs :math:`\partial^2\tilde F_j/\partial q_j^2`
(``compute_param_config_hessian``); ``docs/derivations.md`` §13.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg

from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.exceptions import NotIdentifiableError, ShapeError
from calib_oed.measurement import evaluate_setup
from calib_oed.oed.criteria import ACriterion, make_criterion
from calib_oed.oed.criterion_base import Criterion
from calib_oed.oed.hessian import has_exact_hessian, structured_hessian
from calib_oed.oed.model_error_hessian import design_hessian
from calib_oed.oed.whitening import (
    NoisePieces,
    whitened_row_derivatives,
    whitened_row_hessians,
    whitened_rows,
    whitening_pieces,
)
from calib_oed.solver.result import StructuredHessian

#: KPI entries of :math:`P`: metres to millimetres.
_MM = 1e3


@dataclass(frozen=True)
class DesignEvaluation:
    """Criterion value and gradient of a design.

    Attributes:
        value: :math:`\\phi(q)` in the criterion's unit.
        gradient: :math:`\\partial\\phi/\\partial q`, (n, nv) [unit/rad].
        information: :math:`M(q)`, (n_f, n_f), unit-scaled.
    """

    value: float
    gradient: np.ndarray
    information: np.ndarray


class RowDerivatives(NamedTuple):
    r"""Per-pose rows :math:`\tilde F_j` and their configuration derivatives (module docstring).

    Attributes:
        rows: :math:`\tilde F_j(q_j)`, (n, d, n_f), pose-major: the d rows of
            every model for pose j; column f in 1/mm or 1/mrad (measured
            values in units of their :math:`\sigma`, per mm or mrad of
            free parameter f).
        derivatives: :math:`\partial\tilde F_j/\partial q_{j,k}`, (n, d, n_f, nv),
            along the nv velocity coordinates of pose j; the rows' unit per
            rad (revolute joints).
    """

    rows: np.ndarray
    derivatives: np.ndarray


class DesignObjective:
    """:math:`\\phi(q) = \\Phi(M(q))` for a calibration problem (see module docstring).

    Args:
        problem: The calibration problem (its gauge rule picks the free parameters).
        criterion: A criterion object, or a name from
            :data:`calib_oed.oed.criteria.CRITERIA` (``"kpi"``: the paper's
            A-criterion on the KPI covariance in mm²; ``"params"``: the
            A-criterion on the parameter covariance in mm²/mrad²).
        p: Parameters the sensitivities are evaluated at (None: nominal).
        prior: Information :math:`M_0` already available, (n_f, n_f).
        model_error: The model-error prior of criterion ``"kpi_model"``
            (:mod:`calib_oed.oed.model_error`; None: the default for the robot's reach).
    """

    def __init__(
        self,
        problem: CalibrationProblem,
        criterion: Criterion | str = "kpi",
        p: np.ndarray | None = None,
        prior: np.ndarray | None = None,
        model_error=None,
    ):
        self.problem = problem
        self.p = problem.space.check(p)
        self.free = problem.identifiability.free_indices
        self.scale = problem.space.unit_scale[self.free]
        nf = len(self.free)
        if isinstance(criterion, str):
            criterion = make_criterion(criterion, kpi_jacobian=self.kpi_jacobian(), n_params=nf,
                                       kpi_weights=self.kpi_weights, problem=problem,
                                       model_error=model_error)
        self.criterion = criterion
        if prior is not None:
            prior = np.asarray(prior, dtype=float)
            if prior.shape != (nf, nf):
                raise ShapeError("prior information", f"({nf}, {nf})", prior.shape)
        self.prior = prior
        if prior is not None and self.needs_design:
            from calib_oed.exceptions import DesignError

            raise DesignError("criterion", criterion.name, "does not take the information of "
                              "measurements already made (a prior); use kpi or params")
        # first-order pieces (and the kinematic state) of the last few designs: the SQP
        # asks for value, gradient and curvature at the same point
        self._cache: dict[bytes, tuple] = {}
        self._noise_memo: dict = {}  # whitening pieces of the last state (:meth:`_whitening`)
        self._row_memo: tuple | None = None  # (key, state, rows) of compute_row_derivatives/_hessians

    @property
    def n_free(self) -> int:
        return len(self.free)

    def kpi_jacobian(self) -> np.ndarray:
        """Unit-scaled KPI Jacobian on the free parameters, (3t, n_f) [mm/mm, mm/mrad]."""
        return self.problem.kpi_jacobian(self.p)[:, self.free] * self.scale * _MM

    @property
    def kpi_weights(self) -> np.ndarray | None:
        """Weights of the KPI points (the scene's), or None (all 1)."""
        return getattr(self.problem.kpi, "weights", None)

    def kpi_point_variances(self, q: np.ndarray) -> np.ndarray:
        r"""Per KPI point :math:`v_i = \mathrm{tr}(G_i C G_i^\top)/3` [mm²], (t,)."""
        info = self.compute_information(q)
        g = self.kpi_jacobian()
        try:  # one factorisation for all points: v_i = sum over the point's rows of g C g^T / 3
            factor = scipy.linalg.cho_factor(info, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            try:  # the criterion names the columns of the null space
                ACriterion.kpi(g).compute_value(info)
            except NotIdentifiableError as exc:
                raise self._named(exc) from None
            raise
        y = scipy.linalg.cho_solve(factor, g.T, check_finite=False)  # C G^T
        return np.sum(g.T * y, axis=0).reshape(-1, 3).sum(axis=1) / 3.0

    # -------------------------------------------------------------- pieces
    def _state(self, q: np.ndarray, second_order: bool):
        q = self.problem.robot.check_configurations(q, "design")
        return evaluate_setup(self.problem.space, self.p, q, regressor=True,
                              jacobian=second_order)

    def _whitening(self, mdl, state, order: int) -> NoisePieces:
        """:func:`calib_oed.oed.whitening.whitening_pieces` of a model with ``mdl.noise``,
        kept for the last state (value, gradient and Hessian of one design share them)."""
        memo = self._noise_memo
        if memo.get("state") is not state:
            memo.clear()
            memo["state"] = state
        done, known = memo.get(id(mdl), (-1, None))
        if done < order:
            memo[id(mdl)] = (order, whitening_pieces(mdl, state, self.free, order, known))
        return memo[id(mdl)][1]

    def _rows(self, state) -> np.ndarray:
        blocks = []
        for mdl in self.problem.models:
            if mdl.noise is None:  # independent components: the closed form
                jac = mdl.compute_param_jacobian(state)[:, :, self.free]
                blocks.append(jac / mdl.sigma[None, :, None])
            else:
                blocks.append(whitened_rows(self._whitening(mdl, state, 0)))
        return np.concatenate(blocks, axis=1) * self.scale  # (n, d, n_f)

    def _row_derivatives(self, state) -> np.ndarray:
        blocks = []
        for mdl in self.problem.models:
            if mdl.noise is None:
                d_jac = mdl.compute_param_config_jacobian(state)[:, :, self.free, :]
                blocks.append(d_jac / mdl.sigma[None, :, None, None])
            else:
                blocks.append(whitened_row_derivatives(self._whitening(mdl, state, 1)))
        return np.concatenate(blocks, axis=1) * self.scale[:, None]  # (n, d, n_f, nv)

    def _row_hessians(self, state) -> np.ndarray | None:
        out, start = None, 0
        for mdl in self.problem.models:
            dd = mdl.compute_param_config_hessian(state)
            if dd is None:
                return None
            if out is None:
                out = np.empty((dd.shape[0], sum(m.dim for m in self.problem.models), len(self.free))
                               + dd.shape[3:])
            rows = slice(start, start + mdl.dim)
            start += mdl.dim
            if mdl.noise is None:
                factor = self.scale[None, :] / mdl.sigma[:, None]  # (d, n_f)
                np.multiply(dd[:, :, self.free], factor[None, :, :, None, None], out=out[:, rows])
            else:
                block = whitened_row_hessians(self._whitening(mdl, state, 2), dd[:, :, self.free])
                out[:, rows] = block * self.scale[None, None, :, None, None]
        return out  # (n, d, n_f, nv, nv)

    def compute_blocks(self, q: np.ndarray) -> np.ndarray:
        r"""Per-pose rows :math:`\tilde F_j`, (n, d, n_f), all models stacked per pose."""
        return self._rows(self._state(q, second_order=False))

    def compute_row_derivatives(self, q: np.ndarray) -> RowDerivatives:
        r"""Per-pose rows :math:`\tilde F_j(q_j)` and :math:`\partial\tilde F_j/\partial q_{j,k}` at ``q``.

        .. math::
            \frac{\partial\tilde F_j}{\partial q_{j,k}}
              = \Sigma^{-1}\,\frac{\partial^2 h}{\partial p_f\,\partial q_{j,k}}(p, q_j)\,D
              \quad\Big(\text{full error model: }
              \big(W\,\partial_k J + \partial_k W\,J\big) D\Big),

        the mixed derivative of the measurement models
        (``compute_param_config_jacobian``), weighted and unit-scaled as the
        rows, all models stacked per pose as in :meth:`compute_blocks`. No
        information matrix is formed, so any number of poses is accepted.

        Args:
            q: Configurations (n, nq) [rad].

        Returns:
            :class:`RowDerivatives`: ``rows`` (n, d, n_f) [1/mm, 1/mrad per
            column] and ``derivatives`` (n, d, n_f, nv) [the same per rad].
        """
        key, state = self._row_state(q)
        if self._row_memo[2] is None:  # kept with the state: the gradient and the Hessian both use them
            kept = RowDerivatives(self._rows(state), self._row_derivatives(state))
            for array in kept:
                array.setflags(write=False)
            self._row_memo = (key, state, kept)
        return self._row_memo[2]

    def compute_row_hessians(self, q: np.ndarray) -> np.ndarray | None:
        r""":math:`\partial^2\tilde F_j/\partial q_{j,k}\,\partial q_{j,l}`, (n, d, n_f, nv, nv), or None.

        The models' ``compute_param_config_hessian``, weighted, unit-scaled
        and stacked as :meth:`compute_row_derivatives`; None when a model
        does not provide it (or with joint compliance modelled).
        """
        return self._row_hessians(self._row_state(q)[1])

    def _row_state(self, q: np.ndarray):
        """``(key, state)``: the second-order state of the last ``q``, kept with its read-only rows once
        asked for: a Newton step's gradient and Hessian at one point evaluate the models once."""
        q = np.asarray(q, dtype=float)
        key = (q.shape, q.tobytes())
        if self._row_memo is None or self._row_memo[0] != key:
            self._row_memo = (key, self._state(q, second_order=True), None)
        return self._row_memo[0], self._row_memo[1]

    def check_design_size(self, n: int) -> None:
        """Refuse ``n`` poses that give fewer measured values than free parameters (no prior),
        before any pose is drawn: each pose gives the rows of one block (here at the joint
        limits' midpoint).

        Raises:
            NotIdentifiableError: naming the smallest ``n`` that can work.
        """
        if self.prior is not None:
            return
        robot = self.problem.robot
        per_pose = self.compute_blocks(0.5 * (robot.lower + robot.upper)[None, :]).shape[1]
        if n * per_pose < self.n_free:
            raise NotIdentifiableError(
                self.free_names,
                f"a design of {n} poses gives {n * per_pose} measured values for {self.n_free} "
                f"free parameters; measure more configurations (at least {-(-self.n_free // per_pose)})")

    def information(self, blocks: np.ndarray) -> np.ndarray:
        """:math:`M = M_0 + \\sum_j \\tilde F_j^\\top \\tilde F_j` from per-pose blocks (n, d, n_f).

        Raises:
            NotIdentifiableError: fewer measured values than free parameters
                (and no prior).
        """
        flat = blocks.reshape(-1, blocks.shape[-1])
        if self.prior is None and flat.shape[0] < flat.shape[1]:
            raise NotIdentifiableError(
                self.free_names,
                f"a design of {blocks.shape[0]} poses gives {flat.shape[0]} measured values for "
                f"{flat.shape[1]} free parameters; measure more configurations",
            )
        info = flat.T @ flat
        return info if self.prior is None else info + self.prior

    @property
    def free_names(self) -> list[str]:
        """Names of the free parameters (the columns of :math:`M`)."""
        return [self.problem.space.names[i] for i in self.free]

    def _named(self, exc: NotIdentifiableError) -> NotIdentifiableError:
        """The criterion's error with parameter names instead of column numbers."""
        names = []
        for label in exc.names:
            parts = str(label).split()
            if len(parts) == 2 and parts[0] == "column" and parts[1].isdigit():
                names.append(self.free_names[int(parts[1])])
            else:
                names.append(str(label))
        return NotIdentifiableError(names, "the design's information matrix is singular on them")

    def compute_information(self, q: np.ndarray) -> np.ndarray:
        """:math:`M(q)`, (n_f, n_f)."""
        return self.information(self.compute_blocks(q))

    @property
    def needs_design(self) -> bool:
        """The criterion is evaluated from the rows and configurations, not from M alone."""
        return bool(getattr(self.criterion, "needs_design", False))

    def _point_whitening(self, state, order: int):
        r""":math:`Z_j` (n, d, 3): each model's whitening of its reflector's point error, and
        :math:`\partial Z_j/\partial q_j` (n, d, 3, nv) with ``order`` 1 (None if constant)."""
        z, d_z, n = [], [], state.n
        for mdl in self.problem.models:
            if getattr(mdl, "noise", None) is None:
                z.append(np.broadcast_to(np.diag(1.0 / mdl.sigma), (n, 3, 3)))
                d_z.append(None)
            else:
                pieces = self._whitening(mdl, state, order)
                z.append(pieces.w)
                d_z.append(pieces.d_w)
        if order == 0 or all(x is None for x in d_z):
            return np.concatenate(z, axis=1), None
        nv = next(x for x in d_z if x is not None).shape[-1]
        return np.concatenate(z, axis=1), np.concatenate(
            [np.zeros((n, 3, 3, nv)) if x is None else x for x in d_z], axis=1)

    def compute_value(self, q: np.ndarray) -> float:
        r""":math:`\phi(q)`."""
        if self.needs_design:
            q = self.problem.robot.check_configurations(q, "design")
            state = self._state(q, second_order=False)
            try:
                return self.criterion.compute_design(self._rows(state), q,
                                                     self._point_whitening(state, 0)[0])[0]
            except NotIdentifiableError as exc:
                raise self._named(exc) from None
        info = self.compute_information(q)
        try:
            return float(self.criterion.compute_value(info))
        except NotIdentifiableError as exc:
            raise self._named(exc) from None

    def _first_order(self, q: np.ndarray):
        """Rows, their q-derivatives and M at ``q`` (the last few cached by value)."""
        return self._evaluated(q)[:3]

    def _evaluated(self, q: np.ndarray):
        """Rows, their q-derivatives, M and the kinematic state at ``q`` (cached)."""
        q = np.asarray(q, dtype=float)
        key = q.tobytes()
        cache = self._cache
        if key not in cache:
            state = self._state(q, second_order=True)
            rows = self._rows(state)
            d_rows = self._row_derivatives(state)
            info = self.information(rows)
            if len(cache) >= 4:
                cache.pop(next(iter(cache)))
            cache[key] = (rows, d_rows, info, state)
        return cache[key]

    def compute_hessian(self, q: np.ndarray) -> StructuredHessian | None:
        r"""The exact Hessian of :math:`\phi` in :math:`x = \mathrm{vec}(q)` (pose-major), or None.

        :math:`\nabla^2\phi = \mathrm{blkdiag}(H_1..H_n) + UU^\top`: ``blocks``
        :math:`H_j = \mathrm{tr}(\Gamma\,\partial_{kl}M)` (n, nv, nv), symmetric and
        possibly indefinite, and ``low_rank`` :math:`U` (n·nv, r), the
        positive semidefinite coupling :math:`\nabla^2\Phi(M)[M_a, M_b]` through
        :math:`M`, :math:`M_a = \partial M/\partial q_a`, exact from first derivatives
        (:mod:`calib_oed.oed.hessian`, ``docs/derivations.md`` §12–13). The prior :math:`M_0` enters through
        :math:`M`. ``kpi_model`` (joint-space prior): the dense exact Hessian made positive definite
        (:mod:`calib_oed.oed.model_error_hessian`). None for criteria other than A (``kpi``, ``params``) and D,
        and when a measurement model has no second configuration derivative
        (:meth:`compute_row_hessians`; e.g. with joint compliance modelled).
        """
        if not has_exact_hessian(self.criterion):
            return None
        if self.needs_design:  # kpi_model: dense, made positive definite (oed/model_error_hessian.py)
            try:
                return design_hessian(self, q)
            except NotIdentifiableError as exc:
                raise self._named(exc) from None
        rows, d_rows, info, state = self._evaluated(q)
        dd_rows = self._row_hessians(state)
        if dd_rows is None:
            return None
        try:
            return structured_hessian(self.criterion, info, rows, d_rows, dd_rows)
        except NotIdentifiableError as exc:
            raise self._named(exc) from None

    def compute(self, q: np.ndarray) -> DesignEvaluation:
        r""":math:`\phi(q)` and :math:`\partial\phi/\partial q` (n, nv), exact."""
        rows, d_rows, info = self._first_order(q)
        if self.needs_design:
            state = self._evaluated(q)[3]
            z, d_z = self._point_whitening(state, 1)
            try:
                value, grad = self.criterion.compute_design(rows, np.asarray(q, dtype=float), z, d_rows, d_z)
            except NotIdentifiableError as exc:
                raise self._named(exc) from None
            return DesignEvaluation(value, grad, info)
        try:
            grad_m = self.criterion.compute_gradient(info)
        except NotIdentifiableError as exc:
            raise self._named(exc) from None
        # dphi/dq_jk = 2 sum_d (F_j G)_d . dF_j/dq_k
        grad = 2.0 * np.einsum("jdf,jdfk->jk", rows @ grad_m, d_rows)
        value = float(self.criterion.compute_value(info))
        return DesignEvaluation(value, grad, info)
