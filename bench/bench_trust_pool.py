"""Pooled predicted/achieved over the truths of ``bench_trust.py --frame world --json`` files.

Each file holds one row per (scene, truth); the rows of all files given are pooled per scene:
the ratio of the RMS predicted error to the RMS achieved error over the truths, with its standard
error and 95 % interval by bootstrap over the truths (20000 resamples, seed 0), for the TCP at the
working configuration (world and tracker frame) and for the new poses; the per-truth new-pose
ratios in the world frame and how many lie in 0.8-1.25; the mean gauge share at the TCP [mm²].

    python bench/bench_trust.py --frame world --source realistic --scenes fms_kr16 --truths 10 --json w0.json
    python bench/bench_trust.py --frame world --source realistic --scenes fms_kr16 --first-truth 10 --truths 10 --json w10.json
    python bench/bench_trust.py --frame world --source realistic --scenes fms_kr16 --first-truth 20 --truths 10 --json w20.json
    python bench/bench_trust_pool.py w0.json w10.json w20.json
"""

from __future__ import annotations

import argparse
import json

import numpy as np

RESAMPLES = 20_000
BAND = (0.8, 1.25)


def pooled(pred_ach: np.ndarray) -> float:
    """RMS of the predicted errors over RMS of the achieved ones, (m, 2) [mm] per truth."""
    return float(np.sqrt(np.sum(pred_ach[:, 0] ** 2) / np.sum(pred_ach[:, 1] ** 2)))


def bootstrap(pred_ach: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The pooled ratio of :data:`RESAMPLES` resamples of the truths."""
    m = len(pred_ach)
    return np.array([pooled(pred_ach[rng.integers(0, m, m)]) for _ in range(RESAMPLES)])


def report(rows: list[dict]) -> list[str]:
    """The pooled figures of one scene's rows, one line each."""
    rng = np.random.default_rng(0)
    measures = {
        "TCP, world frame": [(np.sqrt(r["tcp_world_pred_mm2"]), np.sqrt(r["tcp_world_ach_mm2"])) for r in rows],
        "TCP, tracker frame": [(np.sqrt(r["tcp_tracker_pred_mm2"]), np.sqrt(r["tcp_tracker_ach_mm2"])) for r in rows],
        "new poses, world frame": [(r["world_new_pred_mm"], r["world_new_ach_mm"]) for r in rows],
        "new poses, tracker frame": [(r["tracker_new_pred_mm"], r["tracker_new_ach_mm"]) for r in rows],
    }
    out = []
    for name, values in measures.items():
        x = np.asarray(values, dtype=float)
        b = bootstrap(x, rng)
        out.append(f"  {name}: pooled {pooled(x):.2f} ± {np.std(b):.2f} "
                   f"(95 % {np.quantile(b, 0.025):.2f}-{np.quantile(b, 0.975):.2f})")
    ratio = np.array([r["world_new_pred_mm"] / r["world_new_ach_mm"] for r in rows])
    inside = int(np.sum((ratio >= BAND[0]) & (ratio <= BAND[1])))
    out.append(f"  new poses, world frame, per truth: {ratio.min():.2f}-{ratio.max():.2f}, "
               f"{inside} of {len(ratio)} in {BAND[0]}-{BAND[1]}")
    share_pred = np.mean([r["gauge_share_mm2"] for r in rows])
    share_ach = np.mean([r["tcp_world_ach_mm2"] - r["tcp_tracker_ach_mm2"] for r in rows])
    out.append(f"  gauge share at the TCP, mean predicted / achieved: {share_pred:+.3f} / {share_ach:+.3f} mm²")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", metavar="JSON", help="bench_trust.py --frame world --json files")
    args = ap.parse_args()
    rows = [row for name in args.files for row in json.load(open(name))]
    for scene in sorted({r["scene"] for r in rows}):
        mine = [r for r in rows if r["scene"] == scene]
        print(f"{scene}: {len(mine)} truths")
        print("\n".join(report(mine)))


if __name__ == "__main__":
    main()
