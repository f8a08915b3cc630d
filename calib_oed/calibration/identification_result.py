r"""The record of one identification: :class:`IdentificationResult` and its parts.

Owns what :func:`calib_oed.calibration.identification.identify` returns and how it is
read: the solver status (:class:`IdentificationStatus`), the estimate with its
a-priori and a-posteriori uncertainty (:class:`ParameterEstimate`), the
residual diagnostics and outliers (:class:`Outlier`), the self-check
:meth:`IdentificationResult.check` (gradient of the cost at the estimate), the
human-readable :meth:`~IdentificationResult.summary` and the JSON-safe
:meth:`~IdentificationResult.to_dict`. The estimator, its cost and its
options are in :mod:`calib_oed.calibration.identification`; how to read the result:
``docs/identification.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import NamedTuple

import numpy as np

from calib_oed.exceptions import UnknownParameterError
from calib_oed.model.parameters import InReportUnits, report_scale_of
from calib_oed.values import plain


class IdentificationStatus(str, Enum):
    """How the solver stopped (scipy status > 0, 0, < 0)."""

    CONVERGED = "converged"
    MAX_ITERATIONS = "max_iterations"
    FAILED = "failed"


class Outlier(NamedTuple):
    """A measurement whose weighted residual norm :math:`\\lVert r\\rVert/\\sqrt d` exceeds the threshold."""

    block: int
    row: int
    norm: float  # [sigma]


@dataclass(frozen=True)
class ParameterEstimate(InReportUnits):
    """One parameter of an identification result, SI (``value``, ``std``) with report units.

    ``std`` and ``std_posterior`` are 0 for a fixed parameter.
    """

    name: str
    value: float
    unit: str
    free: bool
    std: float
    std_posterior: float


@dataclass(frozen=True, eq=False)
class IdentificationResult:
    """Estimate, fit and uncertainty of one identification (arrays read-only, SI).

    Attributes:
        names: All parameter names; ``free_names`` the estimated ones.
        parameter_units: ``"m"`` or ``"rad"`` of every parameter.
        p: Full estimate (n_p,); fixed parameters at ``p0``. ``p_free`` (n_f,).
        status, message, nfev, njev: How the solver stopped (scipy's message
            and counts of residual and Jacobian evaluations).
        method: The solver.
        cost: Final value of the minimised cost :math:`\\tfrac12\\lVert r\\rVert^2`.
        residuals: Weighted residuals :math:`r` (m,) [sigma].
        block_names: Model name of every block.
        block_residuals: Per block, raw residuals :math:`h - \\eta` (n, d) [m, rad].
        point_residuals_mm: Per block, position residual norm per measurement (n,) [mm].
        angle_residuals_mrad: Per block, rotation residual norm (n,) [mrad]; None
            for blocks without angular components.
        measurement_norms: Per block, :math:`\\lVert r_{row}\\rVert/\\sqrt d` (n,) [sigma].
        rms_mm, max_mm: Over the position residual norms of all measurements [mm].
        rms_mrad, max_mrad: Same for rotation residuals [mrad]; None if no pose data.
        dof: m - n_f. noise_factor: :math:`\\hat\\sigma_0^2 = \\lVert r\\rVert^2/(m - n_f)`;
            sigma0 its square root.
        covariance: A priori :math:`C_p = (F_1^\\top F_1)^{-1}` at the estimate, free
            parameters [m², m·rad, rad²]; std its root diagonal; std_posterior scaled
            by :math:`\\hat\\sigma_0`.
        correlation: :math:`C_{ij}/\\sqrt{C_{ii}C_{jj}}`; strong_correlations:
            ``(a, b, rho)`` with ``|rho| > correlation_threshold``, largest first.
        condition_number: Of :math:`F_1 D` (columns in mm, mrad) at the estimate.
        outliers: Measurements with ``measurement_norms > outlier_threshold``.
        f1: :math:`F_1` on the free columns at the estimate (m, n_f).
    """

    names: tuple[str, ...]
    free_names: tuple[str, ...]
    free_indices: np.ndarray
    parameter_units: tuple[str, ...]
    p: np.ndarray
    status: IdentificationStatus
    message: str
    nfev: int
    njev: int | None
    method: str
    cost: float
    residuals: np.ndarray
    block_names: tuple[str, ...]
    block_residuals: tuple[np.ndarray, ...] = field(repr=False)
    point_residuals_mm: tuple[np.ndarray, ...] = field(repr=False)
    angle_residuals_mrad: tuple[np.ndarray | None, ...] = field(repr=False)
    measurement_norms: tuple[np.ndarray, ...] = field(repr=False)
    rms_mm: float | None
    max_mm: float | None
    rms_mrad: float | None
    max_mrad: float | None
    dof: int
    noise_factor: float
    covariance: np.ndarray = field(repr=False)
    correlation: np.ndarray = field(repr=False)
    strong_correlations: tuple[tuple[str, str, float], ...]
    correlation_threshold: float
    condition_number: float
    outliers: tuple[Outlier, ...]
    outlier_threshold: float
    f1: np.ndarray = field(repr=False)

    @property
    def p_free(self) -> np.ndarray:
        return self.p[self.free_indices]

    @property
    def units(self) -> tuple[str, ...]:
        """SI unit of every free parameter."""
        return tuple(self.parameter_units[i] for i in self.free_indices)

    @property
    def sigma0(self) -> float:
        return float(np.sqrt(self.noise_factor))

    @property
    def noise_factor_inliers(self) -> float:
        """:math:`\\hat\\sigma_0^2` without the outlier rows (equals ``noise_factor`` if none)."""
        out = {(o.block, o.row) for o in self.outliers}
        ss, m = 0.0, 0
        for k, norms in enumerate(self.measurement_norms):
            d = self.block_residuals[k].shape[1]
            keep = np.array([(k, i) not in out for i in range(norms.size)], dtype=bool)
            ss += float(np.sum(norms[keep] ** 2) * d)
            m += int(keep.sum()) * d
        dof = m - len(self.free_names)
        return ss / dof if dof > 0 else float("nan")

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    @property
    def posterior_factor(self) -> float:
        """The :math:`\\hat\\sigma_0^2` that scales the a-posteriori std: ``noise_factor``."""
        return self.noise_factor

    @property
    def std_posterior(self) -> np.ndarray:
        """A-posteriori standard deviations: ``std`` times :math:`\\sqrt{}` ``posterior_factor``."""
        return self.std * np.sqrt(self.posterior_factor)

    @property
    def converged(self) -> bool:
        return self.status is IdentificationStatus.CONVERGED

    def estimate(self, name: str) -> ParameterEstimate:
        """Value (SI) and standard deviations of parameter ``name``."""
        if name not in self.names:
            raise UnknownParameterError(name, self.names)
        k = self.names.index(name)
        j = np.flatnonzero(self.free_indices == k)
        std = float(self.std[j[0]]) if j.size else 0.0
        return ParameterEstimate(name, float(self.p[k]), self.parameter_units[k], bool(j.size),
                                 std, std * float(np.sqrt(self.posterior_factor)))

    def check(self) -> float:
        r"""Norm of the cost's gradient at the estimate, unit-scaled (per mm, per mrad).

        :math:`\lVert D\,F_1^\top r\rVert_2`: near 0 at a stationary point. The estimate's distance from the
        stationary point is about this divided by the square of the smallest
        singular value of :math:`F_1 D`.
        """
        scale = np.array([report_scale_of(u) for u in self.units])
        return float(np.linalg.norm(scale * (self.f1.T @ self.residuals)))

    def _free_estimates(self) -> list[ParameterEstimate]:
        return [self.estimate(n) for n in self.free_names]

    def summary(self, top: int = 10, outliers: bool = True) -> str:
        """Human-readable report in mm and mrad (``outliers=False``: without the a-priori outlier list
        and the sigma0 without them, for callers that judge outliers against an estimated scale,
        :mod:`calib_oed.calibration.robust`)."""
        n_meas = sum(len(x) for x in self.point_residuals_mm)
        lines = [
            f"Identification: {self.status.value} ({self.method}): {self.nfev} residual and "
            f"{self.njev} Jacobian evaluations",
            f"  solver: {self.message}",
            f"  data: {len(self.block_names)} block(s), {n_meas} measurements, "
            f"{self.residuals.size} values; {len(self.free_names)} free parameters, "
            f"{len(self.names) - len(self.free_names)} fixed; {self.dof} degrees of freedom",
        ]
        if self.rms_mm is not None:
            lines.append(f"  position residual [  mm]: RMS {self.rms_mm:.4f}, max {self.max_mm:.4f}")
        if self.rms_mrad is not None:
            lines.append(f"  rotation residual [mrad]: RMS {self.rms_mrad:.4f}, "
                         f"max {self.max_mrad:.4f}")
        lines += [
            f"  a-posteriori noise factor sigma0 = {self.sigma0:.3f} (sigma0^2 = "
            f"{self.noise_factor:.3f}; 1 = residuals as large as the stated sigma)"
            + (f"; without the outliers sigma0^2 = {self.noise_factor_inliers:.3f}"
               if self.outliers and outliers else ""),
            f"  condition number of the weighted Jacobian (columns in mm, mrad): "
            f"{self.condition_number:.4g}",
        ]
        est = sorted(self._free_estimates(), key=lambda e: -abs(e.value / e.report_scale))
        lines.append(f"Largest estimates ({min(top, len(est))} of {len(est)} free), "
                     "value ± a-priori std (a-posteriori std, x sigma0):")
        for e in est[:top]:
            s = e.report_scale
            lines.append(f"  {e.name:<14s} [{e.report_unit:>4s}] {e.value / s:+10.4f} ± "
                         f"{e.std / s:.4f} ({e.std_posterior / s:.4f})")
        lines.append(f"Strong correlations (|rho| > {self.correlation_threshold:g}): "
                     f"{len(self.strong_correlations) or 'none'}")
        for a, b, rho in self.strong_correlations[:top]:
            lines.append(f"  {a} / {b}: {rho:+.3f}")
        if len(self.strong_correlations) > top:
            lines.append(f"  ... ({len(self.strong_correlations) - top} more)")
        if not outliers:
            return "\n".join(lines)
        lines.append(f"Outliers (|r|/sqrt(d) > {self.outlier_threshold:g} sigma): "
                     f"{len(self.outliers) or 'none'}")
        for o in self.outliers[:20]:
            mm = self.point_residuals_mm[o.block][o.row]
            lines.append(f"  block {o.block} ({self.block_names[o.block]}) row {o.row}: "
                         f"{o.norm:.1f} sigma, position residual {mm:.4f} mm")
        if len(self.outliers) > 20:
            lines.append(f"  ... ({len(self.outliers) - 20} more)")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """Machine-readable form (JSON-serialisable, SI unless a key says mm/mrad; NaN, inf -> None)."""
        return plain({
            "status": self.status.value, "message": self.message,
            "nfev": self.nfev, "njev": self.njev,
            "method": self.method,
            "cost": self.cost, "dof": self.dof,
            "noise_factor": self.noise_factor, "sigma0": self.sigma0,
            "noise_factor_inliers": self.noise_factor_inliers,
            "rms_mm": self.rms_mm, "max_mm": self.max_mm,
            "rms_mrad": self.rms_mrad, "max_mrad": self.max_mrad,
            "condition_number": self.condition_number,
            "p": dict(zip(self.names, map(float, self.p), strict=True)),
            "free": [
                {"name": e.name, "value": e.value, "unit": e.unit, "std": e.std,
                 "std_posterior": e.std_posterior}
                for e in self._free_estimates()
            ],
            "covariance": self.covariance.tolist(),
            "strong_correlations": [{"a": a, "b": b, "rho": r} for a, b, r in self.strong_correlations],
            "outliers": [{"block": o.block, "model": self.block_names[o.block], "row": o.row,
                          "norm_sigma": o.norm} for o in self.outliers],
        })
