r"""Identifiability (the gauge rule) and estimability of KPIs.

**Gauge rule.** On a generic design, take the unit-scaled weighted Jacobian
:math:`A = F_1 D` (:math:`D` = 1 mm or 1 mrad per column) and walk its
columns in the declared parameter order. Parameter :math:`k` is *free* if
its column is not in the span of the free columns before it:

.. math::
    r_k = \frac{\lVert (I - Q Q^\top) a_k \rVert}{\lVert a_k \rVert} > \tau,

with :math:`Q` an orthonormal basis of the earlier free columns. Otherwise it
is *fixed* at its nominal value; it is redundant with the earlier free
parameters that express it, :math:`a_k \approx \sum_j \beta_j a_j`, which the
report lists. Each fixed parameter spans one direction
:math:`n_k = e_k - \sum_j \beta_j e_j` of the null space of :math:`A`: the
gauge.

**Estimability.** A KPI with Jacobian :math:`G` is estimable when its rows
lie in the row space of :math:`F_1` over all parameters; the relative
residual is :math:`\lVert G D (I - V V^\top) \rVert_F / \lVert G D \rVert_F`
with :math:`V` the right singular vectors of :math:`A` for its largest
singular values, as many as the gauge rule's rank. A non-estimable KPI depends on the gauge: on the fixed parameters
:math:`k` with :math:`G D n_k \neq 0`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from calib_oed.exceptions import ShapeError

#: Default relative tolerance of the gauge rule. A column closer than this to
#: the span of the earlier free columns would have a standard deviation at
#: least 1e4 times that of a well-determined parameter: fixed in practice.
#: (It also absorbs URDF round-off such as ``rpy="1.5708 0 0"``.)
DEFAULT_TOL = 1e-4
#: Default tolerance of the estimability residual.
ESTIMABILITY_TOL = 1e-6
# Coefficients below this fraction of the largest are not listed as redundancies.
_LIST_TOL = 1e-3


@dataclass(frozen=True)
class FixedParameter:
    """A parameter held at its nominal value by the gauge rule.

    Attributes:
        name: Parameter name.
        residual: Relative residual :math:`r_k` of its column (below tolerance).
        redundant_with: Earlier free parameters whose columns express it, with
            the coefficients :math:`\\beta_j` in unit-scaled terms, largest first.
            Empty when the column is zero (no effect on the measurements).
    """

    name: str
    residual: float
    redundant_with: tuple[tuple[str, float], ...] = ()

    @property
    def reason(self) -> str:
        """One line saying why the parameter is fixed."""
        if not self.redundant_with:
            return "no effect on the measurements"
        names = ", ".join(n for n, _ in self.redundant_with[:6])
        more = len(self.redundant_with) - 6
        return f"redundant with {names}" + (f" and {more} more" if more > 0 else "")


@dataclass(frozen=True, eq=False)
class IdentifiabilityReport:
    """Result of the gauge rule on a generic design.

    Attributes:
        names: All parameter names, in order.
        free: Boolean mask of the free parameters.
        residuals: :math:`r_k` of every parameter.
        fixed: The fixed parameters with their reasons.
        rank: Number of free parameters.
        condition_number: Of the unit-scaled weighted Jacobian on the free
            parameters (mm, mrad), on the generic design.
        n_configurations: Size of the generic design.
        n_rows: Rows of :math:`F_1`.
        seed: Seed of the generic design.
        tol: Tolerance :math:`\\tau`.
        null_space: Gauge directions :math:`n_k` (n_p, n_fixed), unit-scaled.
    """

    names: tuple[str, ...]
    free: np.ndarray
    residuals: np.ndarray
    fixed: tuple[FixedParameter, ...]
    rank: int
    condition_number: float
    n_configurations: int
    n_rows: int
    seed: int | None
    tol: float
    null_space: np.ndarray = field(repr=False)

    @property
    def free_names(self) -> tuple[str, ...]:
        return tuple(n for n, f in zip(self.names, self.free, strict=True) if f)

    @property
    def fixed_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fixed)

    @property
    def free_indices(self) -> np.ndarray:
        return np.flatnonzero(self.free)

    def to_dict(self) -> dict:
        """Machine-readable form (JSON-serialisable)."""
        return {
            "n_parameters": len(self.names),
            "rank": self.rank,
            "condition_number": self.condition_number,
            "n_configurations": self.n_configurations,
            "seed": self.seed,
            "tol": self.tol,
            "free": list(self.free_names),
            "fixed": [
                {
                    "name": f.name,
                    "residual": f.residual,
                    "reason": f.reason,
                    "redundant_with": [{"name": n, "coefficient": c} for n, c in f.redundant_with],
                }
                for f in self.fixed
            ],
        }


def select_gauge(
    scaled_jacobian: np.ndarray,
    names: Sequence[str],
    *,
    tol: float = DEFAULT_TOL,
    n_configurations: int = 0,
    seed: int | None = None,
) -> IdentifiabilityReport:
    """Greedy rank selection in column order (see module docstring).

    Args:
        scaled_jacobian: :math:`A = F_1 D`, (m, n_p).
        names: Parameter names (n_p,).
        tol: Relative residual below which a column counts as dependent.
    """
    a = np.asarray(scaled_jacobian, dtype=float)
    if a.ndim != 2 or a.shape[1] != len(names):
        raise ShapeError("scaled_jacobian", f"(m, {len(names)})", a.shape)
    m, n_p = a.shape
    basis = np.zeros((m, 0))
    free = np.zeros(n_p, dtype=bool)
    residuals = np.zeros(n_p)
    fixed: list[FixedParameter] = []
    null_vectors = []
    # A column this small relative to the largest is round-off: no effect.
    zero = tol * max(float(np.linalg.norm(a, axis=0).max(initial=0.0)), np.finfo(float).tiny)
    for k in range(n_p):
        col = a[:, k]
        norm = np.linalg.norm(col)
        if norm <= zero:
            residuals[k] = 0.0
            fixed.append(FixedParameter(names[k], 0.0))
            vec = np.zeros(n_p)
            vec[k] = 1.0
            null_vectors.append(vec)
            continue
        r = col - basis @ (basis.T @ col)
        r = r - basis @ (basis.T @ r)  # second Gram-Schmidt pass for accuracy
        residuals[k] = np.linalg.norm(r) / norm
        if residuals[k] > tol:
            free[k] = True
            basis = np.column_stack([basis, r / np.linalg.norm(r)])
            continue
        idx = np.flatnonzero(free)
        beta, *_ = np.linalg.lstsq(a[:, idx], col, rcond=None)
        weight = np.abs(beta) * np.linalg.norm(a[:, idx], axis=0) / norm
        order = np.argsort(-weight)
        listed = tuple(
            (names[idx[j]], float(beta[j])) for j in order if weight[j] > _LIST_TOL
        )
        fixed.append(FixedParameter(names[k], float(residuals[k]), listed))
        vec = np.zeros(n_p)
        vec[k] = 1.0
        vec[idx] = -beta
        null_vectors.append(vec)
    sv = np.linalg.svd(a[:, free], compute_uv=False) if free.any() else np.array([0.0])
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    free.setflags(write=False)
    residuals.setflags(write=False)
    null = np.array(null_vectors).T if null_vectors else np.zeros((n_p, 0))
    return IdentifiabilityReport(
        names=tuple(names),
        free=free,
        residuals=residuals,
        fixed=tuple(fixed),
        rank=int(free.sum()),
        condition_number=cond,
        n_configurations=n_configurations,
        n_rows=m,
        seed=seed,
        tol=tol,
        null_space=null,
    )


@dataclass(frozen=True)
class Estimability:
    """Whether a KPI is determined by the measurements.

    Attributes:
        label: KPI name.
        estimable: True when the relative residual is below tolerance.
        residual: :math:`\\lVert G D (I - VV^\\top)\\rVert_F/\\lVert G D\\rVert_F`.
        gauge: Fixed parameters the KPI depends on (empty when estimable).
    """

    label: str
    estimable: bool
    residual: float
    gauge: tuple[str, ...]

    def to_dict(self) -> dict:
        return {
            "kpi": self.label,
            "estimable": self.estimable,
            "residual": self.residual,
            "gauge": list(self.gauge),
        }


def check_estimability(
    scaled_jacobian: np.ndarray,
    scaled_kpi_jacobian: np.ndarray,
    report: IdentifiabilityReport,
    label: str,
    *,
    tol: float = ESTIMABILITY_TOL,
) -> Estimability:
    """Estimability of a KPI with unit-scaled Jacobian :math:`GD` (rows, n_p)."""
    a = np.asarray(scaled_jacobian, dtype=float)
    g = np.atleast_2d(np.asarray(scaled_kpi_jacobian, dtype=float))
    if g.shape[1] != a.shape[1]:
        raise ShapeError("kpi jacobian", f"(k, {a.shape[1]})", g.shape)
    # Row space of F1 at the numerical rank the gauge rule found.
    _, _, vt = np.linalg.svd(a, full_matrices=False)
    v = vt[: report.rank].T
    g_norm = np.linalg.norm(g)
    if g_norm == 0.0:
        return Estimability(label, True, 0.0, ())
    residual = float(np.linalg.norm(g - (g @ v) @ v.T) / g_norm)
    gauge: tuple[str, ...] = ()
    if residual > tol:
        null = report.null_space
        effect = np.linalg.norm(g @ null, axis=0) / (g_norm * np.linalg.norm(null, axis=0))
        gauge = tuple(
            f.name for f, e in zip(report.fixed, effect, strict=True) if e > tol
        )
    return Estimability(label, residual <= tol, residual, gauge)
