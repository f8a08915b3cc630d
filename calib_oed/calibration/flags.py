r"""Outliers judged against noise + model error, and flags that look like model error.

**The rule** (:func:`judge_measurements`; one rule for the report, the JSON and
the residual plot). Measurement :math:`i` (its :math:`d_i` values) is flagged when
its leave-one-out statistic against noise and model error
(:func:`calib_oed.calibration.model_error.leave_one_out`),
:math:`t_i \sim \chi^2_{d_i}` under the model, exceeds
:math:`\chi^2_{d_i}(1-\alpha)` (:math:`\alpha` = 1e-3: a measurement the model
explains is flagged with probability 1e-3). Flags are found by sequential
deletion: the worst measurement beyond its quantile is set aside and the
statistics recomputed without it, so one gross error does not drag the
measurements next to it (another reflector at the same pose shares its model
error) over the line; each measurement set aside is then judged against all
the measurements kept, and flagged only if it is still beyond.

**Model error, not outliers** (:func:`classify_flags`). Flags that look like
what the model misses are reported as likely model error and kept in the fit
(unless the user drops them):

- every reflector of a pose flagged (a pose with two or more): the arm is off
  there as a whole, not one reading;
- flags clustered at one end of one joint's measured range (two or more
  flagged poses, at least half of them, in the outer :data:`END_FRACTION` of the
  joint's range at the same end): an effect of that joint the model lacks
  (compliance, a gain, a transmission error), or too few poses there.

Neither rule counts a flag beyond :data:`GROSS_Z` (below): no model error the fit
describes is that far out, even at a joint's end (on the realistic UR5 a 5 mm
error at one end of A1, 39 standard deviations out, was otherwise called model
error with a suspect beside it, and kept). Of the others, a flag whose
leave-one-out residual is beyond :data:`GROSS_Z`
standard deviations of noise + model error (:math:`\sqrt{t_i} \ge 10`; under the model
:math:`P(\chi^2_{d_i} \ge 100)` = 1.6e-21 for a position, :math:`d_i = 3`, and 2.5e-19
for a pose, :math:`d_i = 6`) is a gross error (a misread reflector, a bumped
nest) and is left out; the rest are reported as suspect and kept: a real arm's
model error has heavier tails than a Gaussian process (on the realistic
simulator's UR5, flags at :math:`\sqrt{t_i}` 5-6.5 with no gross error at all),
and leaving such rows out makes the fit extrapolate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from calib_oed.calibration.model_error import Linearisation, leave_one_out
from calib_oed.measurement.discrepancy import DiscrepancyPrior

#: Default false-flag probability of a measurement the model explains.
DEFAULT_ALPHA = 1e-3
#: A flag is at a joint's end when within this fraction of the measured range of it.
END_FRACTION = 0.1
#: A flag this many standard deviations of noise + model error out (sqrt(t)) is a gross error.
GROSS_Z = 10.0
#: At most this fraction of the measurements is set aside by the sequential deletion.
MAX_FLAGGED_FRACTION = 0.25


def judge_measurements(lin: Linearisation, prior: DiscrepancyPrior | None,
                       alpha: float = DEFAULT_ALPHA) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flags by sequential deletion (module docstring).

    Returns:
        ``(flagged, t, dim)`` per measurement (M,): the flags, :math:`t_i` (each flagged one
        judged against the kept ones) and :math:`d_i`.
    """
    n = int(lin.measurement.max()) + 1
    t, dim = leave_one_out(lin, prior)
    limit = chi2.ppf(1 - alpha, dim)
    kept = np.ones(n, bool)
    stat = t.copy()
    while (~kept).sum() < MAX_FLAGGED_FRACTION * n:
        ratio = np.where(kept, stat / limit, -np.inf)
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1:
            break
        kept[worst] = False
        stat[kept], _ = leave_one_out(lin.subset(kept), prior)
    for i in np.flatnonzero(~kept):  # each one against all the kept measurements
        with_i = kept.copy()
        with_i[i] = True
        t_sub, _ = leave_one_out(lin.subset(with_i), prior)
        stat[i] = t_sub[int(np.sum(with_i[:i]))]
    return ~kept & (stat > limit), stat, dim


@dataclass(frozen=True, eq=False)
class FlagClasses:
    """Which flags look like model error, and why (module docstring).

    Attributes:
        model_error: Per measurement (M,): flagged and classified as likely model error.
        findings: One sentence per finding, naming the poses or the joint and the remedy.
        gross: Per measurement (M,): flagged, not model error, beyond :data:`GROSS_Z`.
    """

    model_error: np.ndarray = field(repr=False)
    findings: tuple[str, ...]
    gross: np.ndarray | None = field(default=None, repr=False)


def classify_flags(flagged: np.ndarray, pose: np.ndarray, q: np.ndarray,
                   joint_names, t: np.ndarray | None = None) -> FlagClasses:
    """Classify the flags of measurements with pose numbers ``pose`` (M,) at ``q`` (M, nq)
    and leave-one-out statistics ``t`` (M,) (None: every flag that is not model error is gross)."""
    flagged = np.asarray(flagged, bool)
    model_error = np.zeros(flagged.size, bool)
    findings = []
    beyond = np.ones(flagged.size, bool) if t is None else np.sqrt(t) >= GROSS_Z
    # a flag beyond GROSS_Z is no model error (1e-20 under the model), whatever its neighbours
    candidate = flagged if t is None else flagged & ~beyond
    whole = [p for p in np.unique(pose[candidate])
             if np.sum(pose == p) >= 2 and candidate[pose == p].all()]
    for p in whole:
        model_error[pose == p] = True
    if whole:
        findings.append(f"pose(s) {', '.join(str(int(p) + 1) for p in whole)}: every reflector "
                        "flagged, the arm is off there as a whole: likely model error, not a "
                        "misread reflector; kept in the fit")
    span_lo, span_hi = q.min(axis=0), q.max(axis=0)
    span = np.where(span_hi > span_lo, span_hi - span_lo, np.inf)
    flagged_poses = np.unique(pose[candidate])
    first = {p: int(np.flatnonzero(pose == p)[0]) for p in flagged_poses}
    for j, name in enumerate(joint_names):
        if not np.isfinite(span[j]):
            continue
        for end, word in ((span_lo[j], "lower"), (span_hi[j], "upper")):
            near = [p for p in flagged_poses
                    if abs(q[first[p], j] - end) <= END_FRACTION * span[j]]
            if len(near) >= 2 and len(near) >= 0.5 * flagged_poses.size:
                for p in near:
                    model_error[(pose == p) & candidate] = True
                findings.append(
                    f"{len(near)} of the {flagged_poses.size} flagged poses sit at the {word} end "
                    f"of {name}'s measured range (near {np.degrees(end):.0f} deg): likely model "
                    f"error of {name}, not outliers; kept in the fit. Remedy: model a "
                    "non-geometric parameter of that joint (robot.compliance, robot.joint_gains) "
                    f"or measure more poses near that end of {name}")
    model_error &= candidate
    gross = flagged & ~model_error & beyond
    suspect = flagged & ~model_error & ~gross
    if suspect.any():
        findings.append(f"{int(suspect.sum())} flagged measurement(s) within {GROSS_Z:g} standard "
                        "deviations of noise + model error: suspect, kept in the fit (re-measure "
                        "them if in doubt)")
    return FlagClasses(model_error, tuple(findings), gross)
