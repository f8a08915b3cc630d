"""What the command's subcommands share: exit codes, argument types, the scene set-up,
the design argument, progress output and the compliance flags."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from calib_oed.exceptions import CalibOedError

EXIT_OK = 0


EXIT_INTERNAL = 1


EXIT_BAD_INPUT = 2


DEFAULT_SCENE = "fms_kr16"


def _non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text}")
    return value


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text}")
    return value


def _problem(scene_ref):
    from calib_oed.calibration.problem import CalibrationProblem
    from calib_oed.scene.reader import load_scene

    scene = load_scene(scene_ref) if isinstance(scene_ref, (str, os.PathLike)) else scene_ref
    return scene, CalibrationProblem.from_scene(scene)


#: Commands with --compliance / --payload-kg (joint compliance under gravity).
COMPLIANCE_COMMANDS = ("identifiability", "demo", "design", "evaluate", "compare", "simulate",
                       "identify", "montecarlo", "sequential")


def _apply_compliance(args) -> None:
    """``--compliance`` / ``--payload-kg``: replace ``args.scene`` by the scene with compliance on."""
    if not (getattr(args, "compliance", False) or getattr(args, "payload_kg", None) is not None):
        return
    import dataclasses

    from calib_oed.model.compliance import Compliance
    from calib_oed.scene.reader import load_scene
    from calib_oed.scene.records import ComplianceSpec

    scene = load_scene(args.scene)
    payload = scene.compliance.payload if scene.compliance is not None else Compliance()
    if args.payload_kg is not None:
        if not args.payload_kg >= 0:
            raise CalibOedError(f"--payload-kg: expected a mass >= 0 kg, got {args.payload_kg:g}")
        payload = Compliance(args.payload_kg, payload.payload_com)
    args.scene = dataclasses.replace(scene, compliance=ComplianceSpec(True, payload))


def _setup(scene_ref):
    from calib_oed.calibration.workflow import setup
    from calib_oed.scene.reader import load_scene

    return setup(load_scene(scene_ref) if isinstance(scene_ref, (str, os.PathLike)) else scene_ref)


def _design(s, args):
    """The design of a command: a design file (YAML or CSV), or n heuristic feasible poses."""
    from calib_oed.calibration.workflow import heuristic_design
    from calib_oed.oed.result import read_design_file

    path = getattr(args, "design", None) or getattr(args, "design_option", None)
    if path:
        return read_design_file(path, s.problem.robot), f"design file {path}"
    q = heuristic_design(s, args.n, args.seed)
    return q, f"{args.n} random feasible poses (seed {args.seed})"


def _say(args, text: str = "") -> None:
    if not getattr(args, "quiet", False) and not getattr(args, "json", False):
        print(text)


def _sqp_settings(args):
    from dataclasses import replace

    from calib_oed.oed.design import DESIGN_SQP

    settings = DESIGN_SQP
    if getattr(args, "iterations", None):
        settings = replace(settings, max_iterations=args.iterations)
    if getattr(args, "time_limit", None):
        settings = replace(settings, time_limit=args.time_limit)
    return settings


def _progress(args, what: str):
    """An SQP iteration callback drawing a tqdm bar (None when quiet)."""
    if getattr(args, "quiet", False) or getattr(args, "json", False):
        return None, None
    from tqdm import tqdm

    bar = tqdm(desc=what, unit=" it", leave=False, file=sys.stderr)

    def callback(record):
        bar.update(1)
        bar.set_postfix(objective=f"{record.objective:.4g}", violation=f"{record.violation:.1e}")

    return callback, bar


def _pool(s, args):
    """``--pool``: a number of random feasible candidates, or a design file of candidates."""
    text = str(getattr(args, "pool", None) or "3000")
    if text.isdigit():
        if int(text) < 1:
            raise CalibOedError(f"--pool {text}: give a number of candidates >= 1 or a design file")
        return int(text)
    from calib_oed.oed.result import read_design_file

    if not Path(text).exists():
        raise CalibOedError(f"--pool {text}: neither a number of candidates nor an existing "
                            "design file (CSV with joint-name header, or design.yaml)")
    return read_design_file(text, s.problem.robot)


def _optimise(s, args, criterion: str, start, aggregate: str = "mean"):
    from calib_oed.oed.design import design

    what = f"{criterion}{'-max' if aggregate == 'max' else ''}-optimal design"
    pool = _pool(s, args)
    callback, bar = _progress(args, what)
    try:
        return design(s, args.n, criterion, start=start, seed=args.seed, pool=pool,
                      n_starts=getattr(args, "starts", 1), collisions=not getattr(args, "no_collisions", False),
                      refine=not getattr(args, "no_refine", False),
                      replicates=getattr(args, "replicates", 1),
                      certificate=not getattr(args, "no_certificate", False),
                      hessian=getattr(args, "hessian", "exact"),
                      settings=_sqp_settings(args), callback=callback, aggregate=aggregate)
    finally:
        if bar is not None:
            bar.close()


def _mesh_check(s, q):
    """The independent check of design ``q`` against the URDF collision meshes."""
    from calib_oed.feasibility.mesh_check import check_design_meshes

    scene = s.scene
    return check_design_meshes(
        scene.robot, q, scene.cell,
        tracker_position=scene.tracker.placement().translation,
        reflector_offsets=np.array([r.offset for r in scene.reflectors]),
        beam_radius=scene.feasibility.beam_radius,
        excluded_pairs=scene.feasibility.excluded_pairs,
    )


def _iterate(args, items, what: str):
    """``items`` with a progress bar unless quiet or JSON."""
    if getattr(args, "quiet", False) or getattr(args, "json", False) or len(items) < 2:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=what, leave=False, file=sys.stderr)


_LENGTH_UNITS_MM = {"mm": 1.0, "um": 1e-3, "µm": 1e-3, "m": 1e3}


def _length_mm(text: str) -> float:
    """A length such as ``0.02mm``, ``20um`` or ``0.02`` (mm) in mm, > 0."""
    raw = text.strip()
    unit = next((u for u in sorted(_LENGTH_UNITS_MM, key=len, reverse=True) if raw.endswith(u)), None)
    number = raw[: -len(unit)].strip() if unit else raw
    try:
        value = float(number) * _LENGTH_UNITS_MM[unit or "mm"]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a length like 0.02mm, 20um or 0.02 (mm); units {', '.join(_LENGTH_UNITS_MM)}; "
            f"got {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a length > 0, got {text!r}")
    return value
