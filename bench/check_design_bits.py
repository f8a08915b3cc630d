"""Check: the designs of this checkout are those of another one, bit for bit.

Run from the repository root:

    PYTHONPATH=/other/checkout .venv/bin/python bench/check_design_bits.py --out REF
    PYTHONPATH=. .venv/bin/python bench/check_design_bits.py --out NEW --reference REF

Runs ``calib-oed design`` (one process each, in ``OUT``, the code on ``PYTHONPATH``) for four cases: the
default call ``fms_kr16 -n 60 --seed 0``, ``--criterion kpi -n 60``, ``--criterion kpi -n 250
--no-certificate`` and ``ur5_table -n 60``, each into ``OUT/<case>``. With ``--reference`` it
compares ``design.csv`` byte for byte and every value of ``design.yaml`` (floats by their exact
bits; ``timing.yaml`` holds the times and is not compared) and prints one line per case. Exit
status 1 when a case differs. A speed-up that keeps the designs valid for a study rerun on the
code before it must pass this check (issue 33).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import yaml
from _children import child_env, package_run  # bench/ is the script folder, first on sys.path

CASES = {
    "default": ["fms_kr16", "-n", "60", "--seed", "0"],
    "kpi60": ["fms_kr16", "--criterion", "kpi", "-n", "60"],
    "ur5": ["ur5_table", "-n", "60"],
    "kpi250": ["fms_kr16", "--criterion", "kpi", "-n", "250", "--no-certificate"],
}


#: Keys of the solver's record that count work, not results (trial points evaluated without
#: derivatives change them and nothing else): not compared.
EFFORT = {"n_objective_evaluations", "n_constraint_evaluations", "n_value_evaluations"}


def differences(a, b, path: str = "") -> list[str]:
    """Paths at which two parsed YAML documents differ (floats compared by their exact value;
    the keys of :data:`EFFORT` skipped)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}/{k}: only in one" for k in sorted((set(a) ^ set(b)) - EFFORT, key=str)]
        for k in (a.keys() & b.keys()) - EFFORT:
            out += differences(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} against {len(b)} items"]
        return [d for k, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, f"{path}[{k}]")]
    same = a == b or (isinstance(a, float) and isinstance(b, float) and a != a and b != b)  # NaN
    return [] if same and type(a) is type(b) else [f"{path}: {a!r} against {b!r}"]


def run(case: str, out: Path) -> float:
    """One design of ``case`` into ``out/case``; its process CPU time [s]."""
    target = (out / case).resolve()
    target.parent.mkdir(parents=True, exist_ok=True)
    before = os.times()
    # run in `out`, not here: `python -m` puts its working directory first on sys.path, so from a
    # checkout's root the package of that checkout would run whatever PYTHONPATH says
    subprocess.run([sys.executable, "-m", "calib_oed", "design", *CASES[case], "-o", str(target), "--quiet"],
                   check=True, stdout=subprocess.DEVNULL, cwd=target.parent, env=child_env())
    after = os.times()
    return (after.children_user - before.children_user) + (after.children_system - before.children_system)


def compare(case: str, out: Path, reference: Path) -> list[str]:
    """What differs between the design of ``case`` in ``out`` and in ``reference``."""
    new, ref = out / case, reference / case
    diff = [] if (new / "design.csv").read_bytes() == (ref / "design.csv").read_bytes() else ["design.csv"]
    load = lambda p: yaml.safe_load((p / "design.yaml").read_text())  # noqa: E731
    return diff + differences(load(new), load(ref))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="directory for the designs")
    ap.add_argument("--reference", type=Path, help="the designs of the other checkout (compared)")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    ap.add_argument("--compare-only", action="store_true", help="compare designs already in --out")
    args = ap.parse_args(argv)
    cases = [c for c in args.cases.split(",") if c]
    unknown = sorted(set(cases) - set(CASES))
    if unknown:
        ap.error(f"unknown case(s) {unknown}; valid: {', '.join(CASES)}")
    if not args.compare_only:
        args.out.mkdir(parents=True, exist_ok=True)
        print(f"code: {package_run(args.out)}", flush=True)
    failed = False
    for case in cases:
        cpu = float("nan") if args.compare_only else run(case, args.out)
        line = f"{case:8s} {' '.join(CASES[case]):45s} process CPU {cpu:7.1f} s"
        if args.reference is not None:
            diff = compare(case, args.out, args.reference)
            failed |= bool(diff)
            line += "  identical" if not diff else f"  DIFFERS ({len(diff)}): {'; '.join(diff[:3])}"
        print(line, flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
