"""Benchmark: size of the viewer's static page for a 60-pose UR10 design (issue 21).

Run from the repository root:

    .venv/bin/python bench/bench_viewer_page.py [--poses 60] [--out DIR]

The scene is ``bench/scenes/ur10_cell.yaml`` (a UR10 from example-robot-data,
meshes), the design ``heuristic_design(s, 60, seed=0)``. The page is written
with ``robot_drawing="auto"`` (the default: capsules when the meshes would
exceed ``MESH_BUDGET_BYTES``) and ``"visual"`` (meshes whatever the size);
printed: which drawing was used, the file size [MB], wall and CPU time of
this process [s] (the meshcat server is a separate process, not counted in
CPU). Only the public ``write_static_html`` is used, so the same command
measures an older checkout for a before/after comparison. With ``--chromium``
each page is also loaded in headless Chromium (a screenshot once it has loaded;
the flags of tests/viz/test_viewer.py) and the wall time of that is printed
(issue 34: a 60-pose mesh page loads in <= 30 s). Results in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from calib_oed import load_scene, setup
from calib_oed.calibration.workflow import heuristic_design
from calib_oed.viz.sessions import write_static_html

SCENE = Path(__file__).resolve().parent / "scenes" / "ur10_cell.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--out", type=Path, default=None, help="folder for the pages (default: temporary)")
    parser.add_argument("--chromium", action="store_true", help="also time loading each page in headless Chromium")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_viewer_"))
    out.mkdir(parents=True, exist_ok=True)
    s = setup(load_scene(str(SCENE)))
    q = heuristic_design(s, args.poses, seed=0)
    print(f"{args.poses}-pose design of {s.scene.name} (robot {s.scene.robot.name})")
    for drawing in ("auto", "visual"):
        wall, cpu = time.perf_counter(), time.process_time()
        view = write_static_html(out / f"view_{drawing}.html", s, q, robot_drawing=drawing)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        size = view.path.stat().st_size
        print(f"robot_drawing={drawing!r:9} drawn as {view.info.robot_drawing!r:10} page {size / 1e6:6.1f} MB "
              f"wall {wall:5.1f} s, CPU {cpu:5.1f} s  {view.path}")
        for note in view.info.notes:
            print(f"    note: {note}")
        if args.chromium:
            print(f"    headless Chromium: loaded and drawn in {_chromium_seconds(view.path):.1f} s (wall)")


def _chromium_seconds(page: Path) -> float:
    """Wall time of headless Chromium writing a screenshot of ``page`` (it waits for the load)."""
    import shutil
    import subprocess

    exe = next(filter(None, (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome"))))
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-extensions",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--virtual-time-budget=5000",
             f"--user-data-dir={page.parent / 'chromium-profile'}",
             f"--screenshot={page.with_suffix('.png')}", "--window-size=1024,768"]
    start = time.perf_counter()
    subprocess.run([exe, *flags, page.as_uri()], capture_output=True, timeout=600, check=False)
    seconds = time.perf_counter() - start
    if not page.with_suffix(".png").is_file():
        raise SystemExit(f"chromium wrote no screenshot of {page}")
    return seconds


if __name__ == "__main__":
    main()
