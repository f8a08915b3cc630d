r"""Laser-tracker error model and robot repeatability: the 3×3 covariance of one position.

A laser tracker measures range with an interferometer/ADM and direction with
angle encoders, so its error ellipsoid is flat along the line of sight and
grows with range. For a reflector at :math:`y \in \mathbb{R}^3` in the
TRACKER frame [m], :math:`d = \lVert y\rVert`, :math:`u = y/d`:

.. math::
    \sigma_r(d) = r_0 + r_1 d, \qquad \sigma_t(d) = t_0 + t_1 d \quad [\mathrm{m}],

    \Sigma(y) = \sigma_r^2\, u u^\top + \sigma_t^2\,(I - u u^\top) + \rho^2 I
    \quad [\mathrm{m}^2],

with :math:`\rho` the robot's repeatability (isotropic standard deviation at
the reflector [m]): the robot does not return exactly to the commanded pose,
which looks like extra noise on each measured position. ``r1`` and ``t1`` are
in m per m of range (dimensionless). Whitening uses the Cholesky factor
:math:`\Sigma = L L^\top` (L lower triangular): :math:`W = L^{-1}` gives
:math:`W e \sim N(0, I)` for :math:`e \sim N(0, \Sigma)`, and
:math:`W^\top W = \Sigma^{-1}`.

Derivative in :math:`y` (for the design gradient, checked by central finite
differences in ``tests/measurement/test_noise.py``), with
:math:`P = (I - u u^\top)/d = \partial u/\partial y`:

.. math::
    \frac{\partial \Sigma}{\partial y_k} =
    2(\sigma_r r_1 - \sigma_t t_1)\,u_k\, u u^\top
    + (\sigma_r^2 - \sigma_t^2)\,(P_{:,k} u^\top + u P_{:,k}^\top)
    + 2\sigma_t t_1 u_k\, I .

How to derive the four numbers from a vendor's MPE statement: ``docs/uncertainty.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import ParameterError, ShapeError

__all__ = ["ISO9283_RP_PER_SIGMA", "TrackerNoise", "sigma_from_mpe", "sigma_from_repeatability"]

#: ISO 9283 pose repeatability :math:`RP = \bar l + 3 S_l` of an isotropic Gaussian
#: position error with :math:`\sigma` per axis, divided by :math:`\sigma`: the
#: distance :math:`l` to the mean is Maxwell distributed, :math:`\bar l = 2\sigma\sqrt{2/\pi}`,
#: :math:`S_l = \sigma\sqrt{3 - 8/\pi}`, so :math:`RP \approx 3.616\,\sigma`.
ISO9283_RP_PER_SIGMA = 2.0 * np.sqrt(2.0 / np.pi) + 3.0 * np.sqrt(3.0 - 8.0 / np.pi)


def sigma_from_repeatability(rp: float) -> float:
    """Per-axis sigma of a robot with ISO 9283 pose repeatability ``rp`` (same unit)."""
    if not (np.isfinite(rp) and rp >= 0):
        raise ParameterError(f"repeatability RP must be finite and >= 0, got {rp}")
    return float(rp) / ISO9283_RP_PER_SIGMA


def sigma_from_mpe(a: float, b: float, k: float = 2.0) -> tuple[float, float]:
    r"""``(c0, c1)`` of :math:`\sigma(d) = c_0 + c_1 d` from an MPE :math:`U = \pm(a + b d)`
    read as an expanded uncertainty with coverage factor ``k`` (same units as ``a``, ``b``)."""
    if not (np.isfinite(k) and k > 0):
        raise ParameterError(f"coverage factor k must be > 0, got {k}")
    if not (np.isfinite(a) and np.isfinite(b) and a >= 0 and b >= 0):
        raise ParameterError(f"MPE terms a and b must be finite and >= 0, got a={a}, b={b}")
    return float(a) / k, float(b) / k


def _pair(value, what: str) -> tuple[float, float]:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (2,):
        raise ShapeError(what, "(2,) = [at zero range, per metre of range]", arr.shape)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ParameterError(f"{what}: both coefficients must be finite and >= 0, got {arr.tolist()}")
    return float(arr[0]), float(arr[1])


@dataclass(frozen=True)
class TrackerNoise:
    r"""Range-dependent anisotropic tracker noise plus robot repeatability (see module docstring).

    Attributes:
        radial: :math:`(r_0, r_1)`: :math:`\sigma_r(d) = r_0 + r_1 d` [m, m/m].
        lateral: :math:`(t_0, t_1)`: :math:`\sigma_t(d) = t_0 + t_1 d` [m, m/m].
        repeatability: :math:`\rho`, isotropic standard deviation at the reflector [m].
    """

    radial: tuple[float, float]
    lateral: tuple[float, float]
    repeatability: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "radial", _pair(self.radial, "noise.radial"))
        object.__setattr__(self, "lateral", _pair(self.lateral, "noise.lateral"))
        rho = float(self.repeatability)
        if not (np.isfinite(rho) and rho >= 0):
            raise ParameterError(f"repeatability must be finite and >= 0 [m], got {rho}")
        object.__setattr__(self, "repeatability", rho)
        for what, (c0, _) in (("radial", self.radial), ("lateral", self.lateral)):
            if c0 == 0.0 and rho == 0.0:
                raise ParameterError(f"noise.{what}[0] is 0 and the repeatability is 0: the "
                                     "covariance would be singular at short range; give "
                                     f"noise.{what}[0] > 0 or a repeatability > 0")

    @classmethod
    def isotropic(cls, sigma: float, repeatability: float = 0.0) -> TrackerNoise:
        """The same sigma [m] in every direction at every range (today's model)."""
        return cls((sigma, 0.0), (sigma, 0.0), repeatability)

    # ---------------------------------------------------------------- helpers
    @staticmethod
    def _geometry(y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        y = np.asarray(y, dtype=float)
        if y.ndim != 2 or y.shape[1] != 3:
            raise ShapeError("reflector positions", "(n, 3)", y.shape)
        d = np.linalg.norm(y, axis=1)
        if np.any(~np.isfinite(d)) or np.any(d <= 0):
            raise ParameterError("reflector positions must be finite and away from the tracker "
                                 f"origin (rows {np.flatnonzero(~(d > 0)).tolist()} are not)")
        return y, d, y / d[:, None]

    def sigmas(self, y) -> tuple[np.ndarray, np.ndarray]:
        r""":math:`\sigma_r(d)` and :math:`\sigma_t(d)` [m], each (n,), at positions ``y`` (n, 3) [m]."""
        _, d, _ = self._geometry(y)
        return self.radial[0] + self.radial[1] * d, self.lateral[0] + self.lateral[1] * d

    # ------------------------------------------------------------- covariance
    def covariance(self, y) -> np.ndarray:
        r""":math:`\Sigma(y)` (n, 3, 3) [m²] in the tracker frame at positions ``y`` (n, 3) [m]."""
        _, d, u = self._geometry(y)
        sr = self.radial[0] + self.radial[1] * d
        st = self.lateral[0] + self.lateral[1] * d
        uu = u[:, :, None] * u[:, None, :]
        iso = (st**2 + self.repeatability**2)[:, None, None] * np.eye(3)
        return (sr**2 - st**2)[:, None, None] * uu + iso

    def covariance_derivative(self, y) -> np.ndarray:
        r""":math:`\partial\Sigma/\partial y_k`, (n, 3, 3, 3) indexed [i, a, b, k] [m]."""
        _, d, u = self._geometry(y)
        r1, t1 = self.radial[1], self.lateral[1]
        sr = self.radial[0] + r1 * d
        st = self.lateral[0] + t1 * d
        uu = u[:, :, None] * u[:, None, :]
        proj = (np.eye(3) - uu) / d[:, None, None]  # P[:, a, k] = du_a/dy_k
        out = (2 * (sr * r1 - st * t1))[:, None, None, None] * uu[:, :, :, None] * u[:, None, None, :]
        duu = proj[:, :, None, :] * u[:, None, :, None] + u[:, :, None, None] * proj[:, None, :, :]
        out += (sr**2 - st**2)[:, None, None, None] * duu
        out += (2 * st * t1)[:, None, None, None] * np.eye(3)[None, :, :, None] * u[:, None, None, :]
        return out

    def cholesky(self, y) -> np.ndarray:
        r"""Lower-triangular :math:`L` with :math:`\Sigma = L L^\top`, (n, 3, 3) [m]."""
        return np.linalg.cholesky(self.covariance(y))

    def whitening(self, y) -> np.ndarray:
        r""":math:`W = L^{-1}` (n, 3, 3) [1/m]: :math:`W^\top W = \Sigma^{-1}`."""
        return np.linalg.inv(self.cholesky(y))

    def sample(self, y, rng: np.random.Generator) -> np.ndarray:
        r"""One draw :math:`e = L z`, :math:`z \sim N(0, I)`, per position, (n, 3) [m]."""
        chol = self.cholesky(y)
        z = rng.normal(size=(chol.shape[0], 3))
        return np.einsum("nij,nj->ni", chol, z)
