r"""Which reflectors (SMRs) of a nest the tracker sees at each pose.

A reflector :math:`j` is *visible* at pose :math:`q` when its visibility rows of
the feasibility model hold with a margin :math:`m \ge 0`: its incidence row
(only for ``aim: fixed``; a manually aimed SMR has none) and every beam row of
its laser line ``laser(<name>)`` against the robot and the cell,

.. math::
    v_j(q) = \big[\min_{r \in R_j} g_r(q) \ge m\big],

:math:`R_j` those rows (values in m for beam rows, cosine units for the
incidence row, as the rows themselves). Designs keep every SMR visible at every
pose (their constraint rows); a given design of poses where an SMR is hidden is
measured (simulated) and identified from the SMRs it sees
(:func:`calib_oed.calibration.simulation.simulate_observations`, ``visible``).
"""

from __future__ import annotations

import numpy as np

from calib_oed.feasibility.constraints import FEASIBILITY_TOL, FeasibilityModel


def reflector_rows(model: FeasibilityModel) -> list[np.ndarray]:
    """Indices of each reflector's visibility rows (its incidence row, its beam rows)."""
    return [np.flatnonzero(model.row_reflectors == j) for j in range(len(model.reflector_names))]


def visible_reflectors(model: FeasibilityModel, q: np.ndarray, margin: float = -FEASIBILITY_TOL) -> np.ndarray:
    """(n, k) bool: reflector j's visibility rows hold with ``margin`` at pose i of ``q`` (n, nq).

    The default margin accepts the rows' feasibility tolerance; give ``margin`` > 0
    [m, or cosine units for incidence] to keep only SMRs seen with room to spare.
    """
    values = model.compute_values(q)
    out = np.ones((values.shape[0], len(model.reflector_names)), dtype=bool)
    for j, rows in enumerate(reflector_rows(model)):
        if rows.size:
            out[:, j] = values[:, rows].min(axis=1) >= margin
    return out
