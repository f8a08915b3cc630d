r"""Laser tracker: the position of one reflector in tracker coordinates.

.. math::
    h(p, q) = {}^{T}c = T_{W,T}(\delta_T)^{-1}\,\big(t_{W,F}(q) + R_{W,F}(q)\,c_j\big)
    \in \mathbb{R}^3 \;[\mathrm{m}]

(paper eq. 3) with :math:`F` the tool frame, :math:`c_j = c^0_j + \delta c_j`
the reflector offset in :math:`F`. Sensitivities, with :math:`R_T` the tracker
rotation, :math:`K` the LOCAL regressor and :math:`J` the LOCAL Jacobian of
the tool frame:

.. math::
    \frac{\partial h}{\partial \delta_i} &= R_T^\top R\,[I\; -[c_j]_\times]\,K_{:,i}\,J_r(\delta_i),\\
    \frac{\partial h}{\partial \delta c_j} &= R_T^\top R,\qquad
    \frac{\partial h}{\partial \delta_T} = [-I\;\; [h]_\times]\,J_r(\delta_T),\\
    \frac{\partial h}{\partial q} &= R_T^\top R\,[I\; -[c_j]_\times]\,J .
"""

from __future__ import annotations

import numpy as np

from calib_oed.measurement.base import MeasurementModel, SetupState
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.measurement.second_order import tool_point_param_config_hessian, with_joint_gains

#: Default laser-tracker noise per axis [m] (0.01 mm).
DEFAULT_SIGMA = 1e-5


class TrackerPosition(MeasurementModel):
    r"""Reflector position measured by a laser tracker.

    Args:
        reflector: Index j of the reflector (0-based).
        sigma: Noise standard deviation per tracker axis [m], scalar or (3,).
        noise: Optional full error model (:class:`~calib_oed.measurement.noise.TrackerNoise`:
            range-dependent radial/lateral noise and robot repeatability). When given,
            identification, covariance and simulation use its 3×3 covariance
            :math:`\Sigma_i` instead of ``sigma``, and so does the design objective
            (:mod:`calib_oed.oed.whitening`).
    """

    dim = 3
    labels = ("x", "y", "z")
    units = ("m", "m", "m")

    def __init__(self, reflector: int = 0, sigma: float | np.ndarray = DEFAULT_SIGMA,
                 noise: TrackerNoise | None = None):
        super().__init__(sigma)
        self.reflector = int(reflector)
        if noise is not None and not isinstance(noise, TrackerNoise):
            raise TypeError(f"noise: expected a TrackerNoise or None, got {type(noise).__name__}")
        self.noise = noise

    @property
    def name(self) -> str:
        return f"reflector{self.reflector}"

    def compute_values(self, state: SetupState) -> np.ndarray:
        return state.tool_point(state.reflector_offset(self.reflector), "tracker")

    def compute_param_jacobian(self, state: SetupState) -> np.ndarray:
        offset = state.reflector_offset(self.reflector)
        return state.tool_point_param_jacobian(offset, "tracker", reflector=self.reflector)

    def compute_config_jacobian(self, state: SetupState) -> np.ndarray:
        return state.tool_point_config_jacobian(state.reflector_offset(self.reflector), "tracker")

    def compute_param_config_jacobian(self, state: SetupState) -> np.ndarray:
        offset = state.reflector_offset(self.reflector)
        return state.tool_point_param_config_jacobian(offset, "tracker", reflector=self.reflector)

    def compute_param_config_hessian(self, state: SetupState, out: np.ndarray | None = None
                                     ) -> np.ndarray | None:
        """Second configuration derivative of the rows (:mod:`~calib_oed.measurement.second_order`).

        None with compliance; ``out``: a zeroed (n, 3, n_p, nv, nv) array to write into.
        """
        if not state.rigid:
            full = with_joint_gains(self, state)
            if out is None or full is None:
                return full
            out[...] = full
            return out
        offset = state.reflector_offset(self.reflector)
        return tool_point_param_config_hessian(state, offset, "tracker", reflector=self.reflector,
                                               out=out)
