"""Box obstacles against the capsule sets that stood for them (issue 17, items 3-4).

For ``fms_kr16`` and the UR10 bench cell, the car as capsules (the scene as
shipped before issue 17) and as boxes enclosing the same body: constraint
rows per pose after the pruning pass, the time to sample 60 feasible poses
(seed 0, wall and CPU), all constraint values + Jacobian at these 60 poses
(wall: best of 7 samples of the mean of 20 calls; CPU: mean of 20 calls),
and the acceptance rate of uniform random configurations (what the rejection
sampler sees), on the same 20000 draws (seed 0). Run from the repository root:

    .venv/bin/python bench/bench_obstacles.py
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
import yaml
from _timing import timed

from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.scene.reader import scene_from_dict

ROOT = Path(__file__).resolve().parents[1]

#: The car of fms_kr16 as boxes [mm]: the lower body x 1300..3100, y -2250..2250 (the capsules'
#: extent along y), z 100..1000; the cabin x 1500..3100, y -1300..1300, z 1000..1450.
KR16_CAR = [{"name": "car_body", "center": [2200, 0, 550], "size": [1800, 4500, 900]},
            {"name": "car_cabin", "center": [2300, 0, 1225], "size": [1600, 2600, 450]}]
#: The UR10 cell's car: lower body x 1100..2000 (z -100..800), cabin x 1350..2150 (z 800..1200).
UR10_CAR = [{"name": "car_body", "center": [1550, 0, 350], "size": [900, 4500, 900]},
            {"name": "car_cabin", "center": [1750, 0, 1000], "size": [800, 2400, 400]}]

CASES = (("fms_kr16", ROOT / "calib_oed/scene/shipped/fms_kr16.yaml", KR16_CAR),
         ("ur10_cell", ROOT / "bench/scenes/ur10_cell.yaml", UR10_CAR))


def variants(path: Path, boxes: list[dict]):
    data = yaml.safe_load(path.read_text())
    caps = copy.deepcopy(data)
    caps["cell"]["capsules"] = [c for c in caps["cell"]["capsules"] if not c["name"].startswith("car_")]
    caps["cell"].pop("boxes", None)
    cap_data = copy.deepcopy(data)
    cap_data["cell"].pop("boxes", None)
    box_data = copy.deepcopy(caps)
    box_data["cell"]["boxes"] = boxes
    if not any(c["name"].startswith("car_") for c in cap_data["cell"].get("capsules", [])):
        return None  # the file already has boxes: nothing to compare
    return {"capsule car": scene_from_dict(cap_data, source=str(path)),
            "box car": scene_from_dict(box_data, source=str(path))}


def main() -> None:
    print(f"{'cell':10s} {'car':12s} {'rows/pose':>9s} {'obst':>5s} {'beam':>5s} {'sample 60 [s] wall/cpu':>22s}"
          f" {'values+J [ms] wall/cpu':>22s} {'accepted of 20000':>18s}")
    for name, path, boxes in CASES:
        scenes = variants(path, boxes)
        if scenes is None:
            print(f"{name}: already boxes in the file; compare against the git history")
            continue
        draws = next(iter(scenes.values())).robot.random_configurations(20000, 0)
        for label, scene in scenes.items():
            fm, _ = feasibility_from_scene(scene)
            start, cpu0 = time.perf_counter(), time.process_time()
            q = sample_feasible(fm, 60, 0)
            sample = (time.perf_counter() - start, time.process_time() - cpu0)
            wall, _ = timed(lambda fm=fm, q=q: fm.compute(q), 7, 20)
            start = time.process_time()
            for _ in range(20):
                fm.compute(q)
            cpu = (time.process_time() - start) / 20
            ok = np.concatenate([fm.compute(draws[k:k + 2000], jacobian=False).feasible
                                 for k in range(0, len(draws), 2000)])
            counts = fm.count_per_pose()
            print(f"{name:10s} {label:12s} {fm.n_constraints:9d} {counts['obstacle']:5d} {counts['beam']:5d}"
                  f" {sample[0]:11.2f} / {sample[1]:5.2f}   {wall * 1e3:9.2f} / {cpu * 1e3:6.2f}"
                  f"   {ok.sum():8d} ({100 * ok.mean():.2f} %)")


if __name__ == "__main__":
    main()
