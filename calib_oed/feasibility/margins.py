"""The tightest constraint of each kind over a design, in report units (mm, deg).

Optimal designs sit on their constraints; the report says by how much each
kind clears its safety margin, which physical quantity that is (clearance
between surfaces, incidence angle, distance to a joint limit) and where.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.feasibility.constraints import FeasibilityModel


@dataclass(frozen=True)
class KindMargin:
    """The tightest constraint of one kind over a design, in report units.

    Attributes:
        kind: Constraint kind.
        slack: Value beyond the required safety margin (>= 0 feasible), in ``unit``.
        actual: The physical quantity at that constraint: clearance between
            surfaces [mm], incidence angle [deg], distance to the joint limit [deg or mm].
        required: What the constraint demands of ``actual`` (same unit; for
            incidence the largest allowed angle).
        unit: ``"mm"`` or ``"deg"``.
        label: The constraint row.
        pose: Index of the pose.
    """

    kind: str
    slack: float
    actual: float
    required: float
    unit: str
    label: str
    pose: int


def margin_report(model: FeasibilityModel, values: np.ndarray) -> list[KindMargin]:
    """Smallest margin per constraint kind of a design's constraint ``values`` (n, m)."""
    out = []
    st = model.settings
    for kind, rows in model.kind_slices().items():
        if rows.size == 0:
            continue
        sub = values[:, rows]
        pose, col = np.unravel_index(int(np.argmin(sub)), sub.shape)
        g = float(sub[pose, col])
        label = model.labels[rows[col]]
        if kind == "incidence":
            limit = st.incidence_limit - st.margins.incidence
            beta = np.degrees(np.arccos(np.clip(g + np.cos(limit), -1.0, 1.0)))
            out.append(KindMargin(kind, float(np.degrees(limit) - beta), float(beta),
                                  float(np.degrees(limit)), "deg", label, int(pose)))
        elif kind == "joint":
            prismatic = model.robot.prismatic[rows[col] // 2]  # two rows per joint, first in the model
            scale, unit = (1e3, "mm") if prismatic else (np.degrees(1.0), "deg")
            out.append(KindMargin(kind, g * scale, (g + st.margins.joint) * scale,
                                  st.margins.joint * scale, unit, label, int(pose)))
        else:
            out.append(KindMargin(kind, g * 1e3, (g + st.margins.clearance) * 1e3,
                                  st.margins.clearance * 1e3, "mm", label, int(pose)))
    return out


def format_margins(margins: list[KindMargin]) -> str:
    """A table of :func:`margin_report` for the terminal."""
    lines = [f"{'kind':10s} {'slack':>10s} {'actual':>10s} {'required':>10s}  tightest constraint (pose)"]
    for m in margins:
        req = f"<={m.required:.1f}" if m.kind == "incidence" else f">={m.required:.1f}"
        slack = m.slack + 0.0 if round(m.slack, 2) != 0 else 0.0  # an active constraint: no "-0.00"
        lines.append(f"{m.kind:10s} {slack:7.2f} {m.unit:3s}{m.actual:7.2f} {m.unit:3s}{req:>8s} {m.unit:3s}"
                     f" {m.label} ({m.pose})")
    return "\n".join(lines)
