"""Same seed, same design files: two `calib-oed design` processes at once write the same bytes
(issue 31). Before the fixes ProxQP's last bits, which depend on where its buffers lie, made
three runs of the cheap call below end at three different designs (the approximate design's QP
is now solved by `solver/simplex_qp.py`), and two ur5_table designs at different certificates
(ProxQP's AVX2 build: `solver/proxqp_build.py` loads its SSE2 build)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from threadpoolctl import threadpool_info, threadpool_limits

from calib_oed import cli
from calib_oed.oed.result import TIMING_KEYS, split_timing


def _designs_in_parallel(tmp_path: Path, argv: list[str], runs: int = 2) -> list[Path]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs, outs = [], []
    for k in range(runs):
        out = tmp_path / f"run{k}"
        outs.append(out)
        procs.append(subprocess.Popen([sys.executable, "-m", "calib_oed", "design", *argv, "-o", str(out),
                                       "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                      text=True, env=env))
    for p in procs:
        _, err = p.communicate(timeout=1800)
        assert p.returncode == 0, err
    return outs


def _assert_same_bytes(outs: list[Path]) -> None:
    for name in ("design.csv", "design.yaml"):
        first = (outs[0] / name).read_bytes()
        assert all((o / name).read_bytes() == first for o in outs[1:]), name
    assert "seconds" not in (outs[0] / "design.yaml").read_text()
    assert "seconds" in yaml.safe_load((outs[0] / "timing.yaml").read_text())


def test_two_processes_same_seed_same_bytes(tmp_path):
    """The default pipeline's path (approximate design with local maxima, exchange, SQP), small."""
    outs = _designs_in_parallel(tmp_path, ["fms_kr16", "-n", "12", "--pool", "200", "--no-certificate",
                                           "--no-collisions", "--iterations", "10"])
    _assert_same_bytes(outs)


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["fms_kr16", "ur5_table"])
def test_two_default_designs_same_bytes(tmp_path, scene):
    """The issue's target: `calib-oed design SCENE -n 60`, two processes at once (~5 min each on 2 busy cores),
    with the noise-only criterion `kpi`, whose certificate (the column generation continued) was the last
    source of different bits."""
    _assert_same_bytes(_designs_in_parallel(tmp_path, [scene, "-n", "60", "--criterion", "kpi"]))


def test_split_timing_keeps_the_structure():
    record = {"seconds": 1.5, "value": 2.0, "solver": {"times": {"qp": 0.1}, "iterations": 3,
              "history": [{"time": 0.2, "objective": 1.0}, {"time": 0.3, "objective": 0.5}]},
              "certificate": {"cpu_seconds": 4.0, "bound": 1.0}, "margins": [{"slack": 0.0}]}
    content, timing = split_timing(record)
    assert content == {"value": 2.0, "solver": {"iterations": 3, "history": [{"objective": 1.0},
                       {"objective": 0.5}]}, "certificate": {"bound": 1.0}, "margins": [{"slack": 0.0}]}
    assert timing == {"seconds": 1.5, "solver": {"times": {"qp": 0.1}, "history": [{"time": 0.2}, {"time": 0.3}]},
                      "certificate": {"cpu_seconds": 4.0}}
    assert not TIMING_KEYS & set(yaml.safe_dump(content).replace(":", " ").split())


def test_a_command_runs_with_one_blas_thread(monkeypatch):
    """What a command writes after its solve must not depend on the caller's thread count, so the
    whole command runs with one BLAS thread (before, `design fms_kr16_program -n 60` under
    OPENBLAS_NUM_THREADS=2 wrote a criterion value that differed in its last digit)."""
    seen = []

    def command(args):
        seen.append({info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"})
        return 0

    monkeypatch.setattr(cli, "cmd_scenes", command)
    with threadpool_limits(limits=2, user_api="blas"):
        assert {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"} == {2}
        assert cli.main(["scenes"]) == 0
    assert seen == [{1}]
