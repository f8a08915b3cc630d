"""06 — Sequential calibration as a cell controller runs it: measure until the TCP is precise enough.

Instead of fixing the number of poses beforehand, the controller asks
calib_oed for the next few poses, measures them, re-identifies, and stops as
soon as the predicted KPI standard deviation at the estimate reaches the
target (docs/oed.md, "Sequential design"). Here a simulated robot on the
shipped scene ``fms_kr16`` stands in for the real one:

1. measure the KPI-optimal design of the fewest poses that identify the
   parameters (9 poses of 3 values for 25 free parameters);
2. loop: identify from all data so far; if the predicted KPI σ at the estimate
   is at most 5 µm, stop; else ask ``SequentialDesigner.propose`` for the next
   3 poses, starting near the robot's current pose, and measure them.

Checks: the loop stops at the target and not before; every proposed pose
satisfies every feasibility row (joint limits, incidence, collisions, beam);
the predicted σ never rises; the TCP error against the simulated truth is
consistent with the prediction (below 4 σ).

Run: .venv/bin/python examples/06_sequential_cell.py   (about 30 s of CPU)
"""

from __future__ import annotations

import numpy as np

from calib_oed import (
    SequentialDesigner,
    design,
    draw_true_parameters,
    identify,
    load_scene,
    setup,
    simulate_observations,
    tcp_errors,
)
from calib_oed.solver.sqp import SQPSettings

TARGET_MM = 0.005
BATCH = 3


def main() -> None:
    s = setup(load_scene("fms_kr16"))
    problem = s.problem
    space, report = problem.space, problem.identifiability
    rng = np.random.default_rng(7)
    p_true = draw_true_parameters(space, report.free_indices, rng)  # the robot we pretend to have

    def measure(q):  # what the tracker would return for poses q
        return simulate_observations(space, problem.models, q, p_true, rng)

    q = design(s, 9, "kpi", seed=0, settings=SQPSettings(max_iterations=40), certificate=False).q  # first poses
    data = measure(q)
    designer = SequentialDesigner(s, TARGET_MM, batch=BATCH, seed=0)
    history = []
    while True:
        p_hat = np.asarray(identify(space, data, report).p)
        sigma = designer.predicted_sigma_mm(q, p_hat).max()
        history.append((len(q), sigma))
        print(f"{len(q):3d} poses measured: predicted KPI sigma {sigma:.5f} mm")
        if designer.done(q, p_hat) or len(q) >= 60:
            break
        q_next = designer.propose(q, p_hat, current_pose=q[-1])
        if not s.feasibility.compute(q_next, jacobian=False).feasible.all():
            raise SystemExit("a proposed pose is not feasible")
        data = data + measure(q_next)
        q = np.vstack([q, q_next])

    sigmas = [h[1] for h in history]
    if not (sigmas[-1] <= TARGET_MM < min(sigmas[:-1])):
        raise SystemExit(f"the loop did not stop at the target: {sigmas}")
    if any(b > a for a, b in zip(sigmas[:-1], sigmas[1:], strict=True)):
        raise SystemExit(f"the predicted sigma rose: {sigmas}")
    error_mm = float(np.linalg.norm(tcp_errors(s, p_true, p_hat, s.problem.kpi.frame), axis=1).max() * 1e3)
    # |e|^2 / sigma^2 is about chi-square with 3 degrees of freedom (sigma per axis): 4 sigma is generous
    if error_mm > 4 * np.sqrt(3) * sigmas[-1]:
        raise SystemExit(f"TCP error {error_mm:.4f} mm is not consistent with sigma {sigmas[-1]:.4f} mm")
    print(f"stopped after {len(q)} poses at sigma {sigmas[-1]:.5f} mm <= {TARGET_MM} mm; "
          f"TCP error against the simulated truth {error_mm:.5f} mm")


if __name__ == "__main__":
    main()
