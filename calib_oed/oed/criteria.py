r"""The shipped design criteria A, D and E, and :func:`make_criterion`, which builds any of them by name.

The A-criterion :math:`\mathrm{tr}(W M^{-1})/k` gives the mean KPI variance
(``kpi``, [mm²]) and the mean parameter variance (``params``, [mm², mrad²]);
D is :math:`\log\det M^{-1}`, E is :math:`\lambda_{\max}(M^{-1})`. All are
:class:`~calib_oed.oed.criterion_base.Criterion` objects of the information
matrix :math:`M` (:mod:`calib_oed.oed.criterion_base` for the conventions), to
minimise. The observability indices ``O1`` .. ``O5`` are
:class:`~calib_oed.oed.observability.ObservabilityIndex`; :data:`CRITERIA`
names every criterion :func:`make_criterion` builds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from calib_oed.exceptions import NonFiniteError, ShapeError, UnknownCriterionError
from calib_oed.oed.criterion_base import (
    Criterion,
    _batched_cholesky,
    _cholesky,
    _forward_substitution,
    _positive_eigh,
    as_information,
)
from calib_oed.oed.observability import ObservabilityIndex

#: Names accepted by :func:`make_criterion`.
#: The criteria of the information matrix alone (a :class:`Criterion` of M).
MATRIX_CRITERIA = ("kpi", "params", "D", "E", "O1", "O2", "O3", "O4", "O5")
#: ... and ``kpi_model`` / ``kpi_kriging``, the KPI error under model error of the parametric
#: fit / of GLS plus kriging, criteria of the whole design (:mod:`calib_oed.oed.model_error`).
CRITERIA = (*MATRIX_CRITERIA, "kpi_model", "kpi_kriging")


# ------------------------------------------------------------- A-criterion
@dataclass(frozen=True, eq=False)
class ACriterion(Criterion):
    r"""Weighted A-criterion :math:`\phi_A(M) = \mathrm{tr}(W M^{-1})/k`.

    .. math::
        \phi_A = \tfrac{1}{k}\,\mathrm{tr}(W C) = \tfrac{1}{k}\,\| L^{-1} R^\top \|_F^2
        = \tfrac{1}{k}\,\mathrm{tr}\big(R\,(M^{-1} R^\top)\big),
        \qquad \frac{\partial \phi_A}{\partial M} = -\tfrac{1}{k}\, M^{-1} W M^{-1},

    with :math:`W = R^\top R` symmetric positive semidefinite and
    :math:`M = L L^\top` (Cholesky; no inverse is formed). With
    :meth:`kpi`, :math:`R = G` and :math:`\phi_A` is the mean variance of the
    KPI, :math:`\mathrm{tr}(G C G^\top)/n_s` [mm²], the paper's
    :math:`\mathrm{tr}(P^\top C_v P)/k`; with :meth:`parameters`, the mean
    variance of the unit-scaled parameters [mm² for lengths, mrad² for angles].

    Attributes:
        weight: :math:`W`, (n_p, n_p), read-only.
        dim: Divisor :math:`k` (number of averaged quantities).
        name: Short name.
        label: Human description.
        root: :math:`R` with :math:`R^\top R = W`, (r, n_p), read-only;
            computed from :math:`W` by an eigen-decomposition when not given.
    """

    weight: np.ndarray
    dim: int
    name: str = "A"
    label: str = "A-criterion tr(W C)/k"
    root: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        w = as_information(self.weight, "weight W")
        if int(self.dim) != self.dim or self.dim < 1:
            raise ValueError(f"dim must be a positive integer, got {self.dim!r}")
        if self.root is None:
            lam, vec = np.linalg.eigh(w)
            top = max(abs(lam[-1]), np.finfo(float).tiny)
            if lam[0] < -1e-10 * top:
                raise ValueError(f"weight W must be positive semidefinite; smallest eigenvalue {lam[0]:.3g}")
            keep = lam > w.shape[0] * np.finfo(float).eps * top
            root = np.sqrt(lam[keep])[:, None] * vec[:, keep].T
        else:
            root = np.array(self.root, dtype=float)
            if root.ndim != 2 or root.shape[1] != w.shape[0]:
                raise ShapeError("root R", f"(r, {w.shape[0]})", root.shape)
            if not np.allclose(root.T @ root, w, rtol=1e-10, atol=1e-12 * np.abs(w).max()):
                raise ValueError("root R does not satisfy R^T R = W")
        if root.shape[0] == 0:
            raise ValueError("weight W is zero: the criterion would be constant")
        w.setflags(write=False)
        root.setflags(write=False)
        object.__setattr__(self, "weight", w)
        object.__setattr__(self, "dim", int(self.dim))
        object.__setattr__(self, "root", root)

    @classmethod
    def kpi(cls, g: np.ndarray, weights=None) -> ACriterion:
        r"""Mean KPI variance :math:`\mathrm{tr}(G C G^\top)/n_s` [mm²], optionally weighted.

        With weights :math:`w_i \ge 0` of the :math:`t = n_s/3` KPI points
        (rows :math:`3i..3i+2` of :math:`G` are point :math:`i`) the value is the
        weighted mean of the per-point variances
        :math:`v_i = \mathrm{tr}(G_i C G_i^\top)/3`,

        .. math::
            \phi = \frac{\sum_i w_i\,\mathrm{tr}(G_i C G_i^\top)}{3\sum_i w_i}
                  = \tfrac{1}{n_s}\,\mathrm{tr}(R C R^\top),\qquad
            R = \mathrm{diag}\big(\sqrt{w_i/\bar w}\big)\,G

        (each factor repeated for x, y, z; :math:`\bar w` the mean weight).
        Equal weights give exactly the unweighted criterion (same root).

        Args:
            g: Unit-scaled KPI Jacobian :math:`G`, (n_s, n_p) [mm/mm, mm/mrad].
            weights: One weight >= 0 per KPI point (n_s/3,), not all zero; None: all 1.
        """
        g = np.atleast_2d(np.array(g, dtype=float))
        if g.ndim != 2:
            raise ShapeError("KPI Jacobian G", "(n_s, n_p)", g.shape)
        if not np.all(np.isfinite(g)):
            raise NonFiniteError("KPI Jacobian G", np.flatnonzero(~np.isfinite(g)).tolist())
        root = g
        if weights is not None:
            w = np.asarray(weights, dtype=float).reshape(-1)
            if g.shape[0] % 3 or w.shape != (g.shape[0] // 3,):
                raise ShapeError("KPI weights", f"({g.shape[0] // 3},), one per KPI point", w.shape)
            if not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
                raise ValueError(f"KPI weights must be finite, >= 0 and not all 0, got {w}")
            if np.any(w != w[0]):  # equal weights: exactly the unweighted criterion
                root = np.repeat(np.sqrt(w / w.mean()), 3)[:, None] * g
        label = ("A-criterion on the KPI covariance, tr(G C G^T)/n_s [mm^2]" if root is g else
                 "weighted A-criterion on the KPI covariance, sum_i w_i tr(C_s,ii)/(3 sum_i w_i) [mm^2]")
        return cls(root.T @ root, g.shape[0], "kpi", label, root)

    @classmethod
    def parameters(cls, n_p: int) -> ACriterion:
        r"""Mean parameter variance :math:`\mathrm{tr}(C)/n_p` on the unit-scaled parameters.

        Lengths are in mm and angles in mrad, so the value mixes [mm²] and
        [mrad²]: a variance of 1 mm² weighs as much as one of 1 mrad².
        """
        n_p = int(n_p)
        if n_p < 1:
            raise ValueError(f"n_p must be >= 1, got {n_p}")
        eye = np.eye(n_p)
        return cls(eye, n_p, "params", "A-criterion on the parameter covariance, tr(C)/n_p [mm^2, mrad^2]", eye)

    def _check_size(self, n: int) -> None:
        if n != self.weight.shape[0]:
            raise ShapeError("information matrix", f"({self.weight.shape[0]}, {self.weight.shape[0]})", (n, n))

    def compute_value(self, info):
        m = as_information(info)
        self._check_size(m.shape[0])
        # tr(R M^-1 R^T) by cho_solve: scipy's solve_triangular was ~100x slower on
        # small matrices with a multithreaded OpenBLAS on a busy machine
        y = scipy.linalg.cho_solve((_cholesky(m), True), self.root.T, check_finite=False)
        return float(np.sum(self.root.T * y) / self.dim)

    def compute_gradient(self, info):
        m = as_information(info)
        self._check_size(m.shape[0])
        y = scipy.linalg.cho_solve((_cholesky(m), True), self.root.T, check_finite=False)  # M^-1 R^T
        return -(y @ y.T) / self.dim

    def _batched_values(self, infos):
        self._check_size(infos.shape[1])
        low, ok = _batched_cholesky(infos)
        z = _forward_substitution(low, self.root.T)
        return np.sum(z**2, axis=(1, 2)) / self.dim, ok


# ---------------------------------------------------------- D, E criteria
@dataclass(frozen=True, eq=False)
class DCriterion(Criterion):
    r"""D-criterion :math:`\phi_D(M) = \log\det C = -\log\det M = -2\sum_i \log L_{ii}`.

    .. math::
        \frac{\partial \phi_D}{\partial M} = -M^{-1}.

    Units: :math:`\log` of [mm^(2a) mrad^(2b)] for :math:`a` length and
    :math:`b` angle parameters; changing units shifts it by a constant.
    The index is the value.
    """

    name = "D"
    label = "D-criterion, log det C"

    def compute_value(self, info):
        low = _cholesky(as_information(info))
        return float(-2.0 * np.sum(np.log(np.diag(low))))

    def compute_gradient(self, info):
        m = as_information(info)
        return -scipy.linalg.cho_solve((_cholesky(m), True), np.eye(m.shape[0]), check_finite=False)

    def _batched_values(self, infos):
        low, ok = _batched_cholesky(infos)
        return -2.0 * np.sum(np.log(np.diagonal(low, axis1=1, axis2=2)), axis=1), ok


@dataclass(frozen=True, eq=False)
class ECriterion(Criterion):
    r"""E-criterion :math:`\phi_E(M) = \lambda_{\max}(C) = 1/\lambda_{\min}(M)`.

    .. math::
        \frac{\partial \phi_E}{\partial M} = -\frac{v v^\top}{\lambda_{\min}^2},

    with :math:`v` the unit eigenvector of :math:`\lambda_{\min}(M)`. The
    criterion is not differentiable where :math:`\lambda_{\min}` is repeated;
    there the formula gives one element of the generalised gradient.
    Units: [mm²] or [mrad²] (the variance of the worst-determined combination
    of unit-scaled parameters). The index is the value.
    """

    name = "E"
    label = "E-criterion, largest eigenvalue of C"

    def compute_value(self, info):
        w, _ = _positive_eigh(as_information(info))
        return float(1.0 / w[0])

    def compute_gradient(self, info):
        w, v = _positive_eigh(as_information(info))
        return -np.outer(v[:, 0], v[:, 0]) / w[0] ** 2

    def _batched_values(self, infos):
        lam_min = np.linalg.eigvalsh(infos)[:, 0]
        ok = lam_min > 0.0
        return 1.0 / np.where(ok, lam_min, 1.0), ok


# ----------------------------------------------------------------- factory
def make_criterion(name: str, *, kpi_jacobian=None, n_params: int | None = None,
                   kpi_weights=None, problem=None, model_error=None) -> Criterion:
    """The criterion called ``name`` (one of :data:`CRITERIA`).

    Args:
        name: ``"kpi"``, ``"params"``, ``"D"``, ``"E"`` or ``"O1"`` .. ``"O5"``.
        kpi_jacobian: Unit-scaled KPI Jacobian :math:`G` (n_s, n_p)
            [mm/mm, mm/mrad]; needed by ``"kpi"``.
        n_params: Number of parameters :math:`n_p`; needed by ``"params"``
            (taken from ``kpi_jacobian`` when not given).
        kpi_weights: Weights of the KPI points for ``"kpi"`` (:meth:`ACriterion.kpi`);
            None: all 1.
        problem: The calibration problem; needed by ``"kpi_model"``, the KPI
            criterion under model error (:mod:`calib_oed.oed.model_error`).
        model_error: Its prior, a :class:`~calib_oed.measurement.discrepancy.DiscrepancyPrior`
            or a :class:`~calib_oed.measurement.joint_prior.JointErrorPrior` (None: the joint-space
            default, :func:`calib_oed.calibration.joint_prior_choice.joint_prior`).

    Raises:
        UnknownCriterionError: ``name`` is not in :data:`CRITERIA`.
        ValueError: ``"kpi"`` without ``kpi_jacobian``, ``"params"`` without
            ``n_params``.
    """
    if not isinstance(name, str) or name not in CRITERIA:
        raise UnknownCriterionError(name, CRITERIA)
    if name == "kpi":
        if kpi_jacobian is None:
            raise ValueError(
                "criterion 'kpi' needs kpi_jacobian=G, the unit-scaled KPI Jacobian "
                "(n_s, n_p) [mm/mm, mm/mrad]"
            )
        return ACriterion.kpi(kpi_jacobian, kpi_weights)
    if name == "params":
        if n_params is None and kpi_jacobian is not None:
            n_params = np.atleast_2d(kpi_jacobian).shape[1]
        if n_params is None:
            raise ValueError("criterion 'params' needs n_params, the number of parameters")
        return ACriterion.parameters(n_params)
    if name in ("kpi_model", "kpi_kriging"):
        from calib_oed.calibration.joint_prior_choice import joint_prior
        from calib_oed.oed.model_error import make_model_error_criterion

        if problem is None or kpi_jacobian is None:
            raise ValueError(f"criterion {name!r} needs problem= and kpi_jacobian=")
        prior = model_error if model_error is not None else joint_prior(problem)
        return make_model_error_criterion(problem, kpi_jacobian, prior, kpi_weights, name)
    if name == "D":
        return DCriterion()
    if name == "E":
        return ECriterion()
    return ObservabilityIndex(int(name[1]))
