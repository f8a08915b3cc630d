"""Benchmark: what the bounded YAML reader costs on hostile and on large legitimate files (issue 34).

Run from the repository root:

    .venv/bin/python bench/bench_yaml_bounds.py

Printed, wall time and peak memory of this process (``ru_maxrss``) after each case:
an alias bomb (9 levels of 10 aliases, 1e10 values expanded), an 8 MB flow list
of 1.6 million numbers (both refused), and a 10000-pose ``design.yaml`` as
``calib-oed design -o`` writes it (block style, radians and degrees; read).
Results in docs/benchmarks.md.
"""

from __future__ import annotations

import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from calib_oed.exceptions import InputFileError
from calib_oed.scene.yaml_file import MAX_YAML_BYTES, load_yaml, load_yaml_file


def _case(name: str, call) -> None:
    start = time.perf_counter()
    try:
        call()
        outcome = "read"
    except InputFileError as exc:
        outcome = f"refused ({exc.problem[:60]}...)"
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{name:28} {outcome:80} {seconds * 1e3:9.1f} ms, peak RSS {peak:6.0f} MB")


def main() -> None:
    bomb = ["x0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    bomb += [f"x{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 10)]
    _case("alias bomb (1e10 values)", lambda: load_yaml("\n".join(bomb)))
    _case("8 MB flow list (1.6e6)", lambda: load_yaml("x: [" + ", ".join(["1.5"] * 1_600_000) + "]\n"))
    rng = np.random.default_rng(0)
    q = rng.uniform(-3, 3, (10_000, 6))
    data = {"format": "calib_oed design v1", "scene": "fms_kr16", "robot": "kr16",
            "joint_names": [f"joint_a{i}" for i in range(1, 7)], "configurations_rad": q.tolist(),
            "configurations_deg": np.degrees(q).round(6).tolist()}
    path = Path(tempfile.mkdtemp()) / "design.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, width=120))
    print(f"10000-pose design.yaml: {path.stat().st_size / 2**20:.1f} MiB")
    _case("10000-pose design.yaml", lambda: load_yaml_file(path, "design file", MAX_YAML_BYTES))


if __name__ == "__main__":
    main()
