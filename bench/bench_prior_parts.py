"""What the design prior predicts of each part of the realistic model error, against what it does.

For one scene and seed: the default ``kpi_model`` design of n poses (the library's joint-space
prior), then, part by part, the KPI error variance the prior predicts at that design (the
``kpi_model`` value of the prior with only that part, minus the noise-only ``kpi``) against the
variance the calibrated robot shows on realistic truths (:mod:`calib_oed.calibration.realistic`)
that carry only that part, **noise-free** (every other part switched off, the geometric errors
kept: the fit is linear in the errors, so the variance is that part's alone). Every truth is
the same draw with one switch changed (``sample_truth`` draws every part whether on or not).

Parts: ``transmission`` (``periodic``: once and twice per joint revolution; ``motor``: per motor
revolution), ``compliance`` (gravity with the J2 balancer), ``gains``, ``tracker`` (the
tracker's scale and encoder systematics: no part of the prior), ``all`` (every part on, the
scene's defaults). The compliance part is predicted twice more: with the arm loaded without the
reflector nest (``compliance, no nest``) and with it (``compliance, nest``, the realistic
simulator's nest mass at the reflectors' centroid), whichever the library's default does.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python bench/bench_prior_parts.py --scene SCENE [-n 60] [--seed 0] [--truths 40]
        [--level F] [--no-balancer]

``--level F`` scales every unmodelled part of the truths (the simulator's ``level``; the prior's
prediction scales with F², so the ratios are those of the linear regime when F is small; the J2
balancer's deflection, its torque times the compliance, scales with F²);
``--no-balancer`` leaves the J2 balancer out of the compliance part's truths.

Prints one JSON line: per part the predicted and achieved variance [mm²], the achieved one's
standard error over truths and their ratio.
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np

import calib_oed.calibration.realistic_measure as realistic_measure
from calib_oed import load_scene
from calib_oed.calibration.identification import identify
from calib_oed.calibration.joint_prior_choice import joint_prior
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_defaults import realistic_settings_from_scene
from calib_oed.calibration.workflow import setup
from calib_oed.model.compliance import Compliance, GravityLoad
from calib_oed.oed.design import design
from calib_oed.oed.model_error import scene_criterion
from calib_oed.oed.objective import DesignObjective

OFF = {"compliance": False, "transmission": False, "gains": False, "balancer": False, "tracker": False}
TRUTHS = {"all": {}, "transmission": {**OFF, "transmission": True},
          "periodic": {**OFF, "transmission": True, "motor_cyclic": (0.0, 0.0)},
          "motor": {**OFF, "transmission": True, "joint_cyclic": (0.0, 0.0)},
          "compliance": {**OFF, "compliance": True, "balancer": True}, "gains": {**OFF, "gains": True},
          "tracker": {**OFF, "tracker": True}}


def part_priors(s, prior) -> dict:
    """The prior with one part at a time (the others zero), keyed as :data:`TRUTHS`."""
    z = np.zeros(prior.nq)
    only = {"periodic": dict(compliance=z, gain=z, motor=0.0), "motor": dict(compliance=z, gain=z, once=z, twice=z),
            "transmission": dict(compliance=z, gain=z),
            "compliance": dict(once=z, twice=z, gain=z, motor=0.0), "gains": dict(once=z, twice=z, compliance=z, motor=0.0)}
    out = {"all": prior, **{k: dataclasses.replace(prior, **v) for k, v in only.items()}}
    robot, space = s.problem.robot, s.problem.space
    payload = getattr(space, "compliance", None) or Compliance()
    loaded = payload.with_nest(realistic_settings_from_scene(s.scene).nest_mass,
                               np.mean(space.reflector_offsets(None), axis=0))
    for name, load in (("compliance, no nest", payload), ("compliance, nest", loaded)):
        out[name] = dataclasses.replace(out["compliance"], gravity=GravityLoad(robot.model, robot.tool_frame_id, load))
    return out


def achieved(s, q, switches: dict, truths: int, seed: int, level: float = 1.0) -> np.ndarray:
    """Mean squared KPI error per truth [mm²], noise-free readings of truths with ``switches``."""
    problem, space = s.problem, s.problem.space
    settings = dataclasses.replace(realistic_settings_from_scene(s.scene), **{"level": level, **switches})
    free = problem.identifiability.free_indices
    w = problem.kpi.weights
    w = np.ones(len(problem.kpi.configurations)) if w is None else np.asarray(w, dtype=float)
    out = np.zeros(truths)
    for k in range(truths):
        truth = sample_truth(s, np.random.default_rng([seed, k]), settings)
        meas = realistic_measure.measure(truth, problem.models, q, np.random.default_rng([seed, k, 0, 1]))
        p_hat = identify(space, meas.blocks, free).p
        err = (problem.kpi.compute_values(space, p_hat) - truth.compute_kpi_values(problem.kpi)) * 1e3
        out[k] = float(w @ np.sum(err**2, axis=1) / (3 * w.sum()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", required=True)
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--truths", type=int, default=40)
    ap.add_argument("--level", type=float, default=1.0, help="scale of the truths' unmodelled parts")
    ap.add_argument("--no-balancer", action="store_true", help="no J2 balancer in the compliance truths")
    a = ap.parse_args()
    truths = {k: ({**v, "balancer": False} if a.no_balancer else v) for k, v in TRUTHS.items()}
    s = setup(load_scene(a.scene))
    prior = joint_prior(s.problem)
    d = design(s, a.n, scene_criterion(s, "kpi_model", prior), seed=a.seed, certificate=False)
    realistic_measure.add_noise = lambda mdl, y, rng: y.copy()  # noise-free: the model error alone
    base = achieved(s, d.q, {"level": 0.0}, a.truths, a.seed)   # the geometric errors alone: ~0
    noise_only = DesignObjective(s.problem, "kpi").compute_value(d.q)
    row = {"scene": s.scene.name, "n": a.n, "seed": a.seed, "truths": a.truths, "prior": prior.describe(),
           "predicted_rms_mm": float(np.sqrt(d.criteria["kpi_model"])), "geometric_only_mm2": float(base.mean()),
           "level": a.level, "balancer": not a.no_balancer}
    seen: dict[str, np.ndarray] = {}
    for name, pr in part_priors(s, prior).items():
        truth_name = name.split(",")[0]
        if truth_name not in seen:
            seen[truth_name] = achieved(s, d.q, truths[truth_name], a.truths, a.seed, a.level) - base
        got = seen[truth_name]
        pred = a.level**2 * (DesignObjective(s.problem, "kpi_model", model_error=pr).compute_value(d.q) - noise_only)
        row[name] = {"predicted_mm2": pred, "achieved_mm2": float(got.mean()),
                     "achieved_se_mm2": float(got.std(ddof=1) / np.sqrt(got.size)), "ratio": float(got.mean() / pred)}
    got = achieved(s, d.q, truths["tracker"], a.truths, a.seed, a.level) - base
    row["tracker"] = {"predicted_mm2": 0.0, "achieved_mm2": float(got.mean()),
                      "achieved_se_mm2": float(got.std(ddof=1) / np.sqrt(got.size))}
    print(json.dumps(row))


if __name__ == "__main__":
    main()
