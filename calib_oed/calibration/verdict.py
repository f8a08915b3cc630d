r"""The verdict of a validation: the user's tolerance, the prediction, the poses.

- **Verdict** (:func:`judge`): PASS when the calibrated RMS position error on
  the validation data is within ``--max-rms`` and its largest error within
  ``--max-error`` [mm] (either or both). The thresholds are the user's, never
  derived from the calibration itself, so the verdict is monotone in the
  achieved error: of two calibrations judged against the same tolerance, the
  less accurate one never passes while the more accurate one fails. Without a
  tolerance there is no verdict (exit 0).
- **Against the prediction**: the identification's predicted RMS at the validation
  measurements themselves (:mod:`calib_oed.calibration.pose_prediction`: parameter
  uncertainty + model error + noise at each row's pose), or, for an identification
  that did not record what this needs, its expected RMS on new poses
  (``predicted_accuracy`` of ``identification.json``, an average over other poses: a
  validation set in a smaller part of the workspace shows a lower error without the
  calibration being better than predicted); the achieved RMS over it is reported, and
  a ratio above :data:`WORSE_THAN_PREDICTED` is called out with its likely causes. This
  is a statement about the calibration's self-knowledge, not a pass or fail.
- **Per pose**: RMS and largest error of each validation pose, beside its predicted
  RMS and the rows inside their 95 % prediction regions
  (:mod:`calib_oed.calibration.pose_prediction`), and the joints
  of poses outside the training joint ranges (beyond :data:`RANGE_SLACK` of the
  range), where the calibration extrapolates.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib_oed.calibration.crossval import pose_index
from calib_oed.exceptions import InputFileError, ParameterError
from calib_oed.scene.yaml_file import read_text_file

#: Achieved over predicted RMS above which a validation is "worse than predicted".
WORSE_THAN_PREDICTED = 1.25
#: Where the prediction a validation is judged against is for: its own measurements (the
#: per-row prediction), or new poses (the identification's headline, older records only).
AT_MEASUREMENTS, ON_NEW_POSES = "at these validation measurements", "on new poses"
#: A validation joint value farther than this fraction of the training range outside it is warned about.
RANGE_SLACK = 0.02


def read_identification(files: dict) -> dict | None:
    """``identification.json`` beside the calibrated URDF, or None when there is none.

    Raises:
        InputFileError: the file is there but unreadable or not an identification record
            (a corrupt file is named, never taken for "none recorded").
    """
    path = Path(files["urdf"]).parent / "identification.json"
    if not path.exists():
        return None
    text = read_text_file(path, "identification")
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise InputFileError(path, f"the identification is unreadable, not JSON ({exc}); give the folder "
                             "`calib-oed identify -o DIR` wrote, or remove the file") from exc
    if not isinstance(data, dict):
        raise InputFileError(path, "the identification is unreadable, not a JSON object; give the folder "
                             "`calib-oed identify -o DIR` wrote, or remove the file")
    return data


def predicted_rms_mm(identification: dict | None, compensated: bool) -> float | None:
    """The identification's expected RMS on new poses [mm], or None when not recorded."""
    try:
        block = identification["predicted_accuracy"]["compensated" if compensated else "uncompensated"]
        value = float(block["new_pose_rms_mm"])
    except (TypeError, KeyError, ValueError):
        return None
    return value if np.isfinite(value) and value > 0 else None


def validation_prediction(predicted, identification: dict | None,
                          compensated: bool) -> tuple[float | None, str]:
    """The prediction a validation is judged against [mm] and where it is for: the per-row
    prediction at the validation measurements (``predicted``, a
    :class:`~calib_oed.calibration.pose_prediction.RowPrediction`), or, when the identification
    did not record what that needs (None), its headline on new poses."""
    if predicted is not None:
        return predicted.total_rms_mm, AT_MEASUREMENTS
    return predicted_rms_mm(identification, compensated), ON_NEW_POSES


@dataclass(frozen=True)
class Verdict:
    """Pass or fail against the user's tolerances, and the achieved error against the prediction.

    Attributes:
        passed: None without a tolerance; else whether every given tolerance holds.
        rms_mm, max_mm: Achieved calibrated errors [mm].
        max_rms_mm, max_error_mm: The tolerances [mm] (None: not given).
        predicted_rms_mm: The identification's predicted RMS [mm], or None.
        predicted_where: Where that prediction is for, in words.
    """

    passed: bool | None
    rms_mm: float
    max_mm: float
    max_rms_mm: float | None
    max_error_mm: float | None
    predicted_rms_mm: float | None
    predicted_where: str = AT_MEASUREMENTS

    @property
    def ratio(self) -> float | None:
        """Achieved over predicted RMS."""
        return None if self.predicted_rms_mm is None else self.rms_mm / self.predicted_rms_mm

    def lines(self) -> list[str]:
        out = []
        if self.predicted_rms_mm is None:
            out.append("prediction: none recorded beside the calibration (identification.json "
                       "of `calib-oed identify -o`), nothing to compare with")
        else:
            r = self.ratio
            what = ("as predicted or better" if r <= WORSE_THAN_PREDICTED else
                    "WORSE THAN PREDICTED: the cell changed since the identification (tracker or "
                    "robot moved, another tool), the validation poses reach where the training "
                    "data did not, or model error the identification data did not show")
            out.append(f"prediction: the identification expected {self.predicted_rms_mm:.4f} mm RMS "
                       f"{self.predicted_where} (parameter uncertainty + model error + noise); achieved "
                       f"{self.rms_mm:.4f} mm, ratio {r:.2f}: {what}")
        if self.passed is None:
            out.append("verdict: none (give --max-rms and/or --max-error, in mm, to judge against "
                       "your tolerance)")
            return out
        parts = []
        if self.max_rms_mm is not None:
            parts.append(f"RMS {self.rms_mm:.4f} mm {'<=' if self.rms_mm <= self.max_rms_mm else '>'} "
                         f"--max-rms {self.max_rms_mm:g} mm")
        if self.max_error_mm is not None:
            parts.append(f"largest error {self.max_mm:.4f} mm "
                         f"{'<=' if self.max_mm <= self.max_error_mm else '>'} --max-error "
                         f"{self.max_error_mm:g} mm")
        out.append(f"verdict: {'PASS' if self.passed else 'FAIL'}: " + "; ".join(parts))
        return out

    def to_dict(self) -> dict:
        return {"passed": self.passed, "rms_mm": self.rms_mm, "max_mm": self.max_mm,
                "max_rms_mm": self.max_rms_mm, "max_error_mm": self.max_error_mm,
                "predicted_rms_mm": self.predicted_rms_mm, "predicted_where": self.predicted_where,
                "achieved_over_predicted": self.ratio}


def _tolerance(value, option) -> float | None:
    if value is None:
        return None
    if not (np.isfinite(value) and value > 0):
        raise ParameterError(f"{option} must be a positive length in mm, got {value:g}")
    return float(value)


def judge(position_mm: np.ndarray, max_rms_mm: float | None = None, max_error_mm: float | None = None,
          predicted: float | None = None, predicted_where: str = AT_MEASUREMENTS) -> Verdict:
    """The :class:`Verdict` of calibrated errors ``position_mm`` (n,) [mm]; ``predicted`` the
    RMS the identification predicted [mm] ``predicted_where`` (:data:`AT_MEASUREMENTS` or
    :data:`ON_NEW_POSES`).

    Raises:
        ParameterError: a tolerance that is not a positive length.
    """
    tol_rms, tol_max = _tolerance(max_rms_mm, "--max-rms"), _tolerance(max_error_mm, "--max-error")
    rms, worst = float(np.sqrt(np.mean(position_mm**2))), float(np.max(position_mm))
    passed = None
    if tol_rms is not None or tol_max is not None:
        passed = (tol_rms is None or rms <= tol_rms) and (tol_max is None or worst <= tol_max)
    return Verdict(passed, rms, worst, tol_rms, tol_max, predicted, predicted_where)


def pose_table(q: np.ndarray, position_mm: np.ndarray, lines: np.ndarray, joint_names,
               ranges: dict | None, predicted_mm: np.ndarray | None = None,
               inside: np.ndarray | None = None) -> list[dict]:
    """Per validation pose: rows, file lines, RMS and max [mm], joints outside the training ranges;
    with the predicted error per row (``predicted_mm``, :math:`\\sqrt{\\mathrm{tr}\\,V_\\ast}` [mm],
    and ``inside`` its 95 % region, :mod:`calib_oed.calibration.pose_prediction`) the pose's
    predicted RMS [mm] and how many of its rows lie in their regions."""
    pose = pose_index(q)
    out = []
    for p in range(int(pose.max()) + 1):
        rows = np.flatnonzero(pose == p)
        qp = q[rows[0]]
        outside = []
        for j, name in enumerate(joint_names):
            if not ranges or name not in ranges:
                continue
            lo, hi = ranges[name]
            slack = RANGE_SLACK * (hi - lo)
            if qp[j] < lo - slack or qp[j] > hi + slack:
                outside.append({"joint": name, "value_deg": float(np.degrees(qp[j])),
                                "range_deg": [float(np.degrees(lo)), float(np.degrees(hi))]})
        e = position_mm[rows]
        row = {"pose": p + 1, "lines": [int(x) for x in lines[rows]], "n": int(rows.size),
               "rms_mm": float(np.sqrt(np.mean(e**2))), "max_mm": float(e.max()),
               "outside_training_ranges": outside}
        if predicted_mm is not None:
            row["predicted_rms_mm"] = float(np.sqrt(np.mean(predicted_mm[rows] ** 2)))
            row["inside_95"] = int(np.sum(inside[rows]))
        out.append(row)
    return out


def pose_lines(table: list[dict], top: int = 10) -> list[str]:
    """The worst ``top`` poses, and a warning for every pose outside the training ranges."""
    worst = sorted(table, key=lambda r: -r["max_mm"])[:top]
    out = [f"per pose (worst {len(worst)} of {len(table)} by largest error, mm"
           + ("; predicted: the RMS the identification expects there, and the rows inside their "
              "95 % prediction regions):" if table and "predicted_rms_mm" in table[0] else "):")]
    out += [f"  pose {r['pose']} (line {r['lines'][0]}): n {r['n']}, RMS {r['rms_mm']:.4f}, "
            f"max {r['max_mm']:.4f}"
            + (f", predicted RMS {r['predicted_rms_mm']:.4f} ({r['inside_95']} of {r['n']} inside)"
               if "predicted_rms_mm" in r else "")
            + (" (outside the training ranges)" if r["outside_training_ranges"] else "") for r in worst]
    for r in table:
        for o in r["outside_training_ranges"]:
            out.append(f"warning: validation pose {r['pose']} (line {r['lines'][0]}) has "
                       f"{o['joint']} = {o['value_deg']:.1f} deg, outside the training range "
                       f"{o['range_deg'][0]:.1f}..{o['range_deg'][1]:.1f} deg: the calibration "
                       "extrapolates there")
    return out
