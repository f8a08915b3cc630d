r"""Stacking measurement models into the weighted sensitivity matrix :math:`F_1`.

For measurement models :math:`h^{(1)}, \dots, h^{(M)}` evaluated at the same n
configurations, rows are ordered model-major, then configuration, then
component:

.. math::
    F_1 = \Sigma^{-1} \frac{\partial h}{\partial p} \in \mathbb{R}^{m \times n_p},
    \qquad m = n \sum_k d_k,

with :math:`\Sigma = \mathrm{diag}(\sigma)` (paper eq. 6 and 24d). Multiplying
by :math:`\Sigma^{-1}` makes the rows dimensionless, so :math:`F_1` has units
[1/unit of the parameter] per column. Every model is whitened per configuration by
its noise contract, :math:`L_i^{-1}` with :math:`\Sigma_i = L_i L_i^\top`
(``model.noise_whitening``: :math:`\mathrm{diag}(1/\sigma)` for independent
components, the tracker error model's factor evaluated at the state's positions
:math:`h(p, q_i)` otherwise).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib_oed.measurement.base import MeasurementModel, SetupState, evaluate_setup
from calib_oed.model.parameters import ParameterSpace


def stacked_values(models: Sequence[MeasurementModel], state: SetupState) -> np.ndarray:
    """Model responses of all models, stacked to a vector (m,)."""
    return np.concatenate([mdl.compute_values(state).ravel() for mdl in models])


def weighted_jacobian_from_state(
    models: Sequence[MeasurementModel], state: SetupState
) -> np.ndarray:
    r""":math:`F_1 = \Sigma^{-1}\partial h/\partial p` for an evaluated state, (m, n_p)."""
    blocks = []
    for mdl in models:
        jac = mdl.compute_param_jacobian(state)
        jac = np.einsum("nij,njk->nik", mdl.noise_whitening(mdl.compute_values(state)), jac)
        blocks.append(jac.reshape(-1, state.space.size))
    return np.concatenate(blocks, axis=0)


def weighted_jacobian(
    space: ParameterSpace,
    models: Sequence[MeasurementModel],
    q: np.ndarray,
    p: np.ndarray | None = None,
) -> np.ndarray:
    r"""One call for :math:`F_1` at configurations ``q`` (n, nq) and parameters ``p``.

    Runs the kinematics once for all models. ``p=None`` means nominal.
    """
    state = evaluate_setup(space, p, q, regressor=True, jacobian=False)
    return weighted_jacobian_from_state(models, state)
