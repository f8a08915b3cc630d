r"""Key performance indicators: the TCP position at working configurations.

For working configurations :math:`q^{work}_1..q^{work}_t` and a point
:math:`b` fixed on the tool (default the tool-frame origin), the KPI is

.. math::
    s_i = t_{W,F}(p, q^{work}_i) + R_{W,F}(p, q^{work}_i)\, b \in \mathbb{R}^3\;[\mathrm{m}]

in the world (= robot base) frame, or :math:`T_{W,T}(\delta_T)^{-1} s_i` in
the tracker frame. With ``reflector=j`` the point is the reflector centre
:math:`b = c_j(p)`. Its parameter Jacobian (paper's :math:`F_2` block of
:math:`\partial\,\mathrm{TCP}/\partial p`) is, in the world frame,

.. math::
    G = \frac{\partial s}{\partial p}, \qquad
    \frac{\partial s_i}{\partial \delta_j} = R\,[I\; -[b]_\times]\,K_{:,j}\,J_r(\delta_j),
    \qquad \frac{\partial s_i}{\partial \delta c_j} = R \;(\text{reflector KPI only});

in the tracker frame every row is premultiplied by :math:`R_T^\top` and the
tracker columns get :math:`[-I\;[s_i]_\times]J_r(\delta_T)`. Whether :math:`s` is determined by the measurements at all is
answered by :mod:`calib_oed.model.identifiability`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib_oed.exceptions import ShapeError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.model.parameters import ParameterSpace

FRAMES = ("world", "tracker")


class TcpKpi:
    """TCP position at t working configurations.

    Args:
        configurations: Working configurations (t, nq) [rad].
        point: Point on the tool in the tool frame (3,) [m].
        frame: ``"world"`` or ``"tracker"``.
        names: One name per working configuration.
        reflector: If given, the KPI point is this reflector's estimated centre
            :math:`c_j(p)` (its offset parameters enter :math:`G`) and
            ``point`` is ignored. In the tracker frame this KPI is a predicted
            measurement, hence estimable.
        weights: Weight >= 0 of each working configuration in the mean KPI
            variance (:meth:`calib_oed.oed.criteria.ACriterion.kpi`), (t,); None: all 1.
    """

    def __init__(
        self,
        configurations: np.ndarray,
        point: np.ndarray | None = None,
        frame: str = "world",
        names: Sequence[str] | None = None,
        reflector: int | None = None,
        weights: Sequence[float] | None = None,
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
        self.reflector = None if reflector is None else int(reflector)
        self.frame = frame
        self.names = tuple(names) if names is not None else tuple(f"work{i}" for i in range(len(q)))
        if len(self.names) != len(q):
            raise ShapeError("names", f"({len(q)},)", (len(self.names),))
        w = np.ones(len(q)) if weights is None else np.array(weights, dtype=float).reshape(-1)
        if w.shape != (len(q),):
            raise ShapeError("weights", f"({len(q)},)", w.shape)
        if not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
            raise ValueError(f"KPI weights must be finite, >= 0 and not all 0, got {w}")
        w.setflags(write=False)
        self.weights = w

    def in_frame(self, frame: str) -> TcpKpi:
        """The same KPI (configurations, point, names, weights) in ``frame``."""
        return TcpKpi(self.configurations, self.point, frame, self.names, self.reflector, self.weights)

    @property
    def dim(self) -> int:
        """Number of KPI components :math:`n_s = 3t`."""
        return 3 * self.configurations.shape[0]

    @property
    def labels(self) -> tuple[str, ...]:
        """Component labels ``"<name>.x"``."""
        return tuple(f"{n}.{c}" for n in self.names for c in "xyz")

    def _point(self, state) -> np.ndarray:
        return self.point if self.reflector is None else state.reflector_offset(self.reflector)

    def compute_values(self, space: ParameterSpace, p: np.ndarray | None = None) -> np.ndarray:
        """KPI values :math:`s`, (t, 3) [m]."""
        state = evaluate_setup(space, p, self.configurations, regressor=False, jacobian=False)
        return state.tool_point(self._point(state), self.frame)

    def compute_param_jacobian(
        self, space: ParameterSpace, p: np.ndarray | None = None
    ) -> np.ndarray:
        r""":math:`G = \partial s / \partial p`, (3t, n_p)."""
        state = evaluate_setup(space, p, self.configurations, regressor=True, jacobian=False)
        g = state.tool_point_param_jacobian(self._point(state), self.frame, self.reflector)
        return g.reshape(3 * state.n, space.size)

    def rows_in_tracker_frame(self, space: ParameterSpace, rows: np.ndarray,
                              p: np.ndarray | None = None) -> np.ndarray:
        r"""KPI rows (3t, k) turned into the tracker frame: :math:`R_T^\top` per point when the
        KPI is in the world frame (``p`` gives the tracker placement, None the nominal one),
        unchanged when it already is in the tracker frame.

        The model error is a Gaussian process of the measured positions in the tracker frame
        (:mod:`calib_oed.measurement.discrepancy`); a KPI error correlates with it component by
        component only in that frame.
        """
        rows = np.asarray(rows, dtype=float)
        if self.frame != "world":
            return rows
        rot = space.tracker_placement(p).rotation
        return np.einsum("ba,tbf->taf", rot, rows.reshape(-1, 3, rows.shape[1])).reshape(rows.shape)

