r"""Key performance indicators: the TCP position at working configurations.

For working configurations :math:`q^{work}_1..q^{work}_t` and a point
:math:`b` fixed on the tool (default the tool-frame origin), the KPI is

.. math::
    s_i = t_{W,F}(p, q^{work}_i) + R_{W,F}(p, q^{work}_i)\, b \in \mathbb{R}^3\;[\mathrm{m}]

in the world (= robot base) frame, or :math:`T_{W,T}(\delta_T)^{-1} s_i` in
the tracker frame. Its parameter Jacobian (paper's :math:`F_2` block of
:math:`\partial\,\mathrm{TCP}/\partial p`) is

.. math::
    G = \frac{\partial s}{\partial p}, \qquad
    \frac{\partial s_i}{\partial \delta_j} = R\,[I\; -[b]_\times]\,K_{:,j}\,J_r(\delta_j)

(plus :math:`[-I\;[s_i]_\times]J_r(\delta_T)` on the tracker columns in the
tracker frame). Whether :math:`s` is determined by the measurements at all is
answered by :mod:`calib_oed.identifiability`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib_oed.exceptions import ShapeError
from calib_oed.measurements.base import evaluate_setup
from calib_oed.parameters import ParameterSpace

FRAMES = ("world", "tracker")


class TcpKpi:
    """TCP position at t working configurations.

    Args:
        configurations: Working configurations (t, nq) [rad].
        point: Point on the tool in the tool frame (3,) [m].
        frame: ``"world"`` or ``"tracker"``.
        names: One name per working configuration.
    """

    def __init__(
        self,
        configurations: np.ndarray,
        point: np.ndarray | None = None,
        frame: str = "world",
        names: Sequence[str] | None = None,
    ):
        q = np.atleast_2d(np.asarray(configurations, dtype=float))
        if q.ndim != 2:
            raise ShapeError("configurations", "(t, nq)", q.shape)
        b = np.zeros(3) if point is None else np.asarray(point, dtype=float)
        if b.shape != (3,):
            raise ShapeError("point", "(3,)", b.shape)
        if frame not in FRAMES:
            raise ValueError(f"frame must be one of {FRAMES}, got {frame!r}")
        self.configurations = q
        self.point = b
        self.frame = frame
        self.names = tuple(names) if names is not None else tuple(f"work{i}" for i in range(len(q)))
        if len(self.names) != len(q):
            raise ShapeError("names", f"({len(q)},)", (len(self.names),))

    @property
    def dim(self) -> int:
        """Number of KPI components :math:`n_s = 3t`."""
        return 3 * self.configurations.shape[0]

    @property
    def labels(self) -> tuple[str, ...]:
        """Component labels ``"<name>.x"``."""
        return tuple(f"{n}.{c}" for n in self.names for c in "xyz")

    def compute_values(self, space: ParameterSpace, p: np.ndarray | None = None) -> np.ndarray:
        """KPI values :math:`s`, (t, 3) [m]."""
        state = evaluate_setup(space, p, self.configurations, regressor=False, jacobian=False)
        s = state.kin.points(self.point)
        if self.frame == "tracker":
            s = (s - state.tracker.translation) @ state.tracker.rotation
        return s

    def compute_param_jacobian(
        self, space: ParameterSpace, p: np.ndarray | None = None
    ) -> np.ndarray:
        r""":math:`G = \partial s / \partial p`, (3t, n_p)."""
        state = evaluate_setup(space, p, self.configurations, regressor=True, jacobian=False)
        t = state.n
        out = np.zeros((t, 3, space.size))
        d_eps = state.kin.point_sensitivity(self.point, "regressor")
        if self.frame == "tracker":
            rt = state.tracker.rotation
            d_eps = rt.T @ d_eps
            s = (state.kin.points(self.point) - state.tracker.translation) @ rt
            out[:, :, space.tracker_slice] = state.tracker_point_sensitivity(s)
        out[:, :, space.joints_slice] = state.joint_param_sensitivity(d_eps)
        return out.reshape(3 * t, space.size)
