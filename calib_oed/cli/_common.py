"""What the command's subcommands share: exit codes, argument types, the scene set-up,
the design argument, progress output and the compliance flags."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from calib_oed.exceptions import CalibOedError

EXIT_OK = 0


EXIT_INTERNAL = 1


EXIT_BAD_INPUT = 2


#: ``validate`` only: the calibrated error exceeds the threshold (docs/identification.md).
EXIT_VALIDATION_FAILED = 3

#: Stopped by Ctrl-C or SIGTERM (128 + SIGINT, the shell's convention).
EXIT_INTERRUPTED = 130


DEFAULT_SCENE = "fms_kr16"


#: The most poses a command accepts with ``-n``: calibrations measure tens to a few hundred.
MAX_POSES = 10_000


def add_command(sub, name: str, func, help: str, *, scene: bool = True,
                outputs: dict[str, str] | None = None) -> argparse.ArgumentParser:
    """The parser of subcommand ``name``, run by ``func(args)``; its first argument the
    positional SCENE unless ``scene`` is False. ``outputs`` ``{dest: "file" | "dir"}`` names
    the paths it writes, checked before any work (:func:`calib_oed.cli._contract.check_outputs`)."""
    p = sub.add_parser(name, help=help)
    p.set_defaults(func=func, **({} if outputs is None else {"outputs": outputs}))
    if scene:
        p.add_argument("scene", help="shipped scene name or scene file path")
    return p


def add_json_quiet(p: argparse.ArgumentParser, quiet: str | None = None) -> None:
    """``--json`` (machine-readable output) and, when ``quiet`` says what it silences, ``--quiet``
    (without it, ``build_parser`` adds a generic ``--quiet`` last)."""
    p.add_argument("--json", action="store_true", help="machine-readable output")
    if quiet is not None:
        p.add_argument("--quiet", action="store_true", help=quiet)


def _integer(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None


def _integer_at_least(text: str, minimum: int, what: str) -> int:
    value = _integer(text, what)
    if value < minimum:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text}")
    return value


def _non_negative_int(text: str) -> int:
    return _integer_at_least(text, 0, "an integer >= 0")


def _positive_int(text: str) -> int:
    return _integer_at_least(text, 1, "an integer >= 1")


def _position_tol_mm(text: str) -> float:
    """``--position-tol``: a distance >= 0 in mm."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value >= 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a distance >= 0 in mm (default 1), got {text!r}")
    return value


def _pose_count(text: str) -> int:
    """``-n``: a number of poses, 1 .. :data:`MAX_POSES`."""
    value = _integer(text, f"a whole number of poses, 1 to {MAX_POSES}")
    if not 1 <= value <= MAX_POSES:
        raise argparse.ArgumentTypeError(
            f"expected a number of poses from 1 to {MAX_POSES} (a calibration measures tens to a few "
            f"hundred), got {text}")
    return value


def _seed(text: str) -> int:
    """A random seed: an integer >= 0 (numpy's ``default_rng`` takes no negative seed)."""
    return _integer_at_least(text, 0, "a seed, an integer >= 0")


def _scene(scene_ref):
    """A loaded scene: ``scene_ref`` is a shipped name, a scene file, or a loaded scene.

    Raises:
        SceneError: a folder given as the scene (and what :func:`load_scene` raises).
    """
    from calib_oed.exceptions import SceneError
    from calib_oed.scene.reader import load_scene, scene_names

    if not isinstance(scene_ref, (str, os.PathLike)):
        return scene_ref
    if Path(scene_ref).is_dir():
        inside = sorted(p.name for p in Path(scene_ref).glob("*.y*ml"))[:5]
        raise SceneError(f"SCENE {os.fspath(scene_ref)} is a folder; give a scene file"
                         + (f" (it holds {', '.join(inside)})" if inside else "")
                         + f" or a shipped scene name ({', '.join(scene_names())})")
    return load_scene(scene_ref)


def _problem(scene_ref):
    from calib_oed.calibration.problem import CalibrationProblem

    scene = _scene(scene_ref)
    return scene, CalibrationProblem.from_scene(scene)


#: Commands with --compliance / --payload-kg (joint compliance under gravity).
COMPLIANCE_COMMANDS = ("identifiability", "demo", "design", "evaluate", "compare", "simulate",
                       "identify", "montecarlo", "sequential")


def _apply_joint_gains(args) -> None:
    """``--joint-gains [JOINTS]``: replace ``args.scene`` by the scene with joint gains modelled
    (the scene's controller couplings, if its block names them, kept)."""
    text = getattr(args, "joint_gains", None)
    if text is None:
        return
    import dataclasses

    from calib_oed.model.joint_map import JointGains

    scene = _scene(args.scene)
    n = scene.robot.model.nq
    try:
        joints = list(range(1, n + 1)) if text.strip() == "all" else [int(s) for s in text.split(",")]
    except ValueError:
        joints = []
    if not joints or any(not 1 <= j <= n for j in joints) or len(set(joints)) != len(joints):
        raise CalibOedError(f"--joint-gains {text}: expected 'all' (or no value) or distinct joint "
                            f"numbers 1..{n} separated by commas, e.g. 2,3")
    couplings = scene.joint_gains.couplings if scene.joint_gains is not None else ()
    args.scene = dataclasses.replace(scene, joint_gains=JointGains(tuple(joints), couplings))


def _apply_compliance(args) -> None:
    """``--compliance`` / ``--payload-kg``: replace ``args.scene`` by the scene with compliance on;
    then ``--joint-gains`` (:func:`_apply_joint_gains`) and ``--prior-from`` (:func:`_apply_prior_from`)."""
    _apply_joint_gains(args)
    _apply_prior_from(args)
    if not (getattr(args, "compliance", False) or getattr(args, "payload_kg", None) is not None):
        return
    import dataclasses

    from calib_oed.model.compliance import Compliance
    from calib_oed.scene.records import ComplianceSpec

    scene = _scene(args.scene)
    payload = scene.compliance.payload if scene.compliance is not None else Compliance()
    if args.payload_kg is not None:
        if not args.payload_kg >= 0:
            raise CalibOedError(f"--payload-kg: expected a mass >= 0 kg, got {args.payload_kg:g}")
        payload = dataclasses.replace(payload, payload_mass=args.payload_kg)  # keeps the scene's link masses
    args.scene = dataclasses.replace(scene, compliance=ComplianceSpec(True, payload))


def _apply_prior_from(args) -> None:
    """``design --prior-from JSON``: replace ``args.scene`` by the scene whose joint-space prior
    comes from an earlier identification (:func:`calib_oed.scene.joint_error.spec_from_identification`).

    Raises:
        SceneError: the file cannot be read or holds no fitted model error (naming ``--prior-from``).
    """
    path = getattr(args, "prior_from", None)
    if path is None:
        return
    import dataclasses

    from calib_oed.exceptions import IdentificationFileError, SceneError
    from calib_oed.scene.joint_error import load_identification, spec_from_identification

    scene = _scene(args.scene)
    try:
        spec = spec_from_identification(load_identification(path), scene.robot.model.nq, str(path))
    except IdentificationFileError as exc:
        raise SceneError(f"--prior-from {path}: {exc}") from None
    args.scene = dataclasses.replace(scene, joint_error=spec)


def _adopt(s, mset, args):
    """``identify --adopt-registration FILE``: write the scene with the fitted tracker pose and
    reflector offsets, say so on stderr, and return its set-up."""
    from calib_oed.calibration.adopt import adopt_registration

    adopted = adopt_registration(s.scene, s.problem.space, mset, args.adopt_registration)
    print(f"calib-oed: {adopted.summary()}", file=sys.stderr)
    return _setup(str(adopted.path))


def _setup(scene_ref):
    from calib_oed.calibration.workflow import setup

    return setup(_scene(scene_ref))


def _design(s, args):
    """The design of a command: a design file (YAML or CSV), or n heuristic feasible poses."""
    from calib_oed.calibration.workflow import heuristic_design
    from calib_oed.io.design_file import read_design_file

    path = getattr(args, "design", None) or getattr(args, "design_option", None)
    if path:
        return read_design_file(path, s.problem.robot, controller=s.scene.controller), f"design file {path}"
    q = heuristic_design(s, args.n, args.seed)
    return q, f"{args.n} random feasible poses (seed {args.seed})"


def _say(args, text: str = "") -> None:
    if not getattr(args, "quiet", False) and not getattr(args, "json", False):
        print(text)


def _sqp_settings(args):
    """The SQP settings ``--iterations``/``--time-limit`` ask for, or None: the design's own
    defaults (``DESIGN_SQP``, capped for the model-error criteria, ``oed.model_error.design_settings``)."""
    from dataclasses import replace

    from calib_oed.oed.design import DESIGN_SQP

    if not (getattr(args, "iterations", None) or getattr(args, "time_limit", None)):
        return None
    settings = DESIGN_SQP
    if getattr(args, "iterations", None):
        settings = replace(settings, max_iterations=args.iterations)
    if getattr(args, "time_limit", None):
        settings = replace(settings, time_limit=args.time_limit)
    return settings


def _bars(args) -> bool:
    """Progress bars: not with --quiet or --json, and only on a terminal (a log gets plain lines)."""
    return not (getattr(args, "quiet", False) or getattr(args, "json", False)) and sys.stderr.isatty()


#: Seconds between plain progress lines when stderr is not a terminal.
PROGRESS_LINE_SECONDS = 10.0


class _Progress:
    """The design SQP's progress: a tqdm bar on a terminal, a plain line every
    :data:`PROGRESS_LINE_SECONDS` otherwise. :meth:`stage` names the poses of the design the
    records that follow are of (a staged design runs its smaller designs first)."""

    def __init__(self, what: str, bar=None):
        self.what, self.bar, self.poses, self._last = what, bar, None, time.perf_counter()

    def stage(self, poses: int) -> None:
        self.poses = int(poses)
        if self.bar is not None:
            self.bar.reset()
            self.bar.set_description(self._name())

    def _name(self) -> str:
        return self.what if self.poses is None else f"{self.what}, {self.poses} poses"

    def __call__(self, record) -> None:
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(objective=f"{record.objective:.4g}", violation=f"{record.violation:.1e}")
            return
        now = time.perf_counter()
        if now - self._last >= PROGRESS_LINE_SECONDS:
            self._last = now
            print(f"{self._name()}: iteration {record.iteration}, objective {record.objective:.4g}, "
                  f"violation {record.violation:.1e}", file=sys.stderr, flush=True)


def _progress(args, what: str):
    """An SQP iteration callback (:class:`_Progress`): a tqdm bar on a terminal, plain lines
    otherwise, nothing when quiet; and the bar (or None)."""
    if getattr(args, "quiet", False) or getattr(args, "json", False):
        return None, None
    if not sys.stderr.isatty():
        return _Progress(what), None
    from tqdm import tqdm

    bar = tqdm(desc=what, unit=" it", leave=False, file=sys.stderr)
    return _Progress(what, bar), bar


def _pool(s, args):
    """``--pool``: a number of random feasible candidates, or a design file of candidates."""
    text = str(getattr(args, "pool", None) or "3000")
    if text.isdigit():
        if int(text) < 1:
            raise CalibOedError(f"--pool {text}: give a number of candidates >= 1 or a design file")
        return int(text)
    from calib_oed.io.design_file import read_design_file

    if not Path(text).exists():
        raise CalibOedError(f"--pool {text}: neither a number of candidates nor an existing "
                            "design file (CSV with joint-name header, or design.yaml)")
    return read_design_file(text, s.problem.robot, controller=s.scene.controller)


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
                      position_tol=1e-3 * getattr(args, "position_tol", 1.0),
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
    """``items`` with a progress bar on a terminal unless quiet or JSON."""
    if not _bars(args) or len(items) < 2:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=what, leave=False, file=sys.stderr)


def _round_trip_text(error_m: float) -> str:
    """The exported URDF's largest tool difference [m] for a report, in mm."""
    if error_m < 1e-12:
        return f"{error_m * 1e3:.1e} mm (floating-point round-off: the URDF reproduces the model)"
    return f"{error_m * 1e3:.3g} mm"


def _note_infeasible(s, q, what: str) -> None:
    """A :class:`~calib_oed.exceptions.CalibOedNote` when poses of ``q`` violate the constraints."""
    import warnings

    from calib_oed.exceptions import CalibOedNote

    bad = np.flatnonzero(~s.feasibility.compute(q, jacobian=False).feasible)
    if bad.size:
        warnings.warn(CalibOedNote(
            f"{bad.size} of {len(q)} poses of the {what} violate the scene's constraints (collision, "
            f"incidence or joint limits), poses {', '.join(str(int(i) + 1) for i in bad[:10])}"
            f"{' ...' if bad.size > 10 else ''}: a real robot could not measure them "
            "(`calib-oed feasibility` lists the margins)"), stacklevel=2)


def _note_deflection(s, criterion) -> None:
    """The :func:`~calib_oed.calibration.joint_prior_choice.deflection_note` of a model-error design."""
    import warnings

    from calib_oed.calibration.joint_prior_choice import deflection_note, joint_prior
    from calib_oed.exceptions import CalibOedNote
    from calib_oed.oed.model_error import KRIGING, MODEL_ERROR, scene_prior

    if criterion not in (MODEL_ERROR, KRIGING):
        return
    prior = scene_prior(s)
    note = deflection_note(s.problem, joint_prior(s.problem) if prior is None else prior)
    if note is not None:
        warnings.warn(CalibOedNote(note), stacklevel=2)


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


def _model_error_warning(result) -> str:
    r"""What ``sequential --measured`` says when the fit's residuals show model error: the KPI sigma
    then covers only part of the error. Model error is shown when :math:`\hat\sigma_0^2` exceeds 1 by
    more than 3 of its standard deviations under the noise model, :math:`\sqrt{2/(m - n_f)}`
    (docs/identification.md, the noise factor); "" otherwise."""
    if not result.dof > 0 or result.noise_factor <= 1.0 + 3.0 * np.sqrt(2.0 / result.dof):
        return ""
    return (f"sigma0 = {result.sigma0:.2f}: the residuals are {result.sigma0:.1f} times the stated noise, "
            "so these data show model error (gravity, gears, temperature), which the KPI sigma does not "
            "cover and more poses do not remove; `calib-oed identify` predicts the accuracy with it "
            "(docs/identification.md#model-error-and-predicted-accuracy)")
