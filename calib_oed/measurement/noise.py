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


def _inverse_sqrt(sigma, slope: float, rho2: float) -> tuple:
    r""":math:`v^{-1/2}` and its first two derivatives in d, :math:`v = \sigma(d)^2 + \rho^2`,
    :math:`\sigma = c_0 + c_1 d` (``slope`` :math:`c_1`)."""
    v = sigma**2 + rho2
    v1, v2 = 2 * sigma * slope, 2 * slope**2
    return v**-0.5, -0.5 * v**-1.5 * v1, 0.75 * v**-2.5 * v1**2 - 0.5 * v**-1.5 * v2


def _over_d2(f: tuple, d: np.ndarray) -> tuple:
    """:math:`f/d^2` and its first two derivatives in d from those of f."""
    f0, f1, f2 = f
    return f0 / d**2, f1 / d**2 - 2 * f0 / d**3, f2 / d**2 - 4 * f1 / d**3 + 6 * f0 / d**4


def _radial_field(y, d, u, p: tuple, s: tuple, order: int) -> tuple:
    r"""A matrix field :math:`A(y) = p(d)\,I + s(d)\,yy^\top` and its derivatives in y.

    ``p``, ``s``: the functions and their first two derivatives in d, each (n,).
    With :math:`\partial_k d = u_k`, :math:`\partial_l u_k = (\delta_{kl} - u_k u_l)/d`:

    .. math::
        \partial_k A = p' u_k I + s' u_k\, yy^\top + s\,(e_k y^\top + y e_k^\top),

        \partial_{kl} A = \big(p'' u_k u_l + p'\,\partial_l u_k\big) I
          + \big(s'' u_k u_l + s'\,\partial_l u_k\big) yy^\top
          + s' u_k (e_l y^\top + y e_l^\top) + s' u_l (e_k y^\top + y e_k^\top)
          + s\,(e_k e_l^\top + e_l e_k^\top).

    Returns ``(A, dA, ddA)`` up to ``order``: (n, 3, 3), [i, a, b, k], [i, a, b, k, l].
    """
    (p0, p1, p2), (s0, s1, s2) = p, s
    eye = np.eye(3)
    yy = y[:, :, None] * y[:, None, :]  # [i, a, b]
    field = p0[:, None, None] * eye + s0[:, None, None] * yy
    if order < 1:
        return (field,)
    ey = eye[None, :, :, None] * y[:, None, None, :]  # (e_k y^T)_ab as [i, k, a, b]
    sym = np.moveaxis(ey + np.swapaxes(ey, 2, 3), 1, 3)  # e_k y^T + y e_k^T as [i, a, b, k]
    first = ((p1[:, None] * u)[:, None, None, :] * eye[None, :, :, None]
             + (s1[:, None] * u)[:, None, None, :] * yy[..., None] + s0[:, None, None, None] * sym)
    if order < 2:
        return field, first
    uu = u[:, :, None] * u[:, None, :]  # [i, k, l]
    du = (eye - uu) / d[:, None, None]  # d u_k / d y_l
    second = ((p2[:, None, None] * uu + p1[:, None, None] * du)[:, None, None] * eye[None, :, :, None, None]
              + (s2[:, None, None] * uu + s1[:, None, None] * du)[:, None, None] * yy[..., None, None])
    second += s1[:, None, None, None, None] * (u[:, None, None, :, None] * sym[:, :, :, None, :]
                                                + u[:, None, None, None, :] * sym[:, :, :, :, None])
    ekel = eye[:, None, :, None] * eye[None, :, None, :]  # (e_k e_l^T)_ab as [k, l, a, b]
    second += s0[:, None, None, None, None] * np.transpose(ekel + np.swapaxes(ekel, 2, 3), (2, 3, 0, 1))
    return field, first, second


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

    def symmetric_whitening(self, y, order: int = 0):
        r""":math:`W = \Sigma^{-1/2}` (n, 3, 3) [1/m], symmetric, and its derivatives in ``y``.

        .. math::
            W = \beta(d)\,I + (\alpha(d) - \beta(d))\,u u^\top,\qquad
            \alpha = (\sigma_r^2 + \rho^2)^{-1/2},\quad \beta = (\sigma_t^2 + \rho^2)^{-1/2},

        so :math:`W^\top W = \Sigma^{-1}` (it differs from :meth:`whitening`, the
        inverse Cholesky factor, by a rotation per position, which leaves
        :math:`F^\top F` unchanged). The design objective uses it for its closed-form
        derivatives (:func:`_radial_field`): ``order`` 1 adds :math:`\partial W/\partial y_k`
        (n, 3, 3, 3) [i, a, b, k] [1/m²], ``order`` 2 also
        :math:`\partial^2 W/\partial y_k\partial y_l` (n, 3, 3, 3, 3) [1/m³].

        Returns:
            ``(W, dW or None, ddW or None)``.
        """
        y, d, u = self._geometry(y)
        (r0, r1), (t0, t1) = self.radial, self.lateral
        rho2 = self.repeatability**2
        alpha = _inverse_sqrt(r0 + r1 * d, r1, rho2)
        beta = _inverse_sqrt(t0 + t1 * d, t1, rho2)
        diff = tuple(x - z for x, z in zip(alpha, beta, strict=True))
        out = _radial_field(y, d, u, beta, _over_d2(diff, d), order)
        return out[0], (out[1] if order >= 1 else None), (out[2] if order >= 2 else None)

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
