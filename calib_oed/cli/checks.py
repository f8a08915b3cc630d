"""Checks of a command's arguments before any work (docs/cli.md, "Exit codes and errors").

:func:`check_inputs` runs after the output paths are checked and before the
command's body. It refuses, each with one line naming the valid choices:

- an option the command would silently drop: ``-n`` or ``--seed`` with a design
  file, a design given both as DESIGN and ``--design``, options that only act
  with another one (``evaluate --pool`` without ``--certificate``, ``sequential
  --length-unit`` without ``--measured``, ``demo --pool`` with ``--no-optimise``, ...);
- numbers outside their meaning: ``--time-limit 0``, ``--payload-kg 1e9``, ``-N 1``;
- the same file as two outputs, or an output that is one of the inputs
  (``simulate -o X --truth X``, ``simulate SCENE d.csv -o d.csv``).

Which options were *given* (not defaulted) is read by parsing the command line
again with every default suppressed (:func:`given_options`).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from calib_oed.exceptions import CalibOedError
from calib_oed.scene.joint_keys import MAX_PAYLOAD_KG

__all__ = ["MAX_PAYLOAD_KG", "check_inputs", "given_options"]


#: Input paths of the commands, by argparse ``dest`` (a list for ``compare``'s designs).
_INPUTS = ("scene", "design", "design_option", "measurements", "measured", "truth", "export",
           "calibrated", "designs", "pool", "start", "program", "config")


class ArgumentError(CalibOedError, ValueError):
    """Command-line options that contradict each other or lie outside their meaning."""


def given_options(args) -> set[str]:
    """The ``dest`` of every option and positional given on the command line of ``args``."""
    from calib_oed.cli import build_parser
    from calib_oed.cli._contract import normalise_argv

    parser = build_parser()
    parsers = [parser, *(parser._subparsers._group_actions[0].choices.values())]
    for p in parsers:
        for action in p._actions:
            action.default = argparse.SUPPRESS
    namespace = parser.parse_args(normalise_argv(list(args.argv), parser))
    return set(vars(namespace)) - {"func", "outputs", "command"}


def _flag(dest: str) -> str:
    return {"n": "-n", "runs": "-N", "design": "DESIGN", "seconds": "--for", "output": "-o",
            "scene": "SCENE", "measurements": "MEASUREMENTS", "designs": "DESIGN"}.get(
        dest, "--" + dest.replace("_", "-"))


def _dropped(args, given: set[str]) -> None:
    """Options that the command would ignore in this combination."""
    command = args.command
    design = getattr(args, "design", None) or getattr(args, "design_option", None)
    if getattr(args, "design", None) and getattr(args, "design_option", None):
        raise ArgumentError(f"{command}: the design is given twice (DESIGN {args.design} and --design "
                            f"{args.design_option}); give one of them")
    if design and "n" in given and command in ("feasibility", "simulate", "montecarlo", "demo"):
        raise ArgumentError(f"{command}: -n {args.n} and the design file {design}: the file sets the "
                            "number of poses; leave out -n (or the design, for -n random poses)")
    if design and "seed" in given and command in ("feasibility", "simulate", "montecarlo"):
        raise ArgumentError(f"{command}: --seed {args.seed} and the design file {design}: the seed draws "
                            "the random design only; leave out --seed (or the design)")
    for cmd, needed, options in (("evaluate", "certificate", ("pool", "seed")),
                                 ("sequential", "measured", ("length_unit", "angle_unit", "max_registration_rms"))):
        for dest in options if command == cmd and not getattr(args, needed, None) else ():
            if dest in given:
                raise ArgumentError(f"{command}: {_flag(dest)} acts only with {_flag(needed)}; add "
                                    f"{_flag(needed)} or leave out {_flag(dest)}")
    if command == "sequential" and getattr(args, "measured", None):
        simulation = ("initial", "initial_design", "max_measurements", "truth_seed", "no_compare",
                      "reference", "grid_step")
        for dest in simulation:
            if dest in given:
                raise ArgumentError(f"sequential: {_flag(dest)} belongs to the simulated run; with "
                                    "--measured (one step of a real calibration) leave it out")
    if command == "demo" and getattr(args, "no_optimise", False):
        for dest in ("pool", "iterations"):
            if dest in given:
                raise ArgumentError(f"demo: {_flag(dest)} acts on the design optimisation, which "
                                    "--no-optimise skips; leave out one of them")
    if command == "study" and getattr(args, "no_report", False) and "no_figures" in given:
        raise ArgumentError("study: --no-figures acts on the report, which --no-report skips; "
                            "leave out one of them")
    if command == "view":
        if getattr(args, "html", None) and "seconds" in given:
            raise ArgumentError("view: --for sets how long the live viewer serves; --html writes a "
                                "page instead; leave out one of them")
        if not getattr(args, "html", None) and "json" in given:
            raise ArgumentError("view: --json describes the page --html writes; add --html FILE or "
                                "leave out --json")
    if command == "design" and getattr(args, "aggregate", None) and args.criterion not in (None, "kpi"):
        raise ArgumentError(f"design: --aggregate {args.aggregate} acts on the criterion 'kpi' only, "
                            f"not --criterion {args.criterion}; use --criterion kpi or leave it out")


def _positive(args, dest: str, what: str, allow_inf: bool = False, allow_zero: bool = False) -> None:
    value = getattr(args, dest, None)
    if value is None:
        return
    ok = (value >= 0 if allow_zero else value > 0) and (math.isfinite(value) or (allow_inf and value == math.inf))
    if not ok:
        also = " (leave it out for no limit)" if allow_inf else ""
        raise ArgumentError(f"{_flag(dest)}: expected {what} {'>=' if allow_zero else '>'} 0{also}, got {value:g}")


def _ranges(args) -> None:
    """Numbers outside their meaning."""
    _positive(args, "time_limit", "a time in seconds", allow_inf=True)
    _positive(args, "seconds", "a time in seconds", allow_zero=True)  # 0: start and stop
    _positive(args, "scale", "a drawing scale")
    _positive(args, "max_rms", "an RMS in mm")
    _positive(args, "max_error", "a position error in mm")
    _positive(args, "max_registration_rms", "an RMS in mm")
    level = getattr(args, "level", None)
    if getattr(args, "command", None) == "view" and level is not None and not 0 < level < 1:
        raise ArgumentError(f"--level: expected a confidence level strictly between 0 and 1 "
                            f"(e.g. 0.95), got {level:g}")
    payload = getattr(args, "payload_kg", None)
    if payload is not None and not 0 <= payload <= MAX_PAYLOAD_KG:
        raise ArgumentError(
            f"--payload-kg: expected a payload mass from 0 to {MAX_PAYLOAD_KG:g} kg (no industrial "
            f"robot carries more; grams typed as kg?), got {payload:g}")
    runs = getattr(args, "runs", None)
    if runs is not None and args.command in ("montecarlo", "demo") and runs < 2:
        raise ArgumentError(f"-N {runs}: a Monte Carlo study needs at least 2 runs to estimate a "
                            "covariance (hundreds are typical)")


def _same(a: str, b: str) -> bool:
    pa, pb = Path(a), Path(b)
    try:
        if pa.exists() and pb.exists():
            return os.path.samefile(pa, pb)
    except OSError:
        pass
    return pa.resolve() == pb.resolve()


def _collisions(args) -> None:
    """The same file as two outputs, or an output that is an input."""
    outputs = getattr(args, "outputs", None) or {}
    files = {d: getattr(args, d) for d, kind in outputs.items()
             if kind == "file" and getattr(args, d, None) is not None}
    if args.command == "simulate" and files.get("output") and not getattr(args, "truth", None):
        from calib_oed.cli._contract import check_output

        args.truth = str(Path(args.output).with_suffix("")) + "_truth.yaml"  # the default, checked too
        check_output(args.truth, "file", "--truth (default <output>_truth.yaml)")
        files["truth"] = args.truth
    names = list(files)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if _same(files[a], files[b]):
                raise ArgumentError(f"{_flag(a)} and {_flag(b)} are the same file {files[a]}; give "
                                    "each output its own file")
    inputs = []
    for dest in (d for d in _INPUTS if d not in outputs):
        value = getattr(args, dest, None)
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, (str, os.PathLike)) and Path(v).is_file():
                inputs.append((dest, os.fspath(v)))
    for out, path in files.items():
        for dest, source in inputs:
            if _same(path, source):
                raise ArgumentError(f"{_flag(out)} {path} is the input {_flag(dest)} "
                                    "file: writing would destroy it; give another output file")


def check_inputs(args) -> None:
    """Raise :class:`ArgumentError` for the mistakes of the module docstring; before any work."""
    given = given_options(args) if getattr(args, "argv", None) is not None else set()
    _dropped(args, given)
    _ranges(args)
    _collisions(args)
