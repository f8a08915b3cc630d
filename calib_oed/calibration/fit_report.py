r"""The report of an identification on measured data: per measurement, reflector and pose, in mm.

Built from the measurement file (:class:`~calib_oed.measurement.dataset.MeasurementSet`,
for file lines, poses and reflector names), the sanity registration
(:mod:`calib_oed.calibration.sanity`) and the robust fit
(:mod:`calib_oed.calibration.robust`). Per measurement row :math:`i`:

- *before*: :math:`\lVert e_i\rVert` of the registration, the nominal robot with
  the tracker pose fitted alone [mm] (the robot's error, whatever the scene's
  tracker pose); *nominal*: the nominal model with the scene's tracker pose [mm];
- *after*: :math:`\lVert h(\hat p, q_i) - \eta_i\rVert` [mm], with its tracker-frame
  components;
- *normalised*: :math:`z_i = \lVert r_i\rVert/\hat s` (weighted residual over the
  estimated residual scale), the robust pass's weight and the final weight
  (0: an outlier, left out of the final estimate).

:func:`write_residuals_csv` writes one CSV row per measurement.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib_oed.calibration.crossval import MM_PER_M, pose_index
from calib_oed.calibration.robust import RobustIdentification
from calib_oed.calibration.sanity import SanityReport
from calib_oed.io.atomic import atomic_write_text
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.parameters import ParameterSpace, report_scale_of, report_unit_of

#: Posterior standard deviation above which a parameter is called implausibly determined
#: [m for lengths, rad for angles, 1 for gains]: 1 mm, 1 mrad, 1 %.
PLAUSIBLE_STD = {"m": 1e-3, "rad": 1e-3, "rad/rad": 1e-2, "m/m": 1e-2}


@dataclass(frozen=True, eq=False)
class FitReport:
    """Per-measurement residuals of one identification, in file-row order (arrays (n,), mm).

    Attributes:
        line: File line of each row. pose: Pose number (1-based, first appearance).
        reflector: Scene reflector name of each row.
        nominal_mm, before_mm, after_mm: See the module docstring.
        after_xyz_mm: (n, 3) after-residual components in the tracker frame [mm].
        normalised, robust_weight, weight: From the robust pass; outlier: flagged.
    """

    source: str
    line: np.ndarray = field(repr=False)
    pose: np.ndarray = field(repr=False)
    reflector: tuple[str, ...] = field(repr=False)
    nominal_mm: np.ndarray = field(repr=False)
    before_mm: np.ndarray = field(repr=False)
    after_mm: np.ndarray = field(repr=False)
    after_xyz_mm: np.ndarray = field(repr=False)
    normalised: np.ndarray = field(repr=False)
    robust_weight: np.ndarray = field(repr=False)
    weight: np.ndarray = field(repr=False)
    outlier: np.ndarray = field(repr=False)

    def groups(self, by: str) -> list[tuple[str, dict]]:
        """RMS and max of before and after [mm] per ``"reflector"`` or ``"pose"`` (outliers included)."""
        keys = self.reflector if by == "reflector" else tuple(str(p) for p in self.pose)
        out = []
        for key in dict.fromkeys(keys):
            m = np.array([k == key for k in keys])
            out.append((key, {"n": int(m.sum()),
                              "before_rms_mm": _rms(self.before_mm[m]),
                              "before_max_mm": float(self.before_mm[m].max()),
                              "after_rms_mm": _rms(self.after_mm[m]),
                              "after_max_mm": float(self.after_mm[m].max()),
                              "outliers": int(self.outlier[m].sum())}))
        return out

    def outlier_lines(self) -> list[str]:
        out = []
        for i in np.flatnonzero(self.outlier):
            out.append(f"  line {self.line[i]}: pose {self.pose[i]}, reflector {self.reflector[i]}: "
                       f"residual {self.after_mm[i]:.4f} mm, normalised {self.normalised[i]:.1f}, "
                       f"robust weight {self.robust_weight[i]:.3f}, final weight {self.weight[i]:g}")
        return out

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["line", "pose", "reflector", "nominal_mm", "before_mm", "after_mm", "after_x_mm",
                    "after_y_mm", "after_z_mm", "normalised", "robust_weight", "weight", "outlier"])
        for i in range(self.line.size):
            w.writerow([int(self.line[i]), int(self.pose[i]), self.reflector[i],
                        f"{self.nominal_mm[i]:.6f}", f"{self.before_mm[i]:.6f}",
                        f"{self.after_mm[i]:.6f}", *(f"{v:.6f}" for v in self.after_xyz_mm[i]),
                        f"{self.normalised[i]:.4f}", f"{self.robust_weight[i]:.4f}",
                        f"{self.weight[i]:g}", int(self.outlier[i])])
        return "# calib_oed identification residuals, one row per measurement; lengths in mm " \
               "(tracker frame); nominal: scene tracker pose; before: nominal robot, tracker pose " \
               "fitted alone; normalised: |r| / residual scale\n" + buf.getvalue()


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.asarray(a) ** 2)))


def _position_residuals(space, mset, blocks, p) -> np.ndarray:
    """:math:`h(p, q) - \\eta`, position part, per file row (n, 3) [m]."""
    out = np.empty((mset.n, 3))
    for j, block in zip(mset.reflectors, blocks, strict=True):
        state = evaluate_setup(space, p, block.q, regressor=False, jacobian=False)
        out[mset.reflector == j] = block.model.compute_values(state)[:, :3] - block.values[:, :3]
    return out


def per_row(mset: MeasurementSet, robust: RobustIdentification, values) -> np.ndarray:
    """``values`` per measurement of ``robust`` (block-then-row order) as per row of ``mset``."""
    rows = np.empty(robust.block.size, dtype=int)  # measurement k (block order) -> file row
    for k, j in enumerate(mset.reflectors):
        in_block = np.flatnonzero(robust.block == k)
        rows[in_block] = np.flatnonzero(mset.reflector == j)[robust.row[in_block]]
    out = np.empty(mset.n, dtype=np.asarray(values).dtype)
    out[rows] = values
    return out


def fit_report(space: ParameterSpace, mset: MeasurementSet, blocks, sanity: SanityReport,
               robust: RobustIdentification, reflector_names) -> FitReport:
    """The per-measurement table of an identification of ``mset`` (``blocks = mset.blocks(...)``)."""

    def by_row(values):
        return per_row(mset, robust, values)

    after = _position_residuals(space, mset, blocks, robust.result.p) * MM_PER_M
    nominal = _position_residuals(space, mset, blocks, None) * MM_PER_M
    names = tuple(reflector_names)
    return FitReport(
        source=mset.source, line=np.asarray(mset.lines), pose=pose_index(mset.q) + 1,
        reflector=tuple(names[j] if j < len(names) else f"reflector{j}" for j in mset.reflector),
        nominal_mm=np.linalg.norm(nominal, axis=1), before_mm=sanity.registration.errors_mm,
        after_mm=np.linalg.norm(after, axis=1), after_xyz_mm=after,
        normalised=by_row(robust.normalised), robust_weight=by_row(robust.robust_weight),
        weight=by_row(robust.weight), outlier=by_row(robust.flagged),
    )


def worst_determined(robust: RobustIdentification, top: int = 5) -> list[dict]:
    """The ``top`` free parameters with the largest a-posteriori std relative to :data:`PLAUSIBLE_STD`."""
    res = robust.result
    post = robust.parameter_std
    rows = []
    for name, unit, s in zip(res.free_names, res.units, post, strict=True):
        bound = PLAUSIBLE_STD.get(unit)
        scale = report_scale_of(unit)
        rows.append({"name": name, "std": float(s), "report_unit": report_unit_of(unit),
                     "std_report": float(s / scale), "implausible": bool(bound is not None and s > bound),
                     "ratio": float(s / bound) if bound else 0.0})
    rows.sort(key=lambda r: -r["ratio"])
    return rows[:top]


SIGMA0_MEANING = (
    "sigma0 = RMS weighted residual of the kept measurements: 1 = residuals as large as the stated "
    "noise (tracker sigma, or the scene's tracker error model with the robot's repeatability); "
    "clearly above 1: the model does not explain everything (model error such as gravity or gear "
    "play, or the noise understated); the residual scale judged outliers and the a-posteriori std "
    "use it")


def format_fit(report: FitReport, robust: RobustIdentification, sanity: SanityReport,
               top: int = 5) -> str:
    """The text report: sanity, before/after per reflector and pose, sigma0, conditioning, outliers."""
    res = robust.result
    lines = [sanity.summary(),
             f"residuals [mm], {report.line.size} measurements of {report.source}: before = nominal "
             "robot with the tracker fitted alone, after = calibrated",
             f"  all: before RMS {_rms(report.before_mm):.4f}, max {report.before_mm.max():.4f}; "
             f"after RMS {_rms(report.after_mm):.4f}, max {report.after_mm.max():.4f}; "
             f"nominal with the scene's tracker pose RMS {_rms(report.nominal_mm):.4f}"
             + (f"; after without the outliers RMS {_rms(report.after_mm[~report.outlier]):.4f}"
                if report.outlier.any() and not report.outlier.all() else "")]
    for by in ("reflector", "pose"):
        groups = report.groups(by)
        if by == "pose":  # the worst poses only
            groups = sorted(groups, key=lambda g: -g[1]["after_max_mm"])[:top]
            lines.append(f"  worst {len(groups)} of {len(report.groups('pose'))} poses (by after max):")
        for key, g in groups:
            lines.append(f"  {by} {key}: n {g['n']}, before RMS {g['before_rms_mm']:.4f} max "
                         f"{g['before_max_mm']:.4f}; after RMS {g['after_rms_mm']:.4f} max "
                         f"{g['after_max_mm']:.4f}" + (f"; {g['outliers']} outlier(s)" if g["outliers"] else ""))
    lines += [f"sigma0 = {robust.scale:.3f} ({robust.result.dof} degrees of freedom; robust median "
              f"scale {robust.robust_scale:.3f}): {SIGMA0_MEANING}",
              f"condition number of the weighted Jacobian (columns in mm, mrad): "
              f"{res.condition_number:.4g}",
              "worst-determined parameters (a-posteriori std"
              + (", under noise + model error):" if robust.std is not None else ", x sigma0):")]
    for w in worst_determined(robust, top):
        flag = "  WARNING: implausibly large, the data barely determine it" if w["implausible"] else ""
        lines.append(f"  {w['name']:<14s} std {w['std_report']:.4f} {w['report_unit']}{flag}")
    if robust.classes is not None:
        kept = int(np.sum(robust.flagged & (robust.weight > 0)))
        rule = (f"leave-one-out residual against noise + model error, normalised, above the "
                f"chi-square {1 - robust.alpha:g} quantile, about {robust.threshold.max():.2f}; "
                f"{robust.n_flagged - kept} left out of the fit, {kept} kept")
    elif np.isfinite(robust.alpha):
        rule = (f"normalised residual above the chi-square {1 - robust.alpha:g} quantile, about "
                f"{robust.threshold.max():.2f}; left out of the fit")
    else:
        rule = (f"plain fit: |r|/sqrt(d) above {res.outlier_threshold:g} stated sigma; kept "
                "in the fit")
    lines.append(f"outliers ({rule}): {robust.n_flagged or 'none'}")
    lines += report.outlier_lines()[:30]
    if robust.classes is not None:
        lines += [f"  {f}" for f in robust.classes.findings]
    return "\n".join(lines)


def fit_dict(report: FitReport, robust: RobustIdentification, sanity: SanityReport) -> dict:
    """The report's numbers as JSON-able data (mm unless a key says otherwise)."""
    return {
        "sanity": sanity.to_dict(), "sigma0": robust.scale, "robust_scale": robust.robust_scale,
        "sigma0_meaning": SIGMA0_MEANING,
        "alpha": robust.alpha if np.isfinite(robust.alpha) else None,
        "flag_rule": ("leave-one-out residual against noise + model error above the chi-square "
                      "1 - alpha quantile" if robust.classes is not None else
                      "normalised residual above the chi-square 1 - alpha quantile"),
        "findings": list(robust.classes.findings) if robust.classes is not None else [],
        "before_rms_mm": _rms(report.before_mm), "after_rms_mm": _rms(report.after_mm),
        "nominal_rms_mm": _rms(report.nominal_mm),
        "per_reflector": dict(report.groups("reflector")), "per_pose": dict(report.groups("pose")),
        "worst_determined": worst_determined(robust),
        "outliers": [{"line": int(report.line[i]), "pose": int(report.pose[i]),
                      "reflector": report.reflector[i], "after_mm": float(report.after_mm[i]),
                      "normalised": float(report.normalised[i]),
                      "robust_weight": float(report.robust_weight[i]),
                      "weight": float(report.weight[i])}
                     for i in np.flatnonzero(report.outlier)],
    }


def write_residuals_csv(path: str | os.PathLike, report: FitReport) -> Path:
    """``residuals.csv``: one row per measurement (atomic write)."""
    return atomic_write_text(path, report.to_csv())
