"""The CLI contract (docs/cli.md): output paths checked before any work, one-line
errors with exit 2, Ctrl-C / SIGTERM as one line with exit 130, notes, --quiet."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import calib_oed.cli as cli
from calib_oed.cli import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_OK, build_parser, main
from calib_oed.cli._contract import FIGURE_SUFFIXES, check_output
from calib_oed.exceptions import OutputPathError
from calib_oed.viz.plots import FIGURE_FORMATS

COMMANDS = ("demo", "design", "evaluate", "compare", "view", "feasibility", "simulate", "identify",
            "sequential", "study", "montecarlo", "validate", "identifiability")


@pytest.fixture
def no_work(monkeypatch):
    """Every command body replaced by one that fails the test if it runs."""
    def work(args):
        raise AssertionError(f"{args.command} started its work before the output check")

    for name in COMMANDS:
        monkeypatch.setattr(cli, f"cmd_{name}", work)


def _one_line_error(capsys, *fragments):
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in err, err
    return err


@pytest.fixture
def read_only(tmp_path):
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        (folder / "probe").write_text("x")
    except OSError:
        yield folder
    else:  # root, or a file system that ignores the mode bits
        pytest.skip("running with write access to a 0o555 folder (root?): chmod cannot make it read-only")
    finally:
        folder.chmod(0o755)


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["design", "fms_kr16", "-o", "{file}"], "exists and is not a folder"),
        (["design", "fms_kr16", "-o", "{file}/sub"], "is a file, so the folder cannot be created"),
        (["evaluate", "fms_kr16", "d.csv", "--plot", "{file}"], "exists and is not a folder"),
        (["sequential", "fms_kr16", "--target-sigma", "0.02", "-o", "{file}"], "exists and is not a folder"),
        (["demo", "-o", "{file}"], "exists and is not a folder"),
        (["identify", "fms_kr16", "m.csv", "-o", "{file}"], "exists and is not a folder"),
        (["study", "smoke", "-o", "{file}"], "exists and is not a folder"),
        (["simulate", "fms_kr16", "-o", "{tmp}/missing/m.csv"], "does not exist; create it first"),
        (["simulate", "fms_kr16", "-o", "{tmp}"], "is a folder; give a file name"),
        (["feasibility", "fms_kr16", "-o", "{tmp}/no/d.csv"], "does not exist"),
        (["compare", "fms_kr16", "d.csv", "--plot", "{tmp}/e.txt"], "valid suffixes are '.png', '.svg', '.pdf'"),
        (["identify", "fms_kr16", "m.csv", "--plot", "{tmp}"], "is a folder"),
        (["view", "fms_kr16", "--html", "{tmp}"], "is a folder"),
    ],
)
def test_bad_output_paths_stop_before_any_work(capsys, tmp_path, no_work, argv, fragment):
    (tmp_path / "existing").write_text("not a folder")
    argv = [a.format(file=tmp_path / "existing", tmp=tmp_path) for a in argv]
    assert main(argv) == EXIT_BAD_INPUT
    _one_line_error(capsys, fragment)


@pytest.mark.parametrize("argv", [["design", "fms_kr16", "-o", "{ro}"], ["design", "fms_kr16", "-o", "{ro}/new"],
                                  ["evaluate", "fms_kr16", "d.csv", "--plot", "{ro}/plots"],
                                  ["simulate", "fms_kr16", "-o", "{ro}/m.csv"],
                                  ["sequential", "fms_kr16", "--target-sigma", "20um", "-o", "{ro}"]])
def test_read_only_folders_stop_before_any_work(capsys, read_only, no_work, argv):
    assert main([a.format(ro=read_only) for a in argv]) == EXIT_BAD_INPUT
    _one_line_error(capsys, "cannot write there", "read-only")


def test_an_unwritable_folder_is_found_by_trying(capsys, tmp_path, monkeypatch, no_work):
    """What the read-only tests check, also where they are skipped (root): the probe
    that fails is what decides, not the mode bits."""
    import calib_oed.cli._contract as contract

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(contract.tempfile, "TemporaryFile", refuse)
    assert main(["design", "fms_kr16", "-o", str(tmp_path / "a" / "b")]) == EXIT_BAD_INPUT
    _one_line_error(capsys, f"{tmp_path}, where the folder would be created, is read-only")


def test_every_output_option_is_declared():
    """A new command that writes must declare its outputs, or nobody checks them."""
    parser = build_parser()
    sub = parser._subparsers._group_actions[0].choices
    inputs = {("identify", "truth")}  # identify --truth reads the truth of a simulation
    for name, p in sub.items():
        writes = {a.dest for a in p._actions} & {"output", "plot", "html", "truth"}
        writes -= {dest for command, dest in inputs if command == name}
        declared = set(p.get_default("outputs") or {})
        assert writes <= declared, (name, writes - declared)
    assert set(FIGURE_SUFFIXES) == set(FIGURE_FORMATS)


def test_check_output_accepts_what_can_be_written(tmp_path):
    check_output(tmp_path / "new" / "deeper", "dir", "-o")  # created later
    check_output(tmp_path, "dir", "-o")
    (tmp_path / "old.csv").write_text("x")
    check_output(tmp_path / "old.csv", "file", "-o")  # overwritten
    assert not (tmp_path / "new").exists()  # checking creates nothing
    # a file in a folder the same command creates first (identify -o cal --plot cal/res.png)
    check_output(tmp_path / "cal" / "res.png", "file", "--plot", created=(tmp_path / "cal",))
    with pytest.raises(OutputPathError, match="folder .*cal does not exist"):
        check_output(tmp_path / "cal" / "res.png", "file", "--plot")
    with pytest.raises(OutputPathError, match="empty path"):
        check_output("", "file", "-o")


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["feasibility", "fms_kr16", "--seed", "-3"], "expected a seed, an integer >= 0, got -3"),
        (["feasibility", "fms_kr16", "-n", "2.5"], "expected a whole number of poses, 1 to 10000, got '2.5'"),
        (["feasibility", "fms_kr16", "-n", "100000"], "a number of poses from 1 to 10000"),
        (["montecarlo", "fms_kr16", "--mc-seed", "x"], "expected a seed"),
        (["sequential", "fms_kr16", "--target-sigma", "-0.005mm"], "expected a length > 0, got '-0.005mm'"),
        (["design", "fms_kr16", "--criterion", "Z"], "invalid choice: 'Z'"),
        (["nonsense"], "invalid choice"),
        # an option another command has: named with the command and its help (review finding:
        # it was "calib-oed: calib-oed: unrecognized arguments: ... (see `calib-oed -h`)")
        (["validate", "fms_kr16", "cal", "v.csv", "--compliance"],
         "calib-oed validate: unrecognized arguments: --compliance (see `calib-oed validate -h`)"),
    ],
)
def test_argument_mistakes_are_one_line_exit_2(capsys, argv, fragment):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == EXIT_BAD_INPUT
    err = _one_line_error(capsys, fragment)
    assert "invalid _" not in err and "expected one argument" not in err


def test_a_folder_as_the_scene(capsys, tmp_path):
    (tmp_path / "cell.yaml").write_text("x: 1\n")
    assert main(["identifiability", str(tmp_path)]) == EXIT_BAD_INPUT
    _one_line_error(capsys, "is a folder; give a scene file (it holds cell.yaml)", "fms_kr16")


def test_a_scene_in_mm_declared_in_m_gets_a_unit_hint(capsys, tmp_path):
    from importlib import resources

    text = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml").read_text()
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(text.replace("units: {length: mm, angle: deg}", "units: {length: m, angle: deg}"))
    assert main(["feasibility", str(wrong), "-n", "5"]) == EXIT_BAD_INPUT
    _one_line_error(capsys, "2968 m from the robot base", "are the numbers in mm?", "units: {length: mm}")


def _design_yaml(path: Path, q: np.ndarray, names) -> Path:
    path.write_text(yaml.safe_dump({"format": "calib_oed design v1", "joint_names": list(names),
                                    "configurations_rad": q.tolist()}))
    return path


def test_start_takes_a_design_yaml_and_n_must_agree(capsys, tmp_path):
    from calib_oed import load_robot

    robot = load_robot("kr16")
    start = _design_yaml(tmp_path / "design.yaml", np.zeros((3, 6)), robot.joint_names)
    assert main(["design", "fms_kr16", "-n", "20", "--start", str(start)]) == EXIT_BAD_INPUT
    _one_line_error(capsys, f"--start {start} has 3 poses", "drop -n")


def test_quiet_wherever_json():
    sub = build_parser()._subparsers._group_actions[0].choices
    for name, p in sub.items():
        dests = {a.dest for a in p._actions}
        assert "json" not in dests or "quiet" in dests, name


def _child(code: str, argv: list[str], cwd: Path) -> subprocess.Popen:
    """The command in a child process, ``code`` run first (to make it slow or chatty);
    ``main()`` reads ``sys.argv`` there, as the console script does."""
    script = (f"import sys\n{code}\nfrom calib_oed.cli import main\n"
              f"sys.argv = ['calib-oed', *{argv!r}]\nsys.exit(main())\n")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-c", script], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


def _wait_for(proc: subprocess.Popen, marker: str, timeout: float = 60.0) -> str:
    seen, t0 = "", time.monotonic()
    while marker not in seen:
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            pytest.fail(f"the child ended before {marker!r}: {seen}")
        seen += line
        if time.monotonic() - t0 > timeout:
            proc.kill()
            pytest.fail(f"no {marker!r} in {timeout} s: {seen}")
    return seen


# The SQP holds in its second exact Hessian (after one iterate was accepted) until a signal
# arrives: the signal lands inside the SQP whatever the machine's speed (no race).
_HELD_SQP = """
import sys
import time
import calib_oed.oed.problem as problem
hessian = problem.DesignProblem.compute_lagrangian_hessian
calls = []
def held(self, *a, **k):
    calls.append(1)
    if len(calls) == 2:
        print("held in the SQP", file=sys.stderr, flush=True)
        while True:
            time.sleep(0.01)
    return hessian(self, *a, **k)
problem.DesignProblem.compute_lagrangian_hessian = held
"""


def test_interrupted_design_writes_the_best_design_so_far(tmp_path):
    """SIGTERM here (a scheduler stopping the job), SIGINT below: both take the Ctrl-C path."""
    proc = _child(_HELD_SQP, ["design", "fms_kr16", "-n", "12", "--pool", "200", "--no-certificate",
                              "--criterion", "kpi", "-o", "out"], tmp_path)  # kpi: the exact Hessian it holds in
    _wait_for(proc, "held in the SQP", timeout=600.0)  # the start takes a while on a loaded machine
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert "Traceback" not in err and "interrupted: the best feasible design found so far, written" in err
    assert "marked interrupted" in out
    data = yaml.safe_load((tmp_path / "out" / "design.yaml").read_text())
    assert data["interrupted"] is True and data["feasible"] is True and data["n"] == 12
    assert "# scene fms_kr16: INTERRUPTED kpi-optimal design of 12 poses" in (tmp_path / "out" / "design.csv").read_text()


def _children(pid: int) -> list[int]:
    return [int(c) for task in Path(f"/proc/{pid}/task").glob("*/children") for c in task.read_text().split()]


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc to see the workers")
def test_a_parallel_command_stops_its_workers_too(tmp_path):
    """SIGINT to the parent alone (not the terminal's process group): the joblib
    workers are stopped too, not waited for; one line, exit 130."""
    proc = _child("", ["montecarlo", "fms_kr16", "-n", "30", "-N", "100000", "--jobs", "2"], tmp_path)
    t0 = time.monotonic()
    while len(_children(proc.pid)) < 2 and proc.poll() is None and time.monotonic() - t0 < 60:
        time.sleep(0.1)
    workers = _children(proc.pid)
    assert len(workers) >= 2, proc.communicate()[1]
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)  # the 100000 runs would take minutes
    assert proc.returncode == EXIT_INTERRUPTED
    assert err.strip().splitlines()[-1] == "calib-oed: interrupted" and "Traceback" not in err
    time.sleep(0.5)
    alive = [w for w in workers if Path(f"/proc/{w}").exists()
             and "Z" not in Path(f"/proc/{w}/stat").read_text().split()[2]]
    assert not alive


def _handler_during_the_command(monkeypatch, call) -> object:
    """The SIGTERM handler in force while the command runs (seen from its output check)."""
    seen = []

    def record(args):
        seen.append(signal.getsignal(signal.SIGTERM))

    monkeypatch.setattr(cli, "check_outputs", record)
    call()
    return seen[0]


def test_signal_handlers_only_when_main_runs_as_the_command(monkeypatch, capsys):
    """In-process ``main([...])`` (tests) keeps the process's SIGTERM handler, so a time
    limit that sends SIGTERM to pytest stops pytest; ``main()`` on ``sys.argv`` (the
    console script, ``python -m calib_oed``) installs the command's and restores the
    previous one afterwards."""
    before = signal.getsignal(signal.SIGTERM)
    assert _handler_during_the_command(monkeypatch, lambda: main(["robots"])) is before
    monkeypatch.setattr(sys, "argv", ["calib-oed", "robots"])
    during = _handler_during_the_command(monkeypatch, main)
    assert during is not before and callable(during)
    assert signal.getsignal(signal.SIGTERM) is before
    assert _handler_during_the_command(monkeypatch, lambda: main(["robots"], as_command=True)) is not before


def test_progress_is_plain_lines_without_a_terminal(capsys, monkeypatch):
    import calib_oed.cli._common as common

    class Args:
        quiet, json = False, False

    class Record:
        iteration, objective, violation = 3, 0.5, 1e-9

    monkeypatch.setattr(common, "PROGRESS_LINE_SECONDS", 0.0)
    callback, bar = common._progress(Args(), "kpi-optimal design")
    assert bar is None and not common._bars(Args())  # capsys: stderr is no terminal
    callback(Record())
    err = capsys.readouterr().err
    assert err == "kpi-optimal design: iteration 3, objective 0.5, violation 1.0e-09\n"
    callback.stage(250)  # a staged design names the poses of the design the lines are of
    callback(Record())
    assert capsys.readouterr().err == "kpi-optimal design, 250 poses: iteration 3, objective 0.5, violation 1.0e-09\n"
    Args.quiet = True
    assert common._progress(Args(), "x") == (None, None)


def test_the_progress_bar_starts_over_at_each_stage():
    import io

    from tqdm import tqdm

    import calib_oed.cli._common as common

    class Record:
        iteration, objective, violation = 0, 0.5, 1e-9

    bar = tqdm(desc="kpi_model-optimal design", file=io.StringIO())
    progress = common._Progress("kpi_model-optimal design", bar)
    progress(Record())
    progress(Record())
    assert bar.n == 2
    progress.stage(500)
    assert bar.n == 0 and bar.desc.startswith("kpi_model-optimal design, 500 poses")
    progress(Record())
    assert bar.n == 1
    bar.close()


def test_round_trip_is_reported_in_mm():
    from calib_oed.cli._common import _round_trip_text

    assert _round_trip_text(5.09e-16).startswith("5.1e-13 mm (floating-point round-off")
    assert _round_trip_text(2e-6) == "0.002 mm"


def test_simulate_warns_about_colliding_poses(capsys, tmp_path):
    from calib_oed.calibration.workflow import setup
    from calib_oed.io.design_file import write_design_csv

    s = setup("fms_kr16")
    q = s.problem.robot.random_configurations(40, np.random.default_rng(0))
    bad = ~s.feasibility.compute(q, jacobian=False).feasible
    assert bad.any()
    design = write_design_csv(tmp_path / "d.csv", s.problem.robot, q)
    assert main(["simulate", "fms_kr16", str(design), "-o", str(tmp_path / "m.csv"), "--quiet"]) == EXIT_OK
    err = capsys.readouterr().err
    assert f"note: {bad.sum()} of 40 poses of the design file {design} violate" in err
    assert (tmp_path / "m.csv").is_file()


def test_duplicate_design_rows_are_a_note_on_the_command_line(capsys, tmp_path):
    design = tmp_path / "d.csv"
    design.write_text("joint_a1,joint_a2,joint_a3,joint_a4,joint_a5,joint_a6\n"
                      "0,-1.2,1.8,0,0.5,0\n0,-1.2,1.8,0,0.5,0\n")
    assert main(["feasibility", "fms_kr16", str(design), "--no-mesh-check", "--quiet"]) == EXIT_OK
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "calib-oed: note:" in err and "line 3 = line 2" in err


def test_demo_writes_to_demo_out_by_default():
    args = build_parser().parse_args(["demo"])
    assert args.output == "demo_out"
    assert tempfile.gettempdir() not in args.output


@pytest.mark.parametrize("argv, expected", [
    (["identify", "--joint-gains", "fms_kr16", "m.csv"],
     ["identify", "--joint-gains=all", "fms_kr16", "m.csv"]),
    (["identify", "fms_kr16", "m.csv", "--joint-gains"], ["identify", "fms_kr16", "m.csv", "--joint-gains=all"]),
    (["design", "--joint-gains", "2,3", "fms_kr16"], ["design", "--joint-gains=2,3", "fms_kr16"]),
    (["design", "--joint-gains", "all", "fms_kr16"], ["design", "--joint-gains=all", "fms_kr16"]),
    (["design", "--joint-g", "fms_kr16"], ["design", "--joint-gains=all", "fms_kr16"]),
    (["design", "--joint-g=5", "fms_kr16"], ["design", "--joint-gains=5", "fms_kr16"]),
    (["design", "fms_kr16", "--joint-gains", "-n", "5"], ["design", "fms_kr16", "--joint-gains=all", "-n", "5"]),
    (["design", "--jo", "2"], ["design", "--jo", "2"]),  # --jobs, --json: ambiguous, argparse decides
    (["view", "--", "--joint-gains", "2"], ["view", "--", "--joint-gains", "2"]),
])
def test_an_option_with_an_optional_value_takes_only_a_value_of_its_form(argv, expected):
    """``--joint-gains`` never swallows the positional argument after it (argparse's nargs='?' did)."""
    from calib_oed.cli._contract import attach_optional_values

    assert attach_optional_values(argv, build_parser()) == expected


def test_no_option_takes_an_optional_value_from_argparse():
    """Every option with an optional value goes through ``attach_optional_values``: argparse's
    ``nargs='?'`` on an option swallows the next argument, whatever it is."""
    parser = build_parser()
    for sub in [parser, *parser._subparsers._group_actions[0].choices.values()]:
        for action in sub._actions:
            assert not (action.option_strings and action.nargs in ("?", "*")), (sub.prog, action.option_strings)


def test_joint_gains_before_the_scene_keeps_the_scene(capsys):
    capsys.readouterr()
    assert main(["identifiability", "--joint-gains", "fms_kr16", "--json"]) == EXIT_OK
    assert "joint6.gain" in capsys.readouterr().out
    assert main(["identifiability", "--joint-gains", "4", "fms_kr16", "--json"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "joint4.gain" in out and "joint3.gain" not in out
