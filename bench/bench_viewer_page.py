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
and the CPU time of all its processes (issue 34: a 60-pose mesh page loads in
<= 30 s). ``--page-only`` skips writing: it times the pages already in ``--out``
(a before/after comparison of two checkouts' pages side by side). Results in
docs/benchmarks.md.
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
    parser.add_argument("--page-only", action="store_true", help="only time Chromium on the pages in --out")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_viewer_"))
    out.mkdir(parents=True, exist_ok=True)
    if args.page_only:
        for page in sorted(out.glob("*.html")):
            wall, cpu = _chromium_seconds(page)
            print(f"{page.name}: {page.stat().st_size / 1e6:.1f} MB, headless Chromium {wall:.1f} s wall, "
                  f"{cpu:.1f} s CPU")
        return
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
            wall, cpu = _chromium_seconds(view.path)
            print(f"    headless Chromium: loaded and drawn in {wall:.1f} s wall, {cpu:.1f} s CPU "
                  "(all its processes)")


def _chromium_seconds(page: Path) -> tuple[float, float]:
    """Wall time of headless Chromium writing a screenshot of ``page`` (it waits for the load), and
    the CPU time of all its processes (read from /proc while it runs: the GPU process that draws
    with SwiftShader is not a child Chromium waits for), both [s]."""
    import shutil
    import subprocess

    exe = next(filter(None, (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome"))))
    profile = page.parent / f"chromium-profile-{page.stem}"
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-extensions",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--virtual-time-budget=5000",
             f"--user-data-dir={profile}",
             f"--screenshot={page.with_suffix('.png')}", "--window-size=1024,768"]
    cpu: dict[int, float] = {}
    start = time.perf_counter()
    proc = subprocess.Popen([exe, *flags, page.as_uri()], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while proc.poll() is None and time.perf_counter() - start < 600:
        cpu.update(_cpu_seconds(str(profile)))
        time.sleep(0.2)
    if proc.poll() is None:
        proc.kill()
        proc.wait()
    seconds = time.perf_counter() - start
    if not page.with_suffix(".png").is_file():
        raise SystemExit(f"chromium wrote no screenshot of {page}")
    return seconds, sum(cpu.values())


def _cpu_seconds(marker: str) -> dict[int, float]:
    """CPU time [s] (user + system) of each running process whose command line holds ``marker``."""
    import os

    tick = os.sysconf("SC_CLK_TCK")
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if marker.encode() not in (entry / "cmdline").read_bytes():
                continue
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        found[int(entry.name)] = (int(fields[11]) + int(fields[12])) / tick
    return found


if __name__ == "__main__":
    main()
