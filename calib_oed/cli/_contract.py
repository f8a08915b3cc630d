"""The command line's contract (docs/cli.md), in one place for every command.

- Output paths are checked before any work (:func:`check_outputs`): each
  subcommand declares them with ``set_defaults(outputs={dest: kind})``, kind
  ``"dir"`` (a folder, created if missing) or ``"file"`` (its folder must exist).
- Bad arguments are one line, exit 2 (:class:`OneLineParser`).
- Ctrl-C and SIGTERM end a command with one line, ``calib-oed: interrupted``,
  exit 130 (:func:`sigterm_as_interrupt`, :data:`EXIT_INTERRUPTED`).
- Notes (:class:`~calib_oed.exceptions.CalibOedNote` warnings) are one line each
  on stderr (:func:`notes_as_lines`).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import sys
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

from calib_oed.cli._common import EXIT_INTERRUPTED
from calib_oed.exceptions import CalibOedNote, OutputPathError

__all__ = ["EXIT_INTERRUPTED", "OPTIONAL_VALUES", "OneLineParser", "attach_optional_values",
           "check_output", "check_outputs", "join_signed_values", "normalise_argv", "notes_as_lines",
           "sigterm_as_interrupt"]

#: Suffixes of figure files (those of ``calib_oed.viz.plots.FIGURE_FORMATS``).
FIGURE_SUFFIXES = (".png", ".svg", ".pdf")

#: Option names shown in messages, by argparse ``dest``.
_FLAGS = {"output": "-o", "plot": "--plot", "html": "--html", "truth": "--truth",
          "adopt_registration": "--adopt-registration"}


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr, exit code 2."""

    def error(self, message: str):  # noqa: D401 - argparse's hook
        self.exit(2, f"calib-oed: error: {self.prog}: {message} (see `{self.prog} -h`)\n")

    def parse_args(self, args=None, namespace=None):
        """argparse's, but arguments left over are named by the command's own parser (its prog
        and help), not the top level's."""
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            parser = self
            for action in self._actions:
                if isinstance(action, argparse._SubParsersAction):
                    parser = action.choices.get(getattr(namespace, action.dest, None), self)
            parser.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace


def _probe_writable(folder: Path) -> bool:
    """Whether a file can be created in ``folder`` (tried, not guessed from mode bits)."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def check_output(path, kind: str, option: str, suffixes: tuple[str, ...] = (),
                 created: tuple[Path, ...] = ()) -> None:
    """Raise :class:`OutputPathError` unless ``path`` can be written as ``kind``.

    Args:
        path: The path given on the command line.
        kind: ``"dir"``: a folder, created later if missing (its nearest existing
            ancestor must be a writable folder); ``"file"``: a file, overwritten
            if it exists, in a folder that exists and is writable.
        option: The option's name for the message.
        suffixes: Allowed file suffixes (case-insensitive), empty for any.
        created: Folders the command creates before it writes this file (its
            folder outputs): a file inside one of them needs no existing folder.
    """
    text = os.fspath(path)
    if not text.strip():
        raise OutputPathError(option, repr(text), "empty path")
    p = Path(text)
    if kind == "dir":
        if p.exists() and not p.is_dir():
            raise OutputPathError(option, text, "exists and is not a folder; give a folder "
                                  "(created if missing) or remove the file")
        folder = p
    else:
        if p.is_dir():
            raise OutputPathError(option, text, "is a folder; give a file name")
        if p.exists() and not p.is_file():
            raise OutputPathError(option, text, "exists and is not a regular file (a device, a "
                                  "pipe or a socket); give the name of a new or a regular file")
        if suffixes and p.suffix.lower() not in suffixes:
            raise OutputPathError(option, text, f"unknown file type {p.suffix or '(none)'!r}; "
                                  f"valid suffixes are {', '.join(map(repr, suffixes))}")
        folder = p.parent if str(p.parent) else Path(".")
        inside = any(folder.resolve().is_relative_to(c.resolve()) for c in created)
        if not folder.exists() and not inside:
            raise OutputPathError(option, text, f"folder {folder} does not exist; create it first")
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise OutputPathError(option, text, f"{existing} is a file, so the folder cannot be created")
    if not _probe_writable(existing):
        what = "the folder" if existing == folder else f"{existing}, where the folder would be created,"
        raise OutputPathError(option, text, f"cannot write there: {what} is read-only or not yours")


def check_outputs(args) -> None:
    """Check every output path the subcommand declared (``args.outputs``) before any work."""
    outputs = getattr(args, "outputs", None) or {}
    folders = tuple(Path(getattr(args, d)) for d, k in outputs.items()
                    if k == "dir" and getattr(args, d, None) is not None)
    for dest, kind in outputs.items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        suffixes = FIGURE_SUFFIXES if (dest == "plot" and kind == "file") else ()
        check_output(value, kind, _FLAGS.get(dest, f"--{dest}"), suffixes, created=folders)


def _workers() -> list[int]:
    """This process's child processes but resource trackers (Linux ``/proc``; empty elsewhere)."""
    pids: list[int] = []
    for task in Path(f"/proc/{os.getpid()}/task").glob("*/children"):
        with contextlib.suppress(OSError, ValueError):
            pids += [int(p) for p in task.read_text().split()]
    keep = []
    for pid in pids:
        with contextlib.suppress(OSError):
            if b"resource_tracker" not in Path(f"/proc/{pid}/cmdline").read_bytes():
                keep.append(pid)
    return keep


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`KeyboardInterrupt` as Ctrl-C does, and
    both first send SIGTERM to the child processes (joblib's workers).

    A Ctrl-C in a terminal reaches the whole process group, workers included; a
    SIGTERM (or SIGINT) sent to this process alone would leave the workers
    running their tasks while the parent waits for them. Only in the main thread
    (signal handlers cannot be set elsewhere); the previous handlers are restored.
    """
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        for pid in _workers():  # SIGTERM: a worker ends without a traceback of its own
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGTERM)
        raise KeyboardInterrupt

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


@contextlib.contextmanager
def notes_as_lines() -> Iterator[None]:
    """Print each :class:`CalibOedNote` warning as one ``calib-oed: note: ...`` line on stderr."""
    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, CalibOedNote):
            print(f"calib-oed: note: {message}", file=sys.stderr)
        else:
            previous(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.simplefilter("always", CalibOedNote)
        warnings.showwarning = show
        try:
            yield
        finally:
            warnings.showwarning = previous


_SIGNED_VALUE = re.compile(r"^-(\d|\.\d)")

#: Options whose value may be left out: option -> (value when left out, form of a value).
#: The parser declares them with a required value; :func:`attach_optional_values` supplies it.
OPTIONAL_VALUES = {"--joint-gains": ("all", re.compile(r"^\s*(all|\d[\d\s,]*)\s*$"))}


def _long_options(parser: argparse.ArgumentParser) -> set[str]:
    parsers = [parser, *(parser._subparsers._group_actions[0].choices.values() if parser._subparsers else ())]
    return {s for p in parsers for a in p._actions for s in a.option_strings if s.startswith("--")}


def attach_optional_values(argv: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """``--joint-gains`` -> ``--joint-gains=all``; ``--joint-gains 2,3`` -> ``--joint-gains=2,3``.

    An option of :data:`OPTIONAL_VALUES` takes the next argument as its value only
    when that argument has the value's form (``all`` or joint numbers), so a bare
    option never swallows a positional argument: in ``identify --joint-gains
    fms_kr16 m.csv`` the scene stays the scene (argparse's ``nargs='?'`` would take
    it for the joints). Unambiguous abbreviations (``--joint-g``) count as the option.
    """
    others = _long_options(parser)
    names = {}
    for option in OPTIONAL_VALUES:
        rivals = others - {option}
        names[option] = option
        for k in range(3, len(option)):
            if not any(r.startswith(option[:k]) for r in rivals):
                names[option[:k]] = option
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        if token == "--":  # everything after is positional
            return out + argv[i:]
        option = names.get(token)
        if option is None:
            head, eq, value = token.partition("=")
            out.append(f"{names[head]}={value}" if eq and head in names else token)
            i += 1
            continue
        default, form = OPTIONAL_VALUES[option]
        if i + 1 < len(argv) and form.match(argv[i + 1]):
            out.append(f"{option}={argv[i + 1]}")
            i += 2
        else:
            out.append(f"{option}={default}")
            i += 1
    return out


def normalise_argv(argv: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """The command line as the parser reads it: :func:`attach_optional_values`, then
    :func:`join_signed_values`."""
    return join_signed_values(attach_optional_values(argv, parser), parser)


def join_signed_values(argv: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """``--target-sigma -0.005mm`` -> ``--target-sigma=-0.005mm``.

    argparse takes a value that starts with ``-`` and is not a plain number for
    an option and reports "expected one argument"; joined, the option's own type
    check names the real problem (a negative length).
    """
    takes_value = {s for a in parser._actions for s in a.option_strings if a.nargs is None and s.startswith("--")}
    for sub in parser._subparsers._group_actions[0].choices.values() if parser._subparsers else ():
        takes_value |= {s for a in sub._actions for s in a.option_strings
                        if a.nargs is None and a.type is not None and s.startswith("--")}
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        if (token in takes_value and i + 1 < len(argv) and _SIGNED_VALUE.match(argv[i + 1])):
            out.append(f"{token}={argv[i + 1]}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out
