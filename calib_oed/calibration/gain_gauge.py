r"""The gauge rule on the measured poses, for joint gains and coupling ratios.

The gauge rule (:mod:`calib_oed.model.identifiability`) decides once, on a
generic design uniform in the joint limits, which parameters are free. That is
right for the geometry, which any spread of poses determines, but a gain's
column :math:`(\partial h/\partial q_i)\,q_i` differs from its joint offset's
only through the spread of :math:`q_i` in the data (:mod:`calib_oed.model.joint_map`):
a data set that holds a joint still cannot separate its gain, even though the
generic design can. So :func:`calib_oed.calibration.identification.identify`
runs the same rule again on the data's own unit-scaled Jacobian over the free
parameters and holds at nominal (and reports) every gain or coupling ratio the
data cannot separate. Geometric parameters keep the generic decision (a data
set that cannot determine them is still an error, ``NotIdentifiableError``).
"""

from __future__ import annotations

import numpy as np

from calib_oed.model.identifiability import FixedParameter, select_gauge
from calib_oed.model.parameters import ParameterSpace


def gains_the_data_fix(space: ParameterSpace, scaled_jacobian: np.ndarray,
                       free: np.ndarray) -> list[FixedParameter]:
    """The free gains and coupling ratios that the data cannot separate, in parameter order.

    Args:
        space: The parameter layout.
        scaled_jacobian: :math:`F_1 D` of the data on the ``free`` columns, (m, len(free)).
        free: Indices of the free parameters, ascending.
    """
    if space.joint_gains is None:
        return []
    report = select_gauge(scaled_jacobian, [space.names[i] for i in free])
    start = space.gain_slice.start
    return [f for f in report.fixed if space.index(f.name) >= start]
