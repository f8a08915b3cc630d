r"""Linearised confidence ellipsoids of estimated quantities (paper eq. 8, Figure 7).

For an estimate :math:`\hat x \in \mathbb{R}^d` with covariance :math:`C`
(e.g. a 3×3 block of the KPI covariance :math:`C_s`), the confidence region
at level :math:`1-\alpha` is

.. math::
    E = \{x : (x - \hat x)^\top C^{-1} (x - \hat x) \le r^2\}, \qquad
    r^2 = \chi^2_d(1-\alpha),

the :math:`(1-\alpha)` quantile of the :math:`\chi^2` distribution with
:math:`d` degrees of freedom. (The paper's eq. 8 prints :math:`C` where
:math:`C^{-1}` is meant.) With :math:`C = V \Lambda V^\top`,
:math:`\lambda_1 \ge \dots \ge \lambda_d > 0`, the half-axes are
:math:`a_k = \sqrt{r^2 \lambda_k}` along the columns of :math:`V`. (Figure 7's
caption calls the eigenvalues the half-axes; they are :math:`\sqrt{r^2\lambda_k}`.)

Two 2-D pictures of a 3-D ellipsoid, both with the covariance block
:math:`C_{JJ}` of the plotted coordinates :math:`J`:

- :meth:`ConfidenceEllipsoid.shadow`: the orthogonal projection of :math:`E`
  onto the plane, :math:`\{y : y^\top C_{JJ}^{-1} y \le \chi^2_d(1-\alpha)\}`.
  This is what Figure 7 draws. It holds the projected estimate with
  probability :math:`F_{\chi^2_2}(\chi^2_3(1-\alpha))` = 0.9799 at 95 %.
- :meth:`ConfidenceEllipsoid.marginal`: the confidence ellipse of the two
  coordinates alone, :math:`\{y : y^\top C_{JJ}^{-1} y \le \chi^2_2(1-\alpha)\}`,
  holding them with probability :math:`1-\alpha`.

Inputs are SI (m, m²); :meth:`ConfidenceEllipsoid.to_dict` reports mm.
Derivation: ``docs/derivations.md`` §10.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.stats

from calib_oed.exceptions import (
    ConfidenceLevelError,
    NonFiniteError,
    NotPositiveDefiniteError,
    ShapeError,
)

#: Kinds of ellipsoid: the joint region of all its components, the marginal
#: region of some components, the shadow (projection) of a larger ellipsoid.
KINDS = ("joint", "marginal", "shadow")
#: Millimetres per metre, for :meth:`ConfidenceEllipsoid.to_dict`.
MM_PER_M = 1e3


def chi2_radius2(level: float, d: int) -> float:
    r""":math:`r^2 = \chi^2_d(\mathrm{level})`, the squared Mahalanobis radius of the region."""
    try:
        lv = float(level)
    except (TypeError, ValueError):
        raise ConfidenceLevelError(level) from None
    if not 0.0 < lv < 1.0:  # also rejects NaN
        raise ConfidenceLevelError(level)
    return float(scipy.stats.chi2.ppf(lv, int(d)))


@dataclass(frozen=True, eq=False)
class ConfidenceEllipsoid:
    r"""The region :math:`(x - c)^\top C^{-1} (x - c) \le \chi^2_d(\mathrm{level})`.

    Attributes:
        center: :math:`c`, (d,) [m].
        covariance: :math:`C`, (d, d) [m²], symmetric positive definite.
        level: Confidence level :math:`1-\alpha` in (0, 1).
        name: Label (e.g. the working configuration).
        kind: ``"joint"``, ``"marginal"`` or ``"shadow"`` (see the module doc).
        dims: Components of the parent ellipsoid this one shows, or ``None``.
        radius2: :math:`r^2 = \chi^2_d(\mathrm{level})` [1].
        half_axes: :math:`\sqrt{r^2\lambda_k}`, (d,) [m], descending.
        axes: Unit eigenvectors of :math:`C` as columns, in the order of
            ``half_axes``, (d, d); each column's largest-magnitude entry is
            made positive, then for d ≥ 2 the last column is flipped if
            needed so that :math:`\det = +1` (right-handed for d = 3).
    """

    center: np.ndarray
    covariance: np.ndarray
    level: float = 0.95
    name: str = ""
    kind: str = "joint"
    dims: tuple[int, ...] | None = None
    radius2: float = field(init=False)
    half_axes: np.ndarray = field(init=False)
    axes: np.ndarray = field(init=False)
    _cholesky: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        what = f"covariance of {self.name}" if self.name else "covariance"
        center = np.array(self.center, dtype=float)
        if center.ndim != 1 or center.size < 1:
            raise ShapeError("center", "(d,) with d >= 1", center.shape)
        d = center.size
        cov = np.array(self.covariance, dtype=float)
        if cov.shape != (d, d):
            raise ShapeError(what, f"({d}, {d})", cov.shape)
        for label, arr in (("center", center), (what, cov)):
            if not np.all(np.isfinite(arr)):
                raise NonFiniteError(label, np.flatnonzero(~np.isfinite(arr)).tolist())
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        radius2 = chi2_radius2(self.level, d)
        scale = np.abs(cov).max()
        sym = 0.5 * (cov + cov.T)
        eigenvalues, vectors = np.linalg.eigh(sym)
        if np.abs(cov - cov.T).max() > 1e-10 * scale:
            raise NotPositiveDefiniteError(what, eigenvalues, "it is not symmetric")
        # Eigenvalues within d*eps*lambda_max of 0 are rounding noise: treat as singular.
        if eigenvalues[0] <= d * np.finfo(float).eps * max(eigenvalues[-1], 0.0):
            raise NotPositiveDefiniteError(what, eigenvalues)
        order = np.argsort(eigenvalues)[::-1]
        eigenvalues, vectors = eigenvalues[order], vectors[:, order]
        big = np.argmax(np.abs(vectors), axis=0)
        vectors = vectors * np.sign(vectors[big, np.arange(d)])
        if d >= 2 and np.linalg.det(vectors) < 0:
            vectors[:, -1] *= -1.0
        half_axes = np.sqrt(radius2 * eigenvalues)
        try:
            chol = scipy.linalg.cholesky(sym, lower=True)
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError(what, eigenvalues[::-1], "Cholesky failed") from None
        for arr in (center, sym, half_axes, vectors, chol):
            arr.setflags(write=False)
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "covariance", sym)
        object.__setattr__(self, "level", float(self.level))
        object.__setattr__(self, "dims", None if self.dims is None else tuple(int(i) for i in self.dims))
        object.__setattr__(self, "radius2", radius2)
        object.__setattr__(self, "half_axes", half_axes)
        object.__setattr__(self, "axes", vectors)
        object.__setattr__(self, "_cholesky", chol)

    @property
    def dim(self) -> int:
        """Dimension :math:`d`."""
        return self.center.size

    # -------------------------------------------------------------- membership
    def mahalanobis_squared(self, points: np.ndarray) -> np.ndarray:
        r""":math:`(x - c)^\top C^{-1} (x - c)` of points (..., d) [m]; shape (...)."""
        x = np.asarray(points, dtype=float)
        if x.ndim < 1 or x.shape[-1] != self.dim:
            raise ShapeError("points", f"(..., {self.dim})", x.shape)
        diff = (x - self.center).reshape(-1, self.dim).T
        z = scipy.linalg.solve_triangular(self._cholesky, diff, lower=True)
        return np.sum(z**2, axis=0).reshape(x.shape[:-1])

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Boolean array (...) : which points (..., d) [m] lie in the closed region."""
        return self.mahalanobis_squared(points) <= self.radius2

    # ------------------------------------------------------------ projections
    def _block(self, dims: Sequence[int]) -> tuple[tuple[int, ...], np.ndarray, np.ndarray]:
        idx = tuple(int(i) for i in dims)
        if not idx or len(set(idx)) != len(idx) or min(idx) < 0 or max(idx) >= self.dim:
            raise ValueError(f"dims must be distinct indices in [0, {self.dim}), got {dims!r}")
        sel = np.array(idx)
        return idx, self.center[sel], self.covariance[np.ix_(sel, sel)]

    def _parent_dims(self, idx: tuple[int, ...]) -> tuple[int, ...]:
        return idx if self.dims is None else tuple(self.dims[i] for i in idx)

    def marginal(self, dims: Sequence[int] = (0, 1), level: float | None = None) -> ConfidenceEllipsoid:
        r"""Confidence region of the components ``dims`` alone, at ``level`` (default: this one's).

        :math:`\{y : (y - c_J)^\top C_{JJ}^{-1} (y - c_J) \le \chi^2_k(\mathrm{level})\}`,
        :math:`k` = ``len(dims)``: it holds the projected estimate with probability ``level``.
        """
        idx, c, cov = self._block(dims)
        return ConfidenceEllipsoid(c, cov, self.level if level is None else level, self.name,
                                   "marginal", self._parent_dims(idx))

    def shadow(self, dims: Sequence[int] = (0, 1)) -> ConfidenceEllipsoid:
        r"""Orthogonal projection of this ellipsoid onto the components ``dims``.

        :math:`\{y : (y - c_J)^\top C_{JJ}^{-1} (y - c_J) \le r^2\}` with this
        ellipsoid's :math:`r^2 = \chi^2_d(1-\alpha)`. Its ``level`` is the
        probability that the projected estimate falls in it,
        :math:`F_{\chi^2_k}(r^2) \ge 1-\alpha` (0.9799 for d = 3, k = 2, 95 %).
        """
        idx, c, cov = self._block(dims)
        level = float(scipy.stats.chi2.cdf(self.radius2, len(idx)))
        return ConfidenceEllipsoid(c, cov, level, self.name, "shadow", self._parent_dims(idx))

    def projection(self, dims: Sequence[int] = (0, 1), kind: str = "marginal") -> ConfidenceEllipsoid:
        """The 2-D picture of ``dims``: ``kind="marginal"`` (:meth:`marginal`) or ``"shadow"`` (:meth:`shadow`)."""
        if kind == "marginal":
            return self.marginal(dims)
        if kind == "shadow":
            return self.shadow(dims)
        raise ValueError(f"kind must be 'marginal' or 'shadow', got {kind!r}")

    def boundary(self, n: int = 181) -> np.ndarray:
        r"""``n`` points on the boundary of a 2-D ellipse, (n, 2) [m], for plotting.

        :math:`c + V\,\mathrm{diag}(a)\,(\cos\theta, \sin\theta)`, :math:`\theta \in [0, 2\pi]`.
        """
        if self.dim != 2:
            raise ValueError(f"boundary() draws 2-D ellipses; this one has d = {self.dim} "
                             "(use marginal() or shadow() first)")
        theta = np.linspace(0.0, 2.0 * np.pi, int(n))
        unit = np.stack([np.cos(theta), np.sin(theta)])
        return (self.center[:, None] + self.axes @ (self.half_axes[:, None] * unit)).T

    # ----------------------------------------------------------------- report
    def to_dict(self) -> dict:
        """JSON-serialisable form; lengths in mm (inputs assumed in m)."""
        return {
            "name": self.name,
            "kind": self.kind,
            "dims": None if self.dims is None else list(self.dims),
            "dimension": self.dim,
            "level": self.level,
            "radius2": self.radius2,
            "center_mm": (self.center * MM_PER_M).tolist(),
            "covariance_mm2": (self.covariance * MM_PER_M**2).tolist(),
            "half_axes_mm": (self.half_axes * MM_PER_M).tolist(),
            "axes": self.axes.tolist(),
        }


def kpi_ellipsoids(
    c_s: np.ndarray,
    centers: np.ndarray,
    level: float = 0.95,
    names: Sequence[str] | None = None,
) -> list[ConfidenceEllipsoid]:
    r"""One 3-D confidence ellipsoid per working configuration.

    Args:
        c_s: KPI covariance :math:`C_s`, (3t, 3t) [m²]; its 3×3 diagonal blocks are used.
        centers: KPI values :math:`s`, (t, 3) or (3t,) [m].
        level: Confidence level :math:`1-\alpha` in (0, 1).
        names: One name per working configuration (default ``work0``, ...).
    """
    c_s = np.asarray(c_s, dtype=float)
    centers = np.asarray(centers, dtype=float)
    if c_s.ndim != 2 or c_s.shape[0] != c_s.shape[1] or c_s.shape[0] % 3:
        raise ShapeError("C_s", "(3t, 3t)", c_s.shape)
    t = c_s.shape[0] // 3
    if centers.size != 3 * t or centers.ndim not in (1, 2):
        raise ShapeError("centers", f"({t}, 3) or ({3 * t},)", centers.shape)
    centers = centers.reshape(t, 3)
    names = tuple(names) if names is not None else tuple(f"work{i}" for i in range(t))
    if len(names) != t:
        raise ShapeError("names", f"({t},)", (len(names),))
    return [
        ConfidenceEllipsoid(centers[i], c_s[3 * i : 3 * i + 3, 3 * i : 3 * i + 3], level, names[i])
        for i in range(t)
    ]
