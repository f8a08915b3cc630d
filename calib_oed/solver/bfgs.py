r"""Damped BFGS update of the quasi-Newton Hessian of the Lagrangian (N&W §18.3).

"N&W": Nocedal & Wright, *Numerical Optimization*, 2nd ed., 2006. The SQP
(:mod:`calib_oed.solver.sqp`, item 3) keeps :math:`B \succ 0` through
Powell's damping, with the Shanno–Phua scaling before the first update.
"""

from __future__ import annotations

import numpy as np

from calib_oed.solver.qp import matvec


def damped_bfgs_update(B, s, y, damping=0.2, scale_first=False):
    r"""Damped BFGS update of :math:`B \succ 0` (N&W Procedure 18.2, Powell 1978).

    .. math::
        \theta = \begin{cases} 1 & s^\top y \ge \delta\, s^\top B s \\
        \dfrac{(1 - \delta)\, s^\top B s}{s^\top B s - s^\top y} & \text{otherwise,}\end{cases}
        \qquad r = \theta y + (1 - \theta) B s,

        B^+ = B - \frac{B s s^\top B}{s^\top B s} + \frac{r r^\top}{s^\top r},

    so that :math:`s^\top r \ge \delta\, s^\top B s > 0` and :math:`B^+ \succ 0`.
    With ``scale_first`` (first step), :math:`B` is first replaced by
    :math:`(y^\top y / s^\top y) I` when :math:`s^\top y > 0` (Shanno–Phua).
    Returns a new array; :math:`B` is unchanged if :math:`s^\top B s` is not positive.
    """
    sy = float(s @ y)
    if scale_first and sy > 0:
        B = np.eye(B.shape[0]) * float(np.clip(y @ y / sy, 1e-8, 1e8))
    Bs = matvec(B, s)
    sBs = float(s @ Bs)
    if not sBs > 0:
        return B
    theta = 1.0 if sy >= damping * sBs else (1.0 - damping) * sBs / (sBs - sy)
    r = theta * y + (1.0 - theta) * Bs
    B = B - np.outer(Bs, Bs) / sBs + np.outer(r, r) / float(s @ r)
    return 0.5 * (B + B.T)
