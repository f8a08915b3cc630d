"""The KPI criterion under model error against today's noise-only design, on the realistic simulator.

For each scene: the noise-only KPI design (criterion ``kpi``) and the model-error design
(``kpi_model``, the scene's prior or the default: the joint-space prior of
:mod:`calib_oed.measurement.joint_prior`) of n poses from the same seed; then the
whole loop on the realistic simulator (:mod:`calib_oed.calibration.realistic`): for each of
``--truths`` true robots and ``--noise`` noise draws, simulated tracker data at each design's
poses, an identification (``identify``, linear loss) and the TCP error at the working
configurations. **Paired**: both designs meet the same truths and the same noise draws, so
their ratio is judged per truth; its standard error is a seeded bootstrap over truths.

``--model compliance`` identifies joint compliance with the scene's own ``robot.compliance``
payload (what ``--compliance`` does; ``fms_kr300``, ``fms_kr500``). ``--model extended``
identifies joint compliance under gravity (payload: the reflector nest of the simulator at the
reflectors' centroid) and a gain for every joint as well (scene keys
``robot.compliance`` and ``robot.joint_gains``), so the designs and the fit have those
parameters; ``rigid`` (default) the scene as it is. ``--compensate`` also reports the
calibration plus the model error's conditional mean at the working configurations
(:func:`calib_oed.calibration.prediction.compensation`, the scene's prior).

Reports per design the achieved KPI error (RMS per axis over truths, noise draws and the
weighted working configurations, mm) with its standard error, the paired ratio to ``kpi``,
its predicted value (sqrt of ``kpi_model``), distinct joint vectors and arm positions, and the
design CPU time (``solver.cpu_seconds``, one BLAS thread).

    nice -n 10 python bench/bench_model_error_design.py [--scenes fms_kr16 ur5_table bench/scenes/ur10_cell.yaml]
        [--model rigid|extended|compliance] [-n 60] [--truths 40] [--noise 1] [--seed 0] [--compensate] [--out DIR]
        [--prior-scale F] [--budgets 25,60,300] [--motor ARCSEC] [--motor-length RAD] [--smooth ARCSEC]
        [--rules block] [--pose-budgets 36000] [--direct] [--staged] [--pool-only] [--enriched]
        [--starts K]

``--prior-scale F`` designs ``kpi_model`` with every amplitude of its prior times F (the
length scales kept): how much a misjudged prior costs.

``--budgets 25,60,300`` adds ``kpi_model`` designs with these SQP iteration limits instead of the
default's (:data:`calib_oed.oed.model_error.MODEL_ERROR_EXACT_ITERATIONS`), the rest of its settings
the default's (the ratio trust rule) and the whole exact Hessian
(:data:`calib_oed.oed.model_error_hessian.FULL_COUPLING_MAX_SIZE` raised to its size, as the default
has it at n = 60); each is paired with both ``kpi`` and the default ``kpi_model`` design. 300 is the
SQP's own limit: the design run to convergence.

``--motor ARCSEC`` sets the RMS of the ``kpi_model`` designs' motor-side part
(:class:`~calib_oed.measurement.joint_prior.JointErrorPrior` ``motor``, length ``--motor-length``,
default :data:`~calib_oed.measurement.joint_prior.MOTOR_LENGTH`; 0 drops it), ``--smooth ARCSEC``
that of their smooth own-angle part (length 60 deg unless the prior has another; the default prior
has none, and the realistic simulator has no such part). ``--motor 0 --smooth 10`` is the default
prior before its motor-side part.

``--pose-budgets 36000`` adds the default ``kpi_model`` design with that many pose-iterations
(:data:`calib_oed.oed.model_error.MODEL_ERROR_POSE_ITERATIONS`, the budget above 60 poses:
this over n iterations, between 25 and 300), everything else the default's, paired with the
default one as the budgets are.

``--direct`` adds the default ``kpi_model`` design without its staged start (a design of
:data:`calib_oed.oed.staged.STAGED_MIN_POSES` poses or more starts from a smaller one measured
twice, :mod:`calib_oed.oed.staged`): the exchange start and the whole budget at ``n``, paired with
the default one as the budgets are. ``--staged`` adds it with the staged start at ``n`` whatever
its size (:data:`~calib_oed.oed.staged.STAGED_MIN_POSES` lowered to ``n``), paired the same way.

``--pool-only`` adds the default ``kpi_model`` design whose start is the exchange on the random
pool alone (``design(..., enrich=False)``: no local maxima of the noise-only sensitivity added to
the candidates, :mod:`calib_oed.oed.approximate_pool`), paired with the default one as the budgets are.
Since 23d698e that is the default's own start (``oed.starts.MODEL_ERROR_ENRICH``), so the two designs
are the same; ``--enriched`` adds the design from the old start instead (``design(..., enrich=True)``:
the exchange on the pool enriched by the column generation, in a staged start its every stage),
paired the same way.

``--starts K`` adds the default ``kpi_model`` design run from K seeded starts, the best kept
(``design(..., n_starts=K)``, ``calib-oed design --starts K``; start k from seed + k, start 0 the
default's), paired with the default one as the budgets are: what K times the CPU buys.

``--rules block`` adds the default ``kpi_model`` design with that rule of the SQP's Hessian
modification (``SQPSettings.hessian_modification``; the default ``auto`` is the tangent rule at
60 poses), paired with the default one as the budgets are.

``--out DIR`` also writes ``DIR/<scene>_<model>_designs.npz`` (both designs and the working
configurations) for the figure of docs/oed.md (``--figure SCENE`` draws it from there).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

import calib_oed.oed.model_error as me
import calib_oed.oed.model_error_hessian as meh
import calib_oed.oed.staged as staged
from calib_oed import load_scene
from calib_oed.calibration.identification import identify
from calib_oed.calibration.joint_prior_choice import joint_prior
from calib_oed.calibration.model_error import linearise
from calib_oed.calibration.prediction import compensation
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_defaults import realistic_settings_from_scene
from calib_oed.calibration.realistic_measure import measure
from calib_oed.calibration.workflow import setup
from calib_oed.measurement.joint_prior import ARCSEC, MOTOR_LENGTH, JointErrorPrior
from calib_oed.model.compliance import Compliance
from calib_oed.model.joint_map import JointGains
from calib_oed.oed.design import design
from calib_oed.oed.model_error import design_prior, scene_criterion
from calib_oed.oed.positions import reflector_positions
from calib_oed.oed.refine import EXACT_TRUST_UPDATE
from calib_oed.scene.records import ComplianceSpec
from calib_oed.solver.settings import SQPSettings

MODELS = ("rigid", "extended", "compliance")
BOOTSTRAP = 2000


def extended_scene(scene):
    """``scene`` with joint compliance (payload: the simulator's reflector nest) and a gain per joint."""
    nest = realistic_settings_from_scene(scene).nest_mass
    offsets = np.array([r.offset for r in scene.reflectors], dtype=float)
    payload = Compliance(nest, offsets.mean(axis=0))
    return dataclasses.replace(scene, compliance=ComplianceSpec(True, payload),
                               joint_gains=JointGains.all_joints(scene.robot.nq))


def compliance_scene(scene):
    """``scene`` with its own ``robot.compliance`` block identified (``--compliance``: its payload)."""
    if scene.compliance is None:
        raise SystemExit(f"--model compliance: scene {scene.name} has no robot.compliance block")
    return dataclasses.replace(scene, compliance=ComplianceSpec(True, scene.compliance.payload))


def achieved_errors(s, q: np.ndarray, truths: int, noise: int, seed: int, compensate: bool,
                    frame: str | None = None) -> dict[str, np.ndarray]:
    """Weighted mean squared KPI error per (truth, noise draw) [mm²], (truths, noise), per predictor,
    in ``frame``: None (default) the KPI's own frame, the one the design criterion predicts (the
    world frame on the shipped scenes, where a realistic truth's error also holds what the fit puts
    into the base gauge), or ``"tracker"``, each model with its own tracker pose, as ``identify``
    predicts and ``tcp_errors`` measures by default (``calibration/workflow.tcp_errors``)."""
    problem, space = s.problem, s.problem.space
    kpi = problem.kpi if frame is None else problem.kpi.in_frame(frame)
    free = problem.identifiability.free_indices
    w = problem.kpi.weights
    w = np.ones(len(problem.kpi.configurations)) if w is None else np.asarray(w, dtype=float)
    prior = design_prior(problem, s.scene.discrepancy())
    out = {"fit": np.zeros((truths, noise))}
    if compensate:
        out["compensated"] = np.zeros((truths, noise))

    def mse(values, s_true):
        err = (values - s_true) * 1e3  # (t, 3) [mm]
        return float(w @ np.sum(err**2, axis=1) / (3 * w.sum()))

    for k in range(truths):
        truth = sample_truth(s, np.random.default_rng([seed, k]))
        s_true = truth.compute_kpi_values(kpi)
        for r in range(noise):
            meas = measure(truth, problem.models, q, np.random.default_rng([seed, k, r, 1]))
            p_hat = identify(space, meas.blocks, free).p
            values = kpi.compute_values(space, p_hat)
            out["fit"][k, r] = mse(values, s_true)
            if compensate:  # the conditional mean is in the tracker frame; the KPI in the world
                lin = linearise(space, meas.blocks, p_hat, free)
                mu = compensation(lin, prior, problem.kpi.configurations)
                if kpi.frame == "world":
                    mu = mu @ space.tracker_placement(p_hat).rotation.T
                out["compensated"][k, r] = mse(values + mu, s_true)
    return out


def paired_ratio(mse: np.ndarray, ref: np.ndarray, seed: int) -> tuple[float, float]:
    """RMS ratio of two designs' errors over the same truths and draws, and its bootstrap SE over truths."""
    a, b = mse.mean(axis=1), ref.mean(axis=1)
    pick = np.random.default_rng(seed).integers(0, a.size, size=(BOOTSTRAP, a.size))
    boot = np.sqrt(a[pick].mean(axis=1) / b[pick].mean(axis=1))
    return float(np.sqrt(a.mean() / b.mean())), float(boot.std(ddof=1))


def rms_with_error(mse: np.ndarray) -> tuple[float, float]:
    """RMS [mm] and its standard error (delta method over truths) [mm]."""
    per_truth = mse.mean(axis=1)
    rms = float(np.sqrt(per_truth.mean()))
    return rms, float(per_truth.std(ddof=1) / np.sqrt(per_truth.size) / (2 * rms))


def budget_design(s, n: int, criterion, seed: int, iterations: int):
    """The ``kpi_model`` design with an SQP limit of ``iterations`` and the whole Hessian (``--budgets``)."""
    old = meh.FULL_COUPLING_MAX_SIZE
    meh.FULL_COUPLING_MAX_SIZE = n * s.problem.robot.nq
    try:
        return design(s, n, criterion, seed=seed, certificate=False,
                      settings=SQPSettings(max_iterations=iterations, trust_update=EXACT_TRUST_UPDATE))
    finally:
        meh.FULL_COUPLING_MAX_SIZE = old


def pose_budget_design(s, n: int, criterion, seed: int, pose_iterations: int):
    """The default ``kpi_model`` design with ``pose_iterations`` pose-iterations (``--pose-budgets``)."""
    old = me.MODEL_ERROR_POSE_ITERATIONS
    me.MODEL_ERROR_POSE_ITERATIONS = pose_iterations
    try:
        return design(s, n, criterion, seed=seed, certificate=False)
    finally:
        me.MODEL_ERROR_POSE_ITERATIONS = old


def threshold_design(s, n: int, criterion, seed: int, staged_start: bool = False):
    """The default ``kpi_model`` design without its staged start (``--direct``), or with it at any
    size (``staged_start``, ``--staged``)."""
    old = staged.STAGED_MIN_POSES
    staged.STAGED_MIN_POSES = n if staged_start else n + 1
    try:
        return design(s, n, criterion, seed=seed, certificate=False)
    finally:
        staged.STAGED_MIN_POSES = old


def with_parts(prior, motor: float | None, motor_length: float, smooth: float | None):
    """``prior`` with its motor-side and smooth parts' RMS set [arcsec] (None: kept)."""
    if (motor is not None or smooth is not None) and not isinstance(prior, JointErrorPrior):
        raise SystemExit("--motor and --smooth need the joint-space prior (the scene has another)")
    if motor is not None:
        prior = prior.with_motor(motor * ARCSEC, motor_length)
    if smooth is not None:
        prior = dataclasses.replace(prior, smooth=np.full(prior.nq, smooth * ARCSEC),
                                    source=f"{prior.source}, smooth {smooth:g} arcsec")
    return prior


def run_scene(scene_ref: str, model: str, n: int, truths: int, noise: int, seed: int, compensate: bool,
              out: Path | None, prior_scale: float = 1.0, frame: str | None = None,
              budgets: tuple[int, ...] = (), motor: float | None = None, motor_length: float = MOTOR_LENGTH,
              smooth: float | None = None, rules: tuple[str, ...] = (), pose_budgets: tuple[int, ...] = (),
              direct: bool = False, staged_start: bool = False, pool_only: bool = False,
              enriched: bool = False, starts: int = 1) -> dict:
    scene = load_scene(scene_ref)
    s = setup(extended_scene(scene) if model == "extended" else compliance_scene(scene) if model == "compliance"
              else scene)
    prior = s.scene.model_error if s.scene.model_error is not None else joint_prior(s.problem)
    if prior_scale != 1.0:
        prior = prior.scaled(prior_scale)
    prior = with_parts(prior, motor, motor_length, smooth)
    row = {"scene": s.scene.name, "model": model, "n": n, "seed": seed, "truths": truths, "noise_draws": noise,
           "prior": prior.describe(), "frame": frame or s.problem.kpi.frame}
    designs, errors = {}, {}
    variants = (tuple(f"kpi_model_{b}" for b in budgets) + tuple(f"kpi_model@{r}" for r in rules)
                + tuple(f"kpi_model#{b}" for b in pose_budgets)
                + (("kpi_model!direct",) if direct else ()) + (("kpi_model!staged",) if staged_start else ())
                + (("kpi_model!pool",) if pool_only else ()) + (("kpi_model!enriched",) if enriched else ())
                + ((f"kpi_model!starts{starts}",) if starts > 1 else ()))
    for crit in ("kpi", "kpi_model") + variants:
        if crit.startswith("kpi_model!starts"):
            d = design(s, n, scene_criterion(s, "kpi_model", prior), seed=seed, certificate=False, n_starts=starts)
        elif crit in ("kpi_model!pool", "kpi_model!enriched"):
            d = design(s, n, scene_criterion(s, "kpi_model", prior), seed=seed, certificate=False,
                       enrich=crit.endswith("enriched"))
        elif crit.startswith("kpi_model!"):
            d = threshold_design(s, n, scene_criterion(s, "kpi_model", prior), seed, crit.endswith("staged"))
        elif crit.startswith("kpi_model#"):
            d = pose_budget_design(s, n, scene_criterion(s, "kpi_model", prior), seed, int(crit.split("#")[1]))
        elif crit.startswith("kpi_model@"):
            d = design(s, n, scene_criterion(s, "kpi_model", prior), seed=seed, certificate=False,
                       settings=SQPSettings(hessian_modification=crit.split("@")[1]))
        elif crit.startswith("kpi_model_"):
            d = budget_design(s, n, scene_criterion(s, "kpi_model", prior), seed, int(crit.rsplit("_", 1)[1]))
        else:
            d = design(s, n, scene_criterion(s, crit, prior), seed=seed, certificate=False)
        designs[crit] = d
        errors[crit] = achieved_errors(s, d.q, truths, noise, seed, compensate, frame)
        row[crit] = {
            "design_cpu_s": d.solver["cpu_seconds"], "iterations": d.solver.get("iterations"),
            "status": d.solver.get("status"), "start": d.solver.get("start"), "distinct_poses": len(d.multiplicity),
            "distinct_positions": d.distinct_positions,
            "predicted_rms_mm": float(np.sqrt(d.criteria["kpi_model"])),
            "noise_only_sigma_mm": float(np.sqrt(d.criteria["kpi"])),
        }
        for pred, mse in errors[crit].items():
            rms, se = rms_with_error(mse)
            ratio, ratio_se = paired_ratio(mse, errors["kpi"]["fit"], seed)
            row[crit][pred] = {"achieved_rms_mm": rms, "se_mm": se, "ratio_to_kpi_fit": ratio,
                               "ratio_se": ratio_se,
                               "better_share": float(np.mean(mse.mean(axis=1) < errors["kpi"]["fit"].mean(axis=1)))}
            if crit in variants:
                ratio, ratio_se = paired_ratio(mse, errors["kpi_model"][pred], seed)
                row[crit][pred].update(ratio_to_kpi_model=ratio, ratio_to_kpi_model_se=ratio_se, better_than_kpi_model=float(
                    np.mean(mse.mean(axis=1) < errors["kpi_model"][pred].mean(axis=1))))
    row["design_cpu_ratio"] = row["kpi_model"]["design_cpu_s"] / row["kpi"]["design_cpu_s"]
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        space = s.problem.space
        np.savez(out / f"{s.scene.name}_{model}_designs.npz", noise_only=designs["kpi"].q,
                 model_error=designs["kpi_model"].q, working=s.problem.kpi.configurations,
                 p_noise_only=reflector_positions(space, designs["kpi"].q)[:, 0],
                 p_model_error=reflector_positions(space, designs["kpi_model"].q)[:, 0],
                 p_working=reflector_positions(space, s.problem.kpi.configurations)[:, 0],
                 **{f"model_error_{b}": designs[f"kpi_model_{b}"].q for b in budgets})
    return row


def figure(out: Path, scene: str, model: str) -> Path:
    """Reflector positions of both designs and the working configurations (top and side views)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = np.load(out / f"{scene}_{model}_designs.npz")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for ax, (i, j, label) in zip(axes, [(0, 1, "top view: x, y"), (0, 2, "side view: x, z")], strict=True):
        for key, style in (("p_noise_only", dict(marker="o", facecolors="none", edgecolors="tab:blue",
                                                   label="noise-only kpi design")),
                           ("p_model_error", dict(marker="^", color="tab:red", s=18,
                                                    label="kpi_model design")),
                           ("p_working", dict(marker="*", color="k", s=120, label="working configurations"))):
            p = data[key] * 1e3
            ax.scatter(p[:, i], p[:, j], **style)
        ax.set_xlabel("xyz"[i] + " [mm]")
        ax.set_ylabel("xyz"[j] + " [mm]")
        ax.set_title(f"{scene} ({model}): reflector positions, {label}", fontsize=10)
        ax.set_aspect("equal", adjustable="datalim")
    axes[0].legend(loc="best", fontsize=8)
    fig.tight_layout()
    path = out / f"{scene}_{model}_model_error_designs.png"
    fig.savefig(path, dpi=110)
    return path


def _budgets(text: str) -> tuple[int, ...]:
    try:
        out = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected iteration limits like 25,60,300, got {text!r}") from None
    if any(b < 1 for b in out):
        raise argparse.ArgumentTypeError(f"iteration limits must be >= 1, got {text!r}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["fms_kr16", "ur5_table", "bench/scenes/ur10_cell.yaml"])
    ap.add_argument("--model", choices=MODELS, default="rigid")
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--truths", type=int, default=40)
    ap.add_argument("--noise", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--compensate", action="store_true")
    ap.add_argument("--prior-scale", type=float, default=1.0,
                    help="the kpi_model design's prior with every amplitude times this (a misjudged prior)")
    ap.add_argument("--frame", choices=("tracker", "world"), default=None,
                    help="where the achieved KPI error is taken (default: the KPI's own frame, the one "
                         "the design criterion predicts; tracker: as identify predicts it)")
    ap.add_argument("--budgets", type=_budgets, default=(), metavar="N,N,...",
                    help="also kpi_model designs with these SQP iteration limits, paired with the default one")
    ap.add_argument("--motor", type=float, default=None, metavar="ARCSEC",
                    help="the kpi_model designs' prior with its motor-side part of this RMS [arcsec] (0: none)")
    ap.add_argument("--motor-length", type=float, default=MOTOR_LENGTH, metavar="RAD")
    ap.add_argument("--smooth", type=float, default=None, metavar="ARCSEC",
                    help="the kpi_model designs' prior with a smooth own-angle part of this RMS [arcsec] (0: none)")
    ap.add_argument("--rules", type=lambda t: tuple(t.split(",")), default=(), metavar="RULE,...",
                    help="also the kpi_model design with these Hessian modification rules (block), paired")
    ap.add_argument("--pose-budgets", type=_budgets, default=(), metavar="N,N,...",
                    help="also the default kpi_model design with these pose-iteration budgets, paired")
    ap.add_argument("--direct", action="store_true",
                    help="also the default kpi_model design without its staged start, paired")
    ap.add_argument("--staged", action="store_true",
                    help="also the default kpi_model design with the staged start at this n, paired")
    ap.add_argument("--pool-only", action="store_true",
                    help="also the default kpi_model design started from the random pool alone, paired")
    ap.add_argument("--enriched", action="store_true",
                    help="also the kpi_model design started from the enriched pool (enrich=True), paired")
    ap.add_argument("--starts", type=int, default=1, metavar="K",
                    help="also the default kpi_model design from K seeded starts, the best kept, paired")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--figure", metavar="SCENE", help="only draw the figure of SCENE from --out")
    args = ap.parse_args()
    if args.figure:
        print(figure(args.out, args.figure, args.model))
        return
    with threadpool_limits(limits=1, user_api="blas"):
        for scene in args.scenes:
            print(json.dumps(run_scene(scene, args.model, args.n, args.truths, args.noise, args.seed,
                                       args.compensate, args.out, args.prior_scale, args.frame,
                                       args.budgets, args.motor, args.motor_length, args.smooth,
                                       args.rules, args.pose_budgets, args.direct, args.staged,
                                       args.pool_only, args.enriched, args.starts)),
                  flush=True)


if __name__ == "__main__":
    main()
