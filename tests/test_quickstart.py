"""docs/quickstart.md runs as written: every `calib-oed` command of its shell blocks,
in order, in one fresh folder, with the installed command, printing the lines the page
shows under it; and the README's Python quick start prints what the README says it
prints."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
QUICKSTART = ROOT / "docs" / "quickstart.md"
BIN = Path(sys.executable).parent


def shell_commands(text: str) -> list[str]:
    """The `calib-oed ...` lines of the ```sh blocks, continuation lines joined."""
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        joined = block.replace("\\\n", " ")
        for line in joined.splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith("calib-oed "):
                commands.append(line)
    return commands


def output_paths(argv: list[str]) -> list[str]:
    """Files and folders a command says it writes (-o, --html, --plot)."""
    out = []
    for flag in ("-o", "--output", "--html", "--plot"):
        if flag in argv:
            out.append(argv[argv.index(flag) + 1])
    return out


def test_the_quickstart_has_the_whole_workflow():
    verbs = [shlex.split(c)[1] for c in shell_commands(QUICKSTART.read_text())]
    for verb in ("identifiability", "design", "evaluate", "compare", "view", "simulate",
                 "identify", "validate", "montecarlo"):
        assert verb in verbs, f"docs/quickstart.md lacks a `calib-oed {verb}` command"


def blocks_with_output(text: str) -> list[tuple[list[str], str | None]]:
    """Each ```sh block's commands, with the ```text block that follows it (the output the page
    shows), if one follows before the next ```sh block."""
    pieces = re.split(r"```sh\n(.*?)```", text, flags=re.S)
    out = []
    for block, after in zip(pieces[1::2], pieces[2::2], strict=False):
        shown = re.match(r"(?:(?!```sh).)*?```text\n(.*?)```", after, flags=re.S)
        out.append((shell_commands(f"```sh\n{block}```"), shown.group(1) if shown else None))
    return out


NUMBER = r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?"


def shown_line_pattern(line: str) -> re.Pattern:
    """A line the page shows as a regular expression: `~x` (a value that is not bitwise
    reproducible, or a time) matches any number, runs of spaces any run of spaces, a trailing
    `...` anything."""
    parts = re.split(rf"(~{NUMBER}|\s+|\.\.\.$)", line.strip())
    regex = "".join(NUMBER if p.startswith("~") else r"\s+" if p.isspace() else ".*" if p == "..." else
                    re.escape(p) for p in parts if p)
    return re.compile(regex)


def check_shown_output(commands: list[str], shown: str, printed: str) -> None:
    """Every line the page shows (but `...`) is printed, in the order shown."""
    lines = printed.splitlines()
    at = 0
    for line in shown.strip().splitlines():
        if line.strip() in ("", "..."):
            continue
        pattern = shown_line_pattern(line)
        hit = next((i for i in range(at, len(lines)) if pattern.fullmatch(lines[i].strip())), None)
        assert hit is not None, (f"docs/quickstart.md shows\n  {line.strip()}\nafter `{commands[-1]}`, "
                                 f"which printed (from there):\n" + "\n".join(lines[at:])[-3000:])
        at = hit + 1


def test_quickstart_runs_as_written(tmp_path):
    """Every command runs, writes what it says, and prints the lines the page shows."""
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    for commands, shown in blocks_with_output(QUICKSTART.read_text()):
        printed = []
        for command in commands:
            argv = shlex.split(command)
            done = subprocess.run([str(BIN / argv[0]), *argv[1:]], cwd=tmp_path, env=env,
                                  capture_output=True, text=True, timeout=600)
            assert done.returncode == 0, f"`{command}` failed ({done.returncode}):\n{done.stderr[-2000:]}"
            for path in output_paths(argv):
                assert (tmp_path / path).exists(), f"`{command}` did not write {path}"
            printed.append(done.stdout)
        if shown is not None and commands:
            check_shown_output(commands, shown, "\n".join(printed))


def readme_python_quickstart() -> tuple[str, str]:
    """The README's Python quick start and the output printed under it."""
    text = (ROOT / "README.md").read_text()
    match = re.search(r"```python\n(.*?)```\s*\nprints\s*\n\s*```text\n(.*?)```", text, flags=re.S)
    if match is None:
        pytest.fail("README.md: expected a ```python block followed by 'prints' and a ```text block")
    return match.group(1), match.group(2)


def test_readme_quick_start_prints_what_it_says(tmp_path):
    """Run as a user would: the snippet as a script in a fresh interpreter."""
    code, expected = readme_python_quickstart()
    assert len(code.strip().splitlines()) <= 12, "the README quick start should stay about ten lines"
    script = tmp_path / "quickstart.py"
    script.write_text(code)
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == expected.strip()
