"""Seeded random feasible configurations (the paper's heuristic designs).

Configurations are drawn uniformly in the joint ranges and kept if every
constraint holds, so the result is uniform on the feasible set. The incidence
limit alone keeps only about 1 in 500 draws of a 6R arm, so draws are
evaluated in large batches: forward kinematics once per draw, then the cheap
joint and incidence rows on the whole batch, and the capsule pairs only on the
survivors.
"""

from __future__ import annotations

import numpy as np

from calib_oed.exceptions import SamplingError
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.constraints import FeasibilityModel


def sample_feasible(
    model: FeasibilityModel,
    n: int,
    rng: np.random.Generator | int,
    *,
    batch: int = 4096,
    max_draws: int = 500_000,
) -> np.ndarray:
    """``n`` feasible configurations, uniform on the feasible set, (n, nq).

    Args:
        model: The constraints.
        n: How many configurations.
        rng: Seed or generator (same seed, same configurations).
        batch: Draws evaluated together.
        max_draws: Give up after this many draws.

    Raises:
        SamplingError: fewer than ``n`` feasible configurations in ``max_draws``
            draws (the message gives the acceptance rate found).
    """
    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    rng = np.random.default_rng(rng)
    robot = model.robot
    found: list[np.ndarray] = []
    count, draws = 0, 0
    rejected = {kind: 0 for kind in model.kind_slices()}
    while count < n:
        if draws >= max_draws:
            worst = ", ".join(f"{kind} {k / draws:.1%}" for kind, k in
                              sorted(rejected.items(), key=lambda kv: -kv[1]) if k)
            raise SamplingError(
                f"only {count} of {n} feasible configurations in {draws} uniform draws "
                f"(acceptance {count / max(draws, 1):.2e}); share of draws rejected by each "
                f"constraint kind (self, obstacle and beam are only evaluated on draws that pass "
                f"the joint and incidence rows): {worst}. Loosen those constraints or their margins in the scene's feasibility "
                "block, or check the cell (tracker visible from the working volume?)"
            )
        q = rng.uniform(robot.lower, robot.upper, size=(batch, robot.nq))
        draws += batch
        states = compute_body_states(robot.model, q, jacobian=False)
        cheap = model.compute_from_states(q, states, jacobian=False, kinds=("joint", "incidence"))
        for kind in ("joint", "incidence"):
            cols = [i for i, k in enumerate(cheap.kinds) if k == kind]
            if cols:
                rejected[kind] += int(np.any(cheap.values[:, cols] < 0, axis=1).sum())
        idx = np.flatnonzero(cheap.feasible)
        if idx.size == 0:
            continue
        full = model.compute_from_states(q[idx], states.take(idx), jacobian=False)
        for kind in ("self", "obstacle", "beam"):
            cols = [i for i, k in enumerate(full.kinds) if k == kind]
            if cols:
                rejected[kind] += int(np.any(full.values[:, cols] < 0, axis=1).sum())
        ok = idx[full.feasible]
        found.append(q[ok])
        count += ok.size
    return np.concatenate(found, axis=0)[:n] if found else np.zeros((0, robot.nq))
