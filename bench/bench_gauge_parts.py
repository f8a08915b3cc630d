"""The world frame's gauge share after identification, part by part of the realistic model error.

``identify`` predicts the TCP accuracy in the world (robot base) frame as the tracker-frame
prediction plus the *gauge share*: the rigid move of the base that the fit's tracker pose takes
from the unmodelled joint errors, which the residuals cannot show (:mod:`calib_oed.calibration.world_frame`:
the joint-space prior's share, scaled to the model error fitted). This bench sets that share,
predicted and achieved (world minus tracker TCP error variance at the working configurations,
pooled over truths), against realistic truths (:mod:`calib_oed.calibration.realistic`) that carry
one part of the model error each (the parts of ``bench/bench_prior_parts.py``; the geometric
errors always), on 60 random training poses per truth, as ``bench/bench_trust.py --frame world``
does with every part on.

``--compliance-signs random`` flips the sign of each joint's drawn compliance at random (seeded per
truth): a real arm's compliances are all positive, the prior draws them independent with zero
mean; if the shares then agree, that difference is the cause.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python bench/bench_gauge_parts.py --scene SCENE [--truths 6]
        [--parts all,compliance,...] [--compliance-signs random]

Prints per part: the gauge share predicted and achieved [mm²], the TCP's world-frame RMS predicted and
achieved [mm], and the new poses' world and tracker predicted/achieved.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from bench_prior_parts import TRUTHS  # bench/ is the script folder, first on sys.path
from bench_trust import world_case

import calib_oed.calibration.realistic as realistic
from calib_oed import load_scene
from calib_oed.calibration.realistic_defaults import realistic_settings_from_scene
from calib_oed.calibration.workflow import setup


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", required=True)
    ap.add_argument("--truths", type=int, default=6)
    ap.add_argument("--parts", default="all,compliance,transmission,periodic,motor,gains,tracker")
    ap.add_argument("--compliance-signs", choices=("drawn", "random"), default="drawn")
    args = ap.parse_args(argv)
    s = setup(load_scene(args.scene))
    base = realistic_settings_from_scene(s.scene)
    draw = realistic.sample_truth
    for part in args.parts.split(","):
        settings = dataclasses.replace(base, **TRUTHS[part])

        def truth(setup_, rng, _settings=None, settings=settings):
            t = draw(setup_, rng, settings)
            if args.compliance_signs == "random":
                flip = np.random.default_rng([7, *np.frombuffer(t.stiffness.tobytes(), np.uint32)[:4]])
                t = dataclasses.replace(t, compliance=t.compliance * flip.choice([-1.0, 1.0], t.compliance.shape))
            return t

        realistic.sample_truth = truth  # world_case draws its truths by this name
        try:
            rows = [world_case(s, k, "realistic", 60, 200) for k in range(args.truths)]
        finally:
            realistic.sample_truth = draw
        n = sum(r["n_work"] for r in rows)
        share_pred = sum(r["gauge_share_mm2"] for r in rows) / n
        share_ach = sum(r["tcp_world_ach_mm2"] - r["tcp_tracker_ach_mm2"] for r in rows) / n
        world = [np.sqrt(sum(r[k] for r in rows) / n) for k in ("tcp_world_pred_mm2", "tcp_world_ach_mm2")]
        ratio = {f: np.sqrt(sum(r[f"{f}_new_pred_mm"] ** 2 for r in rows) / sum(r[f"{f}_new_ach_mm"] ** 2 for r in rows))
                 for f in ("world", "tracker")}
        print(f"{s.scene.name} {part:12s} signs {args.compliance_signs}: gauge share predicted {share_pred:+.5f} "
              f"achieved {share_ach:+.5f} mm2; TCP world {world[0]:.4f} / {world[1]:.4f} mm; new poses "
              f"predicted/achieved world {ratio['world']:.2f}, tracker {ratio['tracker']:.2f}", flush=True)


if __name__ == "__main__":
    main()
