r"""Measured data of one session as a record: :class:`MeasurementSet` (SI, read-only arrays).

What a measurement file holds (format: :mod:`calib_oed.io.measurement_format`)
once read, or what a simulation produces: configurations, reflector indices,
measured positions (and probe rotations) in the tracker frame, optional
per-row sigmas, and where each row came from. :meth:`MeasurementSet.blocks`
turns it into the :class:`~calib_oed.measurement.observations.ObservationBlock`
list the estimator consumes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.measurement.error_model import ErrorModel
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.measurement.pose import DEFAULT_SIGMA_ANGLE
from calib_oed.measurement.position import DEFAULT_SIGMA
from calib_oed.model.robot import Robot
from calib_oed.values import readonly


@dataclass(frozen=True, eq=False)
class MeasurementSet:
    """Measured rows of one session, SI throughout; arrays are read-only.

    Attributes:
        joint_names: The robot's joints, base to tip (columns of ``q``).
        q: Configurations, (n, nq) [rad, or m for prismatic joints].
        reflector: Reflector index of each row, (n,) int, 0-based.
        positions: Measured reflector centres in the tracker frame, (n, 3) [m].
        rotations: Measured probe rotation vectors :math:`\\log_3 R_{T,P}`, (n, 3)
            [rad], or ``None`` for position-only data.
        sigma: Standard deviation of each position coordinate per row, (n,) [m],
            or ``None`` to use the measurement model's.
        source: Where the rows came from (file name, ``"<string>"``, ``"<arrays>"``).
        lines: 1-based line number of each row in ``source`` (for arrays: the row
            number), (n,) int.
    """

    joint_names: tuple[str, ...]
    q: np.ndarray
    reflector: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray | None = None
    sigma: np.ndarray | None = None
    source: str = "<arrays>"
    lines: np.ndarray | None = None

    def __post_init__(self):
        names = tuple(str(j) for j in self.joint_names)
        q = np.array(self.q, dtype=float)
        if q.ndim != 2 or q.shape[0] < 1 or q.shape[1] != len(names):
            raise ShapeError("q", f"(n, {len(names)}) with n >= 1", q.shape)
        n = q.shape[0]
        positions = _finite(self.positions, "positions", (n, 3))
        rotations = None if self.rotations is None else _finite(self.rotations, "rotations", (n, 3))
        _finite(q, "q", q.shape)
        refl = np.asarray(self.reflector)
        if refl.shape != (n,):
            raise ShapeError("reflector", f"({n},)", refl.shape)
        if refl.dtype.kind not in "iuf" or np.any(np.mod(refl, 1) != 0):
            raise ValueError(f"reflector: expected integer indices, got {refl}")
        refl = refl.astype(np.int64)
        if np.any(refl < 0):
            raise ValueError(f"reflector: indices must be >= 0, got rows "
                             f"{np.flatnonzero(refl < 0).tolist()}")
        sigma = None
        if self.sigma is not None:
            sigma = np.asarray(self.sigma, dtype=float)
            sigma = _finite(np.full(n, sigma) if sigma.ndim == 0 else sigma, "sigma", (n,))
            if np.any(sigma <= 0):
                raise ValueError(f"sigma: every standard deviation must be > 0, rows "
                                 f"{np.flatnonzero(sigma <= 0).tolist()} are not")
        lines = np.arange(1, n + 1) if self.lines is None else np.asarray(self.lines, np.int64)
        if lines.shape != (n,):
            raise ShapeError("lines", f"({n},)", lines.shape)
        for name, value in (("joint_names", names), ("q", q), ("reflector", refl),
                            ("positions", positions), ("rotations", rotations),
                            ("sigma", sigma), ("lines", lines)):
            object.__setattr__(self, name, value if value is None or name == "joint_names"
                               else readonly(value))

    @classmethod
    def from_arrays(
        cls,
        robot: Robot,
        q: np.ndarray,
        positions: np.ndarray,
        reflector: np.ndarray | int | None = None,
        sigma: np.ndarray | float | None = None,
        rotations: np.ndarray | None = None,
        source: str = "<arrays>",
    ) -> MeasurementSet:
        """A set from SI arrays: ``q`` (n, nq) in ``robot``'s joint order, ``positions`` (n, 3) [m].

        ``reflector`` (n,) or a scalar (default 0), ``sigma`` (n,) or a scalar [m],
        ``rotations`` (n, 3) [rad]. Joint limits are not checked here.

        Raises:
            ShapeError, NonFiniteError: arrays of the wrong shape or not finite.
            ValueError: negative reflector index, non-positive sigma.
        """
        q = robot.check_configurations(q)
        n = q.shape[0]
        refl = np.broadcast_to(np.asarray(0 if reflector is None else reflector), (n,))
        return cls(robot.joint_names, q, refl, np.array(positions, float, ndmin=2),
                   None if rotations is None else np.array(rotations, float, ndmin=2),
                   sigma, source)

    @property
    def n(self) -> int:
        """Number of rows."""
        return self.q.shape[0]

    @property
    def reflectors(self) -> tuple[int, ...]:
        """The reflector indices present, ascending (the order of :meth:`blocks`)."""
        return tuple(int(j) for j in np.unique(self.reflector))

    def blocks(
        self,
        sigma: float | np.ndarray = DEFAULT_SIGMA,
        sigma_angle: float | np.ndarray = DEFAULT_SIGMA_ANGLE,
        noise: TrackerNoise | None = None,
        *,
        error_model: ErrorModel | None = None,
    ) -> list[ObservationBlock]:
        """One observation block per reflector present, in :attr:`reflectors` order.

        The measurement models come from ``error_model`` (the scene's
        ``scene.error_model()``; its kind follows the rows: position rows give
        ``TrackerPosition`` blocks, pose rows ``PoseMeasurement`` blocks with values
        ``(x, y, z, rx, ry, rz)``), or, without it, from ``sigma``, ``sigma_angle``
        and ``noise``. Each block keeps the rows of its reflector in file order
        (their lines: ``self.lines[self.reflector == j]``). The per-row :attr:`sigma`,
        when present, replaces ``sigma`` on the position components; ``sigma_angle``
        always applies to the rotation components.

        Args:
            sigma: Position noise per tracker axis [m], scalar or (3,).
            sigma_angle: Rotation noise per axis [rad], scalar or (3,) (pose rows only).
            noise: Full error model of position rows (``scene.position_noise()``); when
                given, the fit whitens with its covariance, unless the set has per-row
                :attr:`sigma` (a file's ``sigma`` column): the file's own statement of each
                measurement's uncertainty wins (covariance sigma_i^2 I_3), and
                ``noise`` is not used.
            error_model: The whole contract instead of the three above (the per-row
                :attr:`sigma` wins over its tracker model in the same way).

        Raises:
            ParameterError: ``noise`` with pose rows (it models positions only).
        """
        pose = self.rotations is not None
        if error_model is None:
            error_model = ErrorModel("pose" if pose else "position", sigma, sigma_angle, noise)
        else:
            error_model = error_model.for_rows(pose)
        if self.sigma is not None and error_model.noise is not None:
            error_model = replace(error_model, noise=None)  # the per-row sigma is each row's covariance
        out = []
        for j, model in zip(self.reflectors, error_model.models(self.reflectors), strict=True):
            rows = self.reflector == j
            values = self.positions[rows] if not pose else np.hstack([self.positions[rows],
                                                                     self.rotations[rows]])
            row_sigma = None
            if self.sigma is not None:
                row_sigma = np.tile(model.sigma, (int(rows.sum()), 1))
                row_sigma[:, :3] = self.sigma[rows, None]
            out.append(ObservationBlock(model, self.q[rows], values, row_sigma))
        return out


def _finite(value: Any, what: str, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.shape != tuple(shape):
        raise ShapeError(what, str(tuple(shape)), arr.shape)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(arr)).tolist())
    return arr
