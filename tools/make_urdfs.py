"""Regenerate the shipped URDFs ``urdf/kr16.urdf``, ``kr300.urdf`` and ``kr500.urdf``.

Usage, from the repository root::

    python tools/make_urdfs.py           # rewrite the files
    python tools/make_urdfs.py --check   # exit 1 if a file differs from the generator
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:  # run from a checkout that is not installed
    sys.path.insert(0, str(REPO_ROOT))

from calib_oed.model.kuka import KUKA_ROBOTS, kuka_urdf, write_kuka_urdf  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare, write nothing")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "urdf", help="target folder")
    args = parser.parse_args(argv)
    stale = []
    for key, dims in KUKA_ROBOTS.items():
        path = args.out / f"{key}.urdf"
        if args.check:
            current = path.read_text(encoding="utf-8") if path.exists() else None
            if current != kuka_urdf(dims):
                stale.append(path)
        else:
            write_kuka_urdf(dims, path)
            print(f"wrote {path}")
    for path in stale:
        print(f"out of date: {path} (run python tools/make_urdfs.py)", file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
