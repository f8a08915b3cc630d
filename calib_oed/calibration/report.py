"""Human-readable and JSON reports. Reports speak mm, mrad and mm², and say so."""

from __future__ import annotations

import textwrap

import numpy as np

from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.measurement import PoseMeasurement
from calib_oed.model.identifiability import Estimability, IdentifiabilityReport
from calib_oed.model.parameters import Group


def reflectors_on_last_axis(problem: CalibrationProblem, tol: float = 1e-9) -> list[int]:
    """Reflectors whose nominal centre lies on the last joint's axis (revolute only).

    Such a reflector traces no circle about that axis: the axis' two tilts
    about the reflector are unobservable and the rank drops by 2.
    """
    model = problem.robot.model
    joint = model.joints[model.njoints - 1]
    kind = joint.shortname()
    axes = {"JointModelRX": (1.0, 0, 0), "JointModelRY": (0, 1.0, 0), "JointModelRZ": (0, 0, 1.0)}
    if kind in axes:
        axis = np.array(axes[kind])
    elif kind == "JointModelRevoluteUnaligned":
        axis = np.asarray(joint.extract().axis, dtype=float)
    else:
        return []
    frame = model.frames[problem.robot.tool_frame_id]
    out = []
    for j, c in enumerate(problem.space.reflector_offsets0):
        x = frame.placement.act(c)  # in the last joint's frame
        if np.linalg.norm(x - (x @ axis) * axis) < tol:
            out.append(j)
    return out


def classical_count(problem: CalibrationProblem) -> tuple[int, str] | None:
    """The classical count of identifiable parameters, where it applies.

    Everett and Hollerbach's rule for a complete, minimal model of a serial
    arm with R revolute and P prismatic joints is N = 4R + 2P + 6 with full
    pose measurements and unknown base and tool; with position measurements
    of one point the tool orientation is unobservable: N = 4R + 2P + 3. Our
    parameters add the tracker pose (6) and the reflector offset (3), which
    play the roles of the base and tool parameters, so the rules compare
    with our rank directly. Returns None for set-ups the rule does not cover
    (several reflectors, joint compliance or joint gains modelled).
    """
    n_p = int(problem.robot.prismatic.sum())
    n_r = problem.robot.nq - n_p
    space = problem.space
    if len(problem.models) != 1 or space.compliance is not None or space.joint_gains is not None:
        return None
    if isinstance(problem.models[0], PoseMeasurement):
        return 4 * n_r + 2 * n_p + 6, f"4R + 2P + 6 = 4*{n_r} + 2*{n_p} + 6 (pose measurements)"
    return 4 * n_r + 2 * n_p + 3, f"4R + 2P + 6 - 3 = 4*{n_r} + 2*{n_p} + 3 (one measured point)"


def identifiability_dict(
    problem: CalibrationProblem, report: IdentifiabilityReport, estimability: list[Estimability]
) -> dict:
    """The identifiability report as JSON-serialisable data."""
    out = report.to_dict()
    classical = classical_count(problem)
    out["robot"] = problem.robot.name
    out["tool_frame"] = problem.robot.tool_frame
    out["measurement_models"] = [m.name for m in problem.models]
    comp = problem.space.compliance
    out["compliance"] = None if comp is None else {
        "payload_kg": comp.payload_mass, "payload_com_m": comp.payload_com.tolist(),
        "parameters": list(problem.space.names[problem.space.compliance_slice]),
    }
    if problem.space.joint_gains is not None:  # the key only when gains are identified
        out["joint_gains"] = list(problem.space.names[problem.space.gain_slice])
    out["classical_count"] = None if classical is None else {
        "count": classical[0], "rule": classical[1]
    }
    out["kpi"] = {
        "frame": problem.kpi.frame,
        "point_m": problem.kpi.point.tolist(),
        "estimability": [e.to_dict() for e in estimability],
    }
    return out


def format_identifiability(
    problem: CalibrationProblem,
    report: IdentifiabilityReport,
    estimability: list[Estimability],
    title: str = "",
) -> str:
    """The identifiability report as text."""
    space = problem.space
    lines = [f"Identifiability{': ' + title if title else ''}"]
    lines.append(
        f"  robot {problem.robot.name} ({problem.robot.nq} joints), tool frame "
        f"{problem.robot.tool_frame!r}, measurements: "
        + ", ".join(m.name for m in problem.models)
    )
    lines.append(
        f"  generic design: {report.n_configurations} random configurations in the joint "
        f"limits (seed {report.seed}), {report.n_rows} rows"
    )
    if space.compliance is not None:
        lines.append(f"  {space.compliance.describe()}")
    if space.joint_gains is not None:
        lines.append(f"  joint gains and coupling ratios identified: "
                     f"{', '.join(space.names[space.gain_slice])}")
    lines.append(
        f"  parameters: {len(report.names)}; free (identifiable): {report.rank}; "
        f"fixed: {len(report.fixed)}; rank tolerance {report.tol:g}"
    )
    lines.append(
        "  condition number of the weighted Jacobian on the free parameters "
        f"(columns in mm, mrad): {report.condition_number:.4g}"
    )
    classical = classical_count(problem)
    if classical is not None:
        count, rule = classical
        verdict = "agrees" if count == report.rank else f"differs by {report.rank - count:+d}"
        lines.append(f"  classical rule {rule} = {count}: {verdict} (see docs/conventions.md)")
        if isinstance(problem.models[0], PoseMeasurement):
            lines.append("    the probe's two tilts on the tool are not parameters here: -2")
        elif reflectors_on_last_axis(problem):
            lines.append("    the reflector lies on the last joint's axis, so the axis' two tilts "
                         "about it are unobservable: -2")
    lines.append("")
    lines.append(f"Free parameters ({report.rank}):")
    lines += textwrap.wrap(
        ", ".join(report.free_names), width=96, initial_indent="  ", subsequent_indent="  "
    )
    lines.append("")
    lines.append(f"Fixed parameters ({len(report.fixed)}), held at their nominal value:")
    width = max((len(f.name) for f in report.fixed), default=0)
    for f in report.fixed:
        par = space.parameters[space.index(f.name)]
        why = f.reason
        if par.group == Group.COMPLIANCE and not f.redundant_with:
            why += " (no gravity torque about this joint in any pose, with this payload)"
        lines.append(f"  {f.name:<{width}} [{par.report_unit:>4}]  {why}  (residual {f.residual:.1e})")
    lines.append("")
    where = "tracker frame" if problem.kpi.frame == "tracker" else "world frame"
    if problem.kpi.reflector is not None:
        what = f"centre of reflector{problem.kpi.reflector}"
    else:
        what = f"tool point {np.round(problem.kpi.point * 1e3, 3).tolist()} mm in the tool frame"
    lines.append(f"KPI: {what}, in the {where}:")
    # a gauge parameter with no effect on the measurements is unknown, not a convention
    unseen = {f.name for f in report.fixed if not f.redundant_with}
    for e in estimability:
        if e.estimable:
            lines.append(f"  {e.label}: estimable (residual {e.residual:.1e})")
        elif unseen.isdisjoint(e.gauge):
            lines.append(
                f"  {e.label}: estimated relative to the robot base frame the calibration defines "
                "(the gauge: " + ", ".join(e.gauge) + " held at nominal); its sigma is the "
                "uncertainty in that frame"
            )
        else:
            lines.append(
                f"  {e.label}: NOT estimable (residual {e.residual:.2g}): it depends on "
                + ", ".join(n for n in e.gauge if n in unseen) + ", which no measurement sees"
            )
    if not all(e.estimable for e in estimability):
        lines += textwrap.wrap(
            "Why a gauge: the tracker's pose is unknown, so the data place the robot relative to "
            "the tracker, not in its own base. The calibration defines the base frame, and the tool "
            "beyond the reflector, by holding the gauge parameters at their nominal values, as in "
            "the paper; the calibrated URDF uses that frame, and KPI sigmas are relative to it. A "
            "reflector centre in the tracker frame (scene keys kpi.reflector, kpi.frame: tracker) "
            "needs no gauge.",
            width=96,
            initial_indent="  ",
            subsequent_indent="  ",
        )
    return "\n".join(lines)


def format_kpi_sigma(problem: CalibrationProblem, sigma: np.ndarray, design: str) -> str:
    """KPI standard deviations per working configuration [mm]."""
    lines = [f"KPI standard deviation sqrt(tr(C_s)/3) for {design}:"]
    for name, s in zip(problem.kpi.names, sigma, strict=True):
        lines.append(f"  {name}: {s * 1e3:.4f} mm  (average variance {(s * 1e3) ** 2:.3e} mm^2)")
    lines.append(KPI_SIGMA_COVERS)
    return "\n".join(lines)


#: What the design-time KPI sigma covers, in words an engineer reads once.
KPI_SIGMA_COVERS = (
    "  this sigma covers the measurement noise only (tracker and robot repeatability), the model "
    "taken as exact;\n  on a real arm the error the model does not describe adds to it (gravity, "
    "gear errors: often 0.1-0.5 mm after a geometric calibration):\n  `calib-oed identify` predicts "
    "the accuracy with it from the measured data, in the robot's base frame (where the controller "
    "works) and in the tracker frame")
