"""Bad inputs across every command (issue 34): each is exit 2 with one line naming the
problem, no traceback, nothing written, and before any heavy step (no hang: no solver,
identification, Monte Carlo run or viewer server starts; a work bound, not a clock, so the
check holds under any load).

One table, by kind: outputs that are not regular files or clash, options the command
would silently drop, numbers outside their meaning, files of another robot or scene,
scene YAML beyond its bounds, plain mistakes that used to be internal errors.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path

import pytest
import yaml

from calib_oed.calibration.workflow import (
    setup,
    simulated_measurements,
    write_measurement_file,
    write_truth,
)
from calib_oed.cli import EXIT_BAD_INPUT, main
from calib_oed.io.design_file import write_design_csv
from calib_oed.io.measurement_reader import read_measurements
from calib_oed.model.robot import load_robot

SHIPPED = Path(__file__).resolve().parents[2] / "calib_oed" / "scene" / "shipped" / "fms_kr16.yaml"

_BOMB = ("[&a [1,1,1,1,1,1,1,1,1,1], &b [*a,*a,*a,*a,*a,*a,*a,*a,*a,*a], &c [*b,*b,*b,*b,*b,*b,*b,*b,*b,*b], "
         "&d [*c,*c,*c,*c,*c,*c,*c,*c,*c,*c], &e [*d,*d,*d,*d,*d,*d,*d,*d,*d,*d], "
         "&f [*e,*e,*e,*e,*e,*e,*e,*e,*e,*e], &g [*f,*f,*f,*f,*f,*f,*f,*f,*f,*f], "
         "&h [*g,*g,*g,*g,*g,*g,*g,*g,*g,*g], &i [*h,*h,*h,*h,*h,*h,*h,*h,*h,*h]]")


def _scene_variant(folder: Path, name: str, old: str, new: str) -> None:
    text = SHIPPED.read_text()
    assert old in text
    (folder / name).write_text(text.replace(old, new, 1))


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The inputs of the table: good files of two scenes and bad ones of every kind."""
    d = tmp_path_factory.mktemp("inputs")
    for scene, stem in (("fms_kr16", "m"), ("ur5_table", "ur5")):  # no feasibility model: fast
        s = setup(scene)
        mset, p_true = simulated_measurements(s, s.problem.robot.random_configurations(12, 0), 1)
        write_measurement_file(s, d / f"{stem}.csv", mset, "bad-input table")
        write_truth(d / f"{stem}_truth.yaml", s, p_true, 1)
    kr16, ur5 = load_robot("kr16"), load_robot("ur5")
    q = read_measurements(d / "m.csv", kr16).q
    write_design_csv(d / "d.csv", kr16, q[:5])
    write_design_csv(d / "d1001.csv", kr16, kr16.random_configurations(1001, 0))
    write_design_csv(d / "d_ur5.csv", ur5, read_measurements(d / "ur5.csv", ur5).q[:5])
    design = {"format": "calib_oed design v1", "scene": "fms_kr16", "robot": "kr16",
              "joint_names": list(kr16.joint_names), "configurations_rad": q[:5].tolist()}
    (d / "d.yaml").write_text(yaml.safe_dump(design))
    (d / "d300.yaml").write_text(yaml.safe_dump({**design, "robot": "kr300"}))
    (d / "d_dup.yaml").write_text(yaml.safe_dump(design) + "n: 5\nn: 6\n")
    (d / "d_bomb.yaml").write_text(yaml.safe_dump(design) + f"extra: {_BOMB}\n")
    lines = _lines(d / "m.csv")
    header = next(i for i, line in enumerate(lines) if line.startswith("joint_a1"))
    (d / "one.csv").write_text("\n".join(lines[:header + 2]) + "\n")
    (d / "two.csv").write_text("\n".join(lines[:header + 3]) + "\n")
    (d / "empty.csv").write_text("")
    (d / "binary.csv").write_bytes(b"\xff\xfe\x00garbage\x00" * 10)

    def row_with(values: str) -> str:
        return ",".join(lines[header + 1].split(",")[:7] + values.split(","))

    (d / "huge.csv").write_text("\n".join(lines[:header + 1] + [row_with("1e308,1e308,1e308")] + lines[header + 2:]) + "\n")
    (d / "far.csv").write_text("\n".join(lines[:header + 1] + [row_with("2e8,0,0")] + lines[header + 2:]) + "\n")
    sig = lines[:header] + [lines[header] + ",sigma"] + [r + ",0.01" for r in lines[header + 1:]]
    (d / "sig_big.csv").write_text("\n".join(sig[:header + 1] + [sig[header + 1][:-4] + "500"] + sig[header + 2:]) + "\n")
    (d / "sig_zero.csv").write_text("\n".join(sig[:header + 1] + [sig[header + 1][:-4] + "0"] + sig[header + 2:]) + "\n")
    (d / "m_nodirective.csv").write_text((d / "m.csv").read_text().replace("# robot: kr16\n", ""))
    (d / "m300.csv").write_text((d / "m.csv").read_text().replace("# robot: kr16", "# robot: kr300"))
    (d / "smrx.csv").write_text("\n".join(lines[:header + 1] + [lines[header + 1].replace(",smr0,", ",smrX,")]
                                          + lines[header + 2:]) + "\n")
    truth = yaml.safe_load((d / "m_truth.yaml").read_text())
    for name, data in (("t_robot.yaml", {**truth, "robot": "kr300"}),
                       ("t_missing.yaml", {**truth, "parameters": dict(list(truth["parameters"].items())[1:])}),
                       ("t_unknown.yaml", {**truth, "parameters": {**truth["parameters"], "joint9.tx": 0.0}}),
                       ("t_nan.yaml", {**truth, "parameters": {**truth["parameters"], "joint1.tx": float("nan")}})):
        (d / name).write_text(yaml.safe_dump(data))
    (d / "t_bomb.yaml").write_text(f"scene: fms_kr16\nparameters: {_BOMB}\n")
    _scene_variant(d, "dup.yaml", "name: fms_kr16", "name: fms_kr16\nname: other")
    _scene_variant(d, "dup_nested.yaml", "  rpy: [0, 10, 90]", "  rpy: [0, 10, 90]\n  rpy: [0, 0, 0]")
    _scene_variant(d, "bomb.yaml", "offset: [0, 0, 50]", f"offset: {_BOMB}")
    _scene_variant(d, "recursive.yaml", "offset: [0, 0, 50]", "offset: &r [0, 0, *r]")
    _scene_variant(d, "deep.yaml", "offset: [0, 0, 50]", "offset: " + "[" * 5000 + "]" * 5000)
    _scene_variant(d, "offset_10km.yaml", "offset: [0, 0, 50]", "offset: [0, 0, 10000000]")
    _scene_variant(d, "tracker_far_m.yaml", "position: [600, -2600, 1300]", "position: [600000000.0, -2600, 1300]")
    _scene_variant(d, "payload.yaml", "  tool_frame: tool0", "  tool_frame: tool0\n  compliance: {payload: {mass: 300000}}")
    (d / "latin1.yaml").write_bytes(SHIPPED.read_text().replace("Default scene", "Sc\u00e8ne").encode("latin-1"))
    (d / "big.yaml").write_text(SHIPPED.read_text() + "#" * (2 * 2**20) + "\n")
    (d / "study_dup.yaml").write_text("name: s\nname: t\n")
    os.mkfifo(d / "fifo")
    os.mkfifo(d / "fifo.png")
    os.mkfifo(d / "fifo.yaml")
    (d / "X_truth.yaml").mkdir()
    (d / "notafolder").write_text("x")
    return d


S = "fms_kr16"
SIM = ["simulate", S, "-o", "{t}/out.csv"]
SEQ = ["sequential", S, "--target-sigma", "0.02"]
SEQM = [*SEQ, "--measured", "{d}/m.csv"]

CASES = [
    # -- outputs: not a regular file, the same file twice, an output that is an input
    ("out-pipe", ["simulate", S, "-n", "5", "-o", "{d}/fifo"], "not a regular file"),
    ("truth-pipe", [*SIM, "-n", "5", "--truth", "{d}/fifo"], "not a regular file"),
    ("feasibility-pipe", ["feasibility", S, "-n", "5", "-o", "{d}/fifo"], "not a regular file"),
    ("compare-plot-pipe", ["compare", S, "{d}/d.csv", "--plot", "{d}/fifo.png"], "not a regular file"),
    ("identify-plot-pipe", ["identify", S, "{d}/m.csv", "--plot", "{d}/fifo.png"], "not a regular file"),
    ("view-html-pipe", ["view", S, "--html", "{d}/fifo"], "not a regular file"),
    ("design-out-pipe", ["design", S, "-o", "{d}/fifo"], "exists and is not a folder"),
    ("demo-out-file", ["demo", "-o", "{d}/notafolder"], "exists and is not a folder"),
    ("out-and-truth-same", ["simulate", S, "-n", "5", "-o", "{t}/X.csv", "--truth", "{t}/X.csv"], "same file"),
    ("out-and-truth-same-existing", ["simulate", S, "-n", "5", "-o", "{d}/m.csv", "--truth", "{d}/m.csv"], "same file"),
    ("out-and-truth-same-dotted", ["simulate", S, "-n", "5", "-o", "{t}/X.csv", "--truth", "{t}/./X.csv"], "same file"),
    ("default-truth-is-folder", ["simulate", S, "-n", "5", "-o", "{d}/X.csv"], "is a folder"),
    ("simulate-onto-design", ["simulate", S, "{d}/d.csv", "-o", "{d}/d.csv"], "is the input DESIGN"),
    ("simulate-truth-onto-design", ["simulate", S, "{d}/d.csv", "-o", "{t}/m.csv", "--truth", "{d}/d.csv"],
     "is the input DESIGN"),
    ("feasibility-onto-design", ["feasibility", S, "{d}/d.csv", "-o", "{d}/d.csv"], "is the input DESIGN"),
    ("simulate-onto-scene", ["simulate", "{d}/dup_nested.yaml", "-n", "5", "-o", "{d}/dup_nested.yaml"],
     "is the input SCENE"),
    ("view-onto-design", ["view", S, "{d}/d.csv", "--html", "{d}/d.csv"], "is the input DESIGN"),
    ("feasibility-onto-option-design", ["feasibility", S, "--design", "{d}/d.csv", "-o", "{d}/d.csv"],
     "is the input --design"),
    # -- options the command would drop
    ("simulate-n-and-design", ["simulate", S, "{d}/d.csv", "-n", "5", "-o", "{t}/x.csv"], "leave out -n"),
    ("feasibility-n-and-design", ["feasibility", S, "{d}/d.csv", "-n", "5"], "leave out -n"),
    ("montecarlo-n-and-design", ["montecarlo", S, "{d}/d.csv", "-n", "7"], "leave out -n"),
    ("demo-n-and-design", ["demo", "--design", "{d}/d.csv", "-n", "5", "-o", "{t}/demo"], "leave out -n"),
    ("simulate-seed-and-design", ["simulate", S, "{d}/d.csv", "--seed", "3", "-o", "{t}/x.csv"], "leave out --seed"),
    ("feasibility-seed-and-design", ["feasibility", S, "{d}/d.yaml", "--seed", "3"], "leave out --seed"),
    ("montecarlo-seed-and-design", ["montecarlo", S, "{d}/d.csv", "--seed", "1"], "leave out --seed"),
    ("design-twice", ["simulate", S, "{d}/d.csv", "--design", "{d}/d.csv", "-o", "{t}/x.csv"], "given twice"),
    ("design-twice-different", ["feasibility", S, "{d}/d.csv", "--design", "{d}/d.yaml"], "given twice"),
    ("montecarlo-design-twice", ["montecarlo", S, "{d}/d.csv", "--design", "{d}/d.yaml"], "given twice"),
    ("evaluate-pool-without-certificate", ["evaluate", S, "{d}/d.csv", "--pool", "20"], "only with --certificate"),
    ("evaluate-seed-without-certificate", ["evaluate", S, "{d}/d.csv", "--seed", "2"], "only with --certificate"),
    ("sequential-length-unit-without-measured", [*SEQ, "--length-unit", "mm"], "only with --measured"),
    ("sequential-angle-unit-without-measured", [*SEQ, "--angle-unit", "deg"], "only with --measured"),
    ("sequential-measured-initial", [*SEQM, "--initial", "5"], "belongs to the simulated run"),
    ("sequential-measured-truth-seed", [*SEQM, "--truth-seed", "2"], "belongs to the simulated run"),
    ("sequential-measured-no-compare", [*SEQM, "--no-compare"], "belongs to the simulated run"),
    ("sequential-measured-reference", [*SEQM, "--reference", "10"], "belongs to the simulated run"),
    ("sequential-measured-grid-step", [*SEQM, "--grid-step", "3"], "belongs to the simulated run"),
    ("sequential-measured-max", [*SEQM, "--max-measurements", "50"], "belongs to the simulated run"),
    ("sequential-measured-initial-design", [*SEQM, "--initial-design", "optimal"], "belongs to the simulated run"),
    ("demo-no-optimise-pool", ["demo", "--no-optimise", "--pool", "100", "-o", "{t}/demo"], "--no-optimise skips"),
    ("demo-no-optimise-iterations", ["demo", "--no-optimise", "--iterations", "3", "-o", "{t}/demo"],
     "--no-optimise skips"),
    ("study-no-report-no-figures", ["study", "smoke", "-o", "{t}/study", "--no-report", "--no-figures"],
     "--no-report skips"),
    ("view-html-and-for", ["view", S, "--html", "{t}/v.html", "--for", "3"], "leave out one of them"),
    ("view-json-without-html", ["view", S, "--json"], "add --html FILE"),
    ("design-aggregate-not-kpi", ["design", S, "--criterion", "D", "--aggregate", "max"], "'kpi' only"),
    # -- numbers outside their meaning
    ("time-limit-0", ["design", S, "-n", "5", "--time-limit", "0"], "--time-limit: expected a time"),
    ("time-limit-negative", ["design", S, "-n", "5", "--time-limit", "-5"], "--time-limit: expected a time"),
    ("time-limit-nan", ["design", S, "-n", "5", "--time-limit", "nan"], "--time-limit: expected a time"),
    ("payload-1e9", ["identifiability", S, "--payload-kg", "1e9"], "0 to 2500 kg"),
    ("payload-grams", ["simulate", S, "-n", "5", "-o", "{t}/x.csv", "--payload-kg", "300000"], "0 to 2500 kg"),
    ("payload-negative", ["design", S, "--payload-kg", "-1"], "0 to 2500 kg"),
    ("payload-nan", ["identify", S, "{d}/m.csv", "--payload-kg", "nan"], "0 to 2500 kg"),
    ("payload-inf", ["montecarlo", S, "--payload-kg", "inf"], "0 to 2500 kg"),
    ("montecarlo-one-run", ["montecarlo", S, "-n", "10", "-N", "1"], "at least 2 runs"),
    ("demo-one-run", ["demo", "-n", "10", "-N", "1", "--no-optimise", "-o", "{t}/demo"], "at least 2 runs"),
    ("view-level-above-1", ["view", S, "--level", "1.5", "--html", "{t}/v.html"], "strictly between 0 and 1"),
    ("view-level-0", ["view", S, "--level", "0", "--html", "{t}/v.html"], "strictly between 0 and 1"),
    ("view-scale-0", ["view", S, "--scale", "0", "--html", "{t}/v.html"], "--scale: expected a drawing scale"),
    ("view-scale-inf", ["view", S, "--scale", "inf", "--html", "{t}/v.html"], "--scale: expected a drawing scale"),
    ("view-for-nan", ["view", S, "--for", "nan"], "--for: expected a time"),
    ("view-for-negative", ["view", S, "--for", "-1"], "--for: expected a time"),
    ("validate-max-rms-0", ["validate", S, "{d}", "{d}/m.csv", "--max-rms", "0"], "--max-rms: expected an RMS"),
    ("validate-max-rms-negative", ["validate", S, "{d}", "{d}/m.csv", "--max-rms", "-1"], "--max-rms: expected"),
    ("validate-max-rms-nan", ["validate", S, "{d}", "{d}/m.csv", "--max-rms", "nan"], "--max-rms: expected"),
    ("identify-registration-rms-inf", ["identify", S, "{d}/m.csv", "--max-registration-rms", "inf"],
     "--max-registration-rms: expected"),
    ("joint-gains-beyond-the-joints", ["identifiability", S, "--joint-gains", "2,9"], "joint numbers 1..6"),
    ("joint-gains-not-numbers", ["design", S, "--joint-gains=a2"], "joint numbers 1..6"),
    ("joint-gains-twice", ["simulate", S, "-n", "5", "-o", "{t}/x.csv", "--joint-gains", "2,2"], "distinct"),
    ("scene-payload-grams", ["identifiability", "{d}/payload.yaml"], "no industrial robot carries more"),
    # -- files of another robot or scene
    ("truth-of-another-scene", ["identify", S, "{d}/m.csv", "--truth", "{d}/ur5_truth.yaml"], "the truth of scene 'ur5_table'"),
    ("truth-of-kr16-on-ur5", ["identify", "ur5_table", "{d}/ur5.csv", "--truth", "{d}/m_truth.yaml"],
     "the truth of scene 'fms_kr16'"),
    ("truth-of-another-robot", ["identify", S, "{d}/m.csv", "--truth", "{d}/t_robot.yaml"], "the truth of robot 'kr300'"),
    ("truth-missing-parameter", ["identify", S, "{d}/m.csv", "--truth", "{d}/t_missing.yaml"], "missing tracker.tx"),
    ("truth-unknown-parameter", ["identify", S, "{d}/m.csv", "--truth", "{d}/t_unknown.yaml"], "unknown joint9.tx"),
    ("truth-nan", ["identify", S, "{d}/m.csv", "--truth", "{d}/t_nan.yaml"], "NaN or infinite"),
    ("truth-without-compliance", ["identify", S, "{d}/m.csv", "--truth", "{d}/m_truth.yaml", "--compliance"],
     "missing joint1.c"),
    ("truth-file-missing", ["identify", S, "{d}/m.csv", "--truth", "{d}/nothing.yaml"], "not found"),
    ("truth-is-a-measurement-file", ["identify", S, "{d}/m.csv", "--truth", "{d}/m.csv"], "not a truth file"),
    ("truth-alias-bomb", ["identify", S, "{d}/m.csv", "--truth", "{d}/t_bomb.yaml"], "expand to more than"),
    ("measurements-of-another-robot", ["identify", S, "{d}/m300.csv"], "the file is of robot 'kr300'"),
    ("measurements-of-another-robot-validate", ["validate", S, "{d}", "{d}/m300.csv"], "of robot 'kr300'"),
    ("measurements-of-another-robot-sequential", [*SEQ, "--measured", "{d}/m300.csv"], "of robot 'kr300'"),
    ("measurements-other-robot-directive", ["identify", "ur5_table", "{d}/m.csv"], "of robot 'kr16'"),
    ("measurements-other-joints", ["identify", "ur5_table", "{d}/m_nodirective.csv"], "a file of another robot"),
    ("measurements-unknown-reflector", ["identify", S, "{d}/smrx.csv"], "unknown reflector 'smrX'"),
    ("design-other-joints", ["evaluate", S, "{d}/d_ur5.csv"], "a design of another robot"),
    ("design-yaml-of-another-robot", ["evaluate", S, "{d}/d300.yaml"], "a design of robot 'kr300'"),
    ("design-yaml-of-kr16-on-ur5", ["evaluate", "ur5_table", "{d}/d.yaml"], "a design of robot 'kr16'"),
    ("simulate-design-of-another-robot", ["simulate", "ur5_table", "{d}/d.csv", "-o", "{t}/x.csv"], "a design of another robot"),
    ("compare-one-foreign-design", ["compare", S, "{d}/d300.yaml", "{d}/d.csv"], "a design of robot 'kr300'"),
    # -- YAML beyond its bounds
    ("scene-duplicate-key", ["identifiability", "{d}/dup.yaml"], "duplicate key 'name'"),
    ("scene-duplicate-nested-key", ["identifiability", "{d}/dup_nested.yaml"], "duplicate key 'rpy'"),
    ("scene-alias-bomb", ["identifiability", "{d}/bomb.yaml"], "expand to more than"),
    ("scene-recursive-alias", ["identifiability", "{d}/recursive.yaml"], "recursive alias"),
    ("scene-nested-too-deep", ["identifiability", "{d}/deep.yaml"], "nest"),
    ("scene-too-large", ["identifiability", "{d}/big.yaml"], "MiB calib_oed reads"),
    ("scene-not-utf8", ["identifiability", "{d}/latin1.yaml"], "not UTF-8"),
    ("scene-pipe", ["identifiability", "{d}/fifo.yaml"], "{d}/fifo.yaml"),
    ("scene-10km-reflector-in-mm", ["identifiability", "{d}/offset_10km.yaml"], "no reflector sits 5 m"),
    ("scene-tracker-600000km", ["identifiability", "{d}/tracker_far_m.yaml"], "no laser tracker measures beyond"),
    ("design-yaml-duplicate-key", ["evaluate", S, "{d}/d_dup.yaml"], "duplicate key 'n'"),
    ("design-yaml-alias-bomb", ["evaluate", S, "{d}/d_bomb.yaml"], "expand to more than"),
    ("study-duplicate-key", ["study", "{d}/study_dup.yaml", "-o", "{t}/study"], "duplicate key 'name'"),
    # -- plain mistakes that were internal errors
    ("one-row", ["identify", S, "{d}/one.csv"], "at least 3 measured points"),
    ("two-rows", ["identify", S, "{d}/two.csv"], "at least 3 measured points"),
    ("one-row-validate", ["validate", S, "{d}", "{d}/one.csv"], "at least 3 measured points"),
    ("one-row-sequential", [*SEQ, "--measured", "{d}/one.csv"], "at least 3 measured points"),
    ("values-1e308", ["identify", S, "{d}/huge.csv"], "beyond any laser tracker's range"),
    ("values-200km", ["identify", S, "{d}/far.csv"], "beyond any laser tracker's range"),
    ("sigma-500mm", ["identify", S, "{d}/sig_big.csv"], "at most 10 mm"),
    ("sigma-0", ["identify", S, "{d}/sig_zero.csv"], "must be > 0"),
    ("measurements-pipe", ["identify", S, "{d}/fifo"], "not a regular file"),
    ("measurements-folder", ["identify", S, "{d}"], "is a folder"),
    ("measurements-missing", ["identify", S, "{d}/nothing.csv"], "not found"),
    ("measurements-empty", ["identify", S, "{d}/empty.csv"], "no column header"),
    ("measurements-binary", ["identify", S, "{d}/binary.csv"], "not UTF-8"),
    ("design-pipe", ["evaluate", S, "{d}/fifo"], "not a regular file"),
    ("design-empty", ["evaluate", S, "{d}/empty.csv"], "design file"),
    ("pool-pipe", ["design", S, "--pool", "{d}/fifo.yaml", "--no-certificate"], "not a regular file"),
    ("start-pipe", ["design", S, "--start", "{d}/fifo.yaml"], "not a regular file"),
    ("program-pipe", ["view", S, "--program", "{d}/fifo", "--html", "{t}/v.html"], "fifo"),
    ("view-1001-poses", ["view", S, "{d}/d1001.csv", "--html", "{t}/v.html"], "at most 1000 poses"),
    ("view-1001-poses-live", ["view", S, "{d}/d1001.csv", "--for", "1"], "at most 1000 poses"),
    ("validate-calibration-missing", ["validate", S, "{d}/nothing", "{d}/m.csv"], "does not exist"),
    # -- a second round (issue 34, item 3): 58 fresh inputs, these the ones unlike the above
    ("design-pool-0", ["design", S, "--pool", "0"], "a number of candidates >= 1"),
    ("design-pool-word", ["design", S, "--pool", "many"], "neither a number of candidates nor"),
    ("design-start-missing", ["design", S, "--start", "{d}/nothing.csv"], "not found"),
    ("design-start-is-measurements", ["design", S, "--start", "{d}/m.csv"], "unknown column(s) ['reflector'"),
    ("evaluate-truth-as-design", ["evaluate", S, "{d}/m_truth.yaml"], "not a calib_oed design YAML"),
    ("compare-plot-bad-suffix", ["compare", S, "{d}/d.csv", "--plot", "{t}/p.txt"], "valid suffixes"),
    ("view-level-nan", ["view", S, "--level", "nan", "--html", "{t}/v.html"], "strictly between 0 and 1"),
    ("view-scale-negative", ["view", S, "--scale", "-1", "--html", "{t}/v.html"], "drawing scale > 0"),
    ("simulate-out-folder-missing", ["simulate", S, "-n", "5", "-o", "{t}/no/x.csv"], "does not exist"),
    ("simulate-level-without-realistic", [*SIM, "-n", "5", "--level", "2"], "need --realistic"),
    ("simulate-thermal-without-realistic", [*SIM, "-n", "5", "--thermal"], "need --realistic"),
    ("simulate-realistic-level-nan", [*SIM, "-n", "5", "--realistic", "--level", "nan"], "finite and >= 0"),
    ("simulate-gross-more-than-poses", [*SIM, "-n", "5", "--realistic", "--gross-errors", "50"],
     "more than the 5 measurements"),
    ("identify-cv-1", ["identify", S, "{d}/m.csv", "--cv", "1"], "between 2 and the number of poses"),
    ("identify-cv-more-than-poses", ["identify", S, "{d}/m.csv", "--cv", "100"], "between 2 and"),
    ("identify-design-as-measurements", ["identify", S, "{d}/d.csv"], "missing column(s) x, y, z"),
    ("identify-adopt-onto-measurements", ["identify", S, "{d}/m.csv", "--adopt-registration", "{d}/m.csv"],
     "is the input MEASUREMENTS"),
    ("validate-max-error-negative", ["validate", S, "{d}", "{d}/m.csv", "--max-error", "-1"],
     "--max-error: expected"),
    ("validate-max-error-nan", ["validate", S, "{d}", "{d}/m.csv", "--max-error", "nan"], "--max-error: expected"),
    ("sequential-initial-beyond-max", [*SEQ, "--initial", "50", "--max-measurements", "20"], "must be >= initial"),
    ("study-missing", ["study", "{d}/nothing.yaml", "-o", "{t}/s"], "shipped studies are"),
    ("import-onto-input", ["import", S, "{d}/m.csv", "-o", "{d}/m.csv"], "is the input --export"),
    ("import-empty", ["import", S, "{d}/empty.csv", "-o", "{t}/x.csv"], "no data rows"),
    ("scene-is-a-design", ["identifiability", "{d}/d.yaml"], "keys of the top level are"),
    ("scene-unknown-name", ["identifiability", "no_such_scene"], "shipped scenes are"),
    ("joint-gains-zero", ["identifiability", S, "--joint-gains", "0"], "joint numbers 1..6"),
]


#: The heavy steps of the commands (module, name looked up at call time): a bad input is
#: refused before any of them starts.
HEAVY = (("scipy.optimize", "least_squares"), ("calib_oed.oed.refine", "solve_sqp"),
         ("calib_oed.oed.sensitivity_maxima", "solve_sqp"), ("calib_oed.calibration.montecarlo", "_run_chunk"),
         ("meshcat", "Visualizer"))


class HeavyWorkStarted(BaseException):
    """Raised by a heavy step in the bad-input table (a BaseException: no command catches it)."""


@pytest.fixture
def no_heavy_work(monkeypatch):
    """Every heavy step stopped."""
    for module, name in HEAVY:
        def stop(*args, _what=f"{module}.{name}", **kwargs):
            raise HeavyWorkStarted(f"{_what} started before the bad input was refused")

        monkeypatch.setattr(importlib.import_module(module), name, stop)


def _snapshot(*folders: Path) -> dict:
    return {p: (p.stat().st_mtime_ns, p.stat().st_size) for f in folders for p in f.rglob("*")
            if not p.is_fifo()}


@pytest.mark.parametrize("argv, fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(argv, fragment, files, tmp_path, capsys, monkeypatch,
                                                         no_heavy_work):
    monkeypatch.chdir(tmp_path)
    argv = [a.format(d=files, t=tmp_path) for a in argv]
    before = _snapshot(files, tmp_path)
    capsys.readouterr()
    code = main(argv)
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT, err
    assert err.startswith("calib-oed: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    assert fragment.format(d=files) in err, err
    assert _snapshot(files, tmp_path) == before, "a file was written or changed"


def test_the_table_covers_every_kind_with_100_cases():
    assert len(CASES) >= 100
    assert len({c[0] for c in CASES}) == len(CASES)


def test_the_work_bound_stops_a_good_input(files, tmp_path, monkeypatch, no_heavy_work):
    """The bound is live: a valid command reaches a heavy step and is stopped there."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(HeavyWorkStarted, match="least_squares started before"):
        main(["identify", S, str(files / "m.csv")])
