r"""A design criterion as a function of the measurement configurations, with its exact gradient.

For a design :math:`q = (q_1, \dots, q_n)`, :math:`q_j \in \mathbb{R}^{n_v}`,
each pose contributes the rows

.. math::
    \tilde F_j(q_j) = \Sigma^{-1}\,\frac{\partial h}{\partial p_f}(p, q_j)\,D
    \in \mathbb{R}^{d \times n_f}

of the weighted sensitivity on the free parameters :math:`p_f` (gauge rule),
unit-scaled by :math:`D = \mathrm{diag}(u_f)` so that parameters are in mm
and mrad (``ParameterSpace.unit_scale``). The information matrix and the
objective are

.. math::
    M(q) = M_0 + \sum_{j=1}^{n} \tilde F_j^\top \tilde F_j, \qquad
    \phi(q) = \Phi\big(M(q)\big)

with :math:`M_0` an optional prior (measurements already taken) and
:math:`\Phi` a :class:`calib_oed.criteria.Criterion`. Because
:math:`\tilde F_j` depends on :math:`q_j` alone,

.. math::
    \frac{\partial\phi}{\partial q_{j,k}}
      = 2\,\mathrm{tr}\Big(\tilde F_j\,\frac{\partial\Phi}{\partial M}\,
        \frac{\partial \tilde F_j^\top}{\partial q_{j,k}}\Big),

and :math:`\partial\tilde F_j/\partial q_{j,k}` is the mixed derivative
:math:`\partial^2 h/\partial p\,\partial q` of the measurement models
(:meth:`calib_oed.measurements.MeasurementModel.compute_param_config_jacobian`),
batched over poses. Derivation: ``docs/derivations.md`` §11.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.criteria import ACriterion, Criterion, make_criterion
from calib_oed.exceptions import NotIdentifiableError, ShapeError
from calib_oed.measurements import evaluate_setup
from calib_oed.problem import CalibrationProblem

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


class DesignObjective:
    """:math:`\\phi(q) = \\Phi(M(q))` for a calibration problem (see module docstring).

    Args:
        problem: The calibration problem (its gauge rule picks the free parameters).
        criterion: A criterion object, or a name from
            :data:`calib_oed.criteria.CRITERIA` (``"kpi"``: the paper's
            A-criterion on the KPI covariance in mm²; ``"params"``: the
            A-criterion on the parameter covariance in mm²/mrad²).
        p: Parameters the sensitivities are evaluated at (None: nominal).
        prior: Information :math:`M_0` already available, (n_f, n_f).
    """

    def __init__(
        self,
        problem: CalibrationProblem,
        criterion: Criterion | str = "kpi",
        p: np.ndarray | None = None,
        prior: np.ndarray | None = None,
    ):
        self.problem = problem
        self.p = problem.space.check(p)
        self.free = problem.identifiability.free_indices
        self.scale = problem.space.unit_scale[self.free]
        nf = len(self.free)
        if isinstance(criterion, str):
            criterion = make_criterion(criterion, kpi_jacobian=self.kpi_jacobian(), n_params=nf)
        self.criterion = criterion
        if prior is not None:
            prior = np.asarray(prior, dtype=float)
            if prior.shape != (nf, nf):
                raise ShapeError("prior information", f"({nf}, {nf})", prior.shape)
        self.prior = prior

    @property
    def n_free(self) -> int:
        return len(self.free)

    def kpi_jacobian(self) -> np.ndarray:
        """Unit-scaled KPI Jacobian on the free parameters, (3t, n_f) [mm/mm, mm/mrad]."""
        return self.problem.kpi_jacobian(self.p)[:, self.free] * self.scale * _MM

    def kpi_criterion(self) -> ACriterion:
        """The paper's KPI criterion of this problem (whatever is optimised)."""
        return ACriterion.kpi(self.kpi_jacobian())

    # -------------------------------------------------------------- pieces
    def _state(self, q: np.ndarray, second_order: bool):
        q = self.problem.robot.check_configurations(q, "design")
        return evaluate_setup(self.problem.space, self.p, q, regressor=True,
                              jacobian=second_order)

    def _rows(self, state) -> np.ndarray:
        blocks = [
            mdl.compute_param_jacobian(state)[:, :, self.free] / mdl.sigma[None, :, None]
            for mdl in self.problem.models
        ]
        return np.concatenate(blocks, axis=1) * self.scale  # (n, d, n_f)

    def _row_derivatives(self, state) -> np.ndarray:
        blocks = [
            mdl.compute_param_config_jacobian(state)[:, :, self.free, :]
            / mdl.sigma[None, :, None, None]
            for mdl in self.problem.models
        ]
        return np.concatenate(blocks, axis=1) * self.scale[:, None]  # (n, d, n_f, nv)

    def compute_blocks(self, q: np.ndarray) -> np.ndarray:
        r"""Per-pose rows :math:`\tilde F_j`, (n, d, n_f), all models stacked per pose."""
        return self._rows(self._state(q, second_order=False))

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

    def compute_value(self, q: np.ndarray) -> float:
        r""":math:`\phi(q)`."""
        info = self.compute_information(q)
        try:
            return float(self.criterion.compute_value(info))
        except NotIdentifiableError as exc:
            raise self._named(exc) from None

    def compute(self, q: np.ndarray) -> DesignEvaluation:
        r""":math:`\phi(q)` and :math:`\partial\phi/\partial q` (n, nv), exact."""
        state = self._state(q, second_order=True)
        rows = self._rows(state)
        info = self.information(rows)
        try:
            grad_m = self.criterion.compute_gradient(info)
        except NotIdentifiableError as exc:
            raise self._named(exc) from None
        d_rows = self._row_derivatives(state)
        # dphi/dq_jk = 2 sum_d (F_j G)_d . dF_j/dq_k
        grad = 2.0 * np.einsum("jdf,jdfk->jk", rows @ grad_m, d_rows)
        value = float(self.criterion.compute_value(info))
        return DesignEvaluation(value, grad, info)
