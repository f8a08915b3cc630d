r"""The design joint window: the joint ranges a design may use, one turn about home.

A revolute joint whose range exceeds one turn (a UR's :math:`\pm 360°`) reaches every
placement of its link twice. A design that uses the whole range may put a pose a
turn away from home, where no continuous motion from home leads (on ``ur5_table``:
``shoulder_lift`` at 264° is the arm pointing up like -96°, but between -60° at
home and 264° lies 90°, the upper arm in the table). The window limits each such
joint, for the design only, to one turn centred on home, intersected with its limits:

.. math::

    [\ell_i^w, u_i^w] = [\max(\ell_i,\ h_i - \pi),\ \min(u_i,\ h_i + \pi)]
    \quad\text{if } u_i - \ell_i > 2\pi,\qquad [\ell_i, u_i]\ \text{otherwise} \quad [\mathrm{rad}],

with :math:`h` the home the measurement program starts from by default (the scene's
``program.home``, else its first KPI working configuration; :func:`design_home`). One
turn of a revolute joint covers every angle, so no placement is lost unless the turn runs
past a limit (KUKA A1, ±185°: -185° to 171° about home at -7°).

The window acts through the robot limits of the feasibility model
(:func:`windowed_robot`: the same Pinocchio model with narrower ``lower``/``upper``),
so everything the design takes from there follows it: the sampler and candidate pool,
the SQP's bounds, the joint rows and the certificate. The scene's robot keeps its real
limits for identification and measured data. Scene key ``feasibility.joint_window``
(:data:`JOINT_WINDOWS`): ``one_turn`` (default) or ``full`` (the whole range).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import SceneError
from calib_oed.model.robot import Robot, joint_kind
from calib_oed.units import ANGLE_UNITS

#: Values of the scene key ``feasibility.joint_window``.
JOINT_WINDOWS = ("one_turn", "full")


@dataclass(frozen=True, eq=False)
class JointWindow:
    """The joint ranges a design may use.

    Attributes:
        mode: ``"one_turn"`` or ``"full"`` (:data:`JOINT_WINDOWS`).
        home: The window's centre [rad], (nq,).
        home_source: Where the centre came from (for reports).
        lower: Lower limits of the design [rad or m], (nq,), read-only.
        upper: Upper limits of the design [rad or m], (nq,), read-only.
        joints: Names of the joints whose range the window narrows.
        robot_lower: The robot's own lower limits [rad or m], (nq,).
        robot_upper: The robot's own upper limits [rad or m], (nq,).
        robot_names: The robot's joint names, base to tip.
    """

    mode: str
    home: np.ndarray
    home_source: str
    lower: np.ndarray
    upper: np.ndarray
    joints: tuple[str, ...]
    robot_lower: np.ndarray
    robot_upper: np.ndarray
    robot_names: tuple[str, ...]

    def summary(self) -> str:
        """One line: which joints are windowed and to what [deg]."""
        if self.mode == "full":
            return "design joint window: full (every joint over its whole range)"
        if not self.joints:
            return "design joint window: one_turn, no joint has more than one turn of range"
        names = list(self.robot_names)
        parts = [f"{j} {np.degrees(self.lower[names.index(j)]):.1f} to "
                 f"{np.degrees(self.upper[names.index(j)]):.1f} deg (range "
                 f"{np.degrees(self.robot_lower[names.index(j)]):.0f} to "
                 f"{np.degrees(self.robot_upper[names.index(j)]):.0f})" for j in self.joints]
        return ("design joint window: one_turn about home (" + self.home_source + "): "
                + ", ".join(parts))


def revolute_indices(robot: Robot) -> list[int]:
    """Configuration indices of the robot's revolute joints."""
    model = robot.model
    return [model.joints[j].idx_q for j in range(1, model.njoints)
            if joint_kind(model.joints[j]) == "revolute"]


def design_window(robot: Robot, home: np.ndarray | None, mode: str = "one_turn",
                  home_source: str = "given") -> JointWindow:
    """The design joint window of ``robot`` about ``home`` [rad] (module docstring).

    Args:
        robot: The robot (its limits are the real ones).
        home: The centre [rad], (nq,); ``None``: the middle of each joint's range.
        mode: ``"one_turn"`` or ``"full"``.
        home_source: Where ``home`` came from, for the summary.

    Raises:
        SceneError: an unknown ``mode`` (naming the valid ones), or a home of the wrong
            size, not finite or outside the joint limits.
    """
    if mode not in JOINT_WINDOWS:
        raise SceneError(f"expected one of {', '.join(JOINT_WINDOWS)}, got {mode!r}",
                         key="feasibility.joint_window")
    lo, hi = np.asarray(robot.lower, float), np.asarray(robot.upper, float)
    if home is None:
        home, home_source = (lo + hi) / 2, "the middle of each joint's range (no home in the scene)"
    home = np.asarray(home, dtype=float).reshape(-1)
    if home.shape != (robot.nq,) or not np.all(np.isfinite(home)):
        raise SceneError(f"the design joint window's centre ({home_source}) must be {robot.nq} finite "
                         f"joint values, got {home.tolist()}", key="feasibility.joint_window")
    if np.any(home < lo - 1e-9) or np.any(home > hi + 1e-9):
        bad = [robot.joint_names[i] for i in np.flatnonzero((home < lo - 1e-9) | (home > hi + 1e-9))]
        raise SceneError(f"the design joint window's centre ({home_source}) is outside the joint "
                         f"limits of {', '.join(bad)}", key="feasibility.joint_window")
    lower, upper, joints = lo.copy(), hi.copy(), []
    if mode == "one_turn":
        for i in revolute_indices(robot):
            if hi[i] - lo[i] > 2 * np.pi + 1e-9:
                lower[i], upper[i] = max(lo[i], home[i] - np.pi), min(hi[i], home[i] + np.pi)
                joints.append(robot.joint_names[i])
    for a in (lower, upper, home):
        a.setflags(write=False)
    return JointWindow(mode, home, home_source, lower, upper, tuple(joints), lo, hi,
                       tuple(robot.joint_names))


def windowed_robot(robot: Robot, window: JointWindow) -> Robot:
    """``robot`` with the window's limits (the same Pinocchio model; ``robot`` itself if
    the window narrows nothing)."""
    if not window.joints:
        return robot
    return dataclasses.replace(robot, lower=window.lower, upper=window.upper)


def design_home(scene) -> tuple[np.ndarray | None, str]:
    """The home a scene's measurement program starts from by default [rad], and where it
    came from: ``program.home`` (file units), else the first KPI working configuration;
    ``None`` if the scene has neither (as :func:`calib_oed.program.build.home_configuration`
    without ``--home``)."""
    block = getattr(scene, "program", None) or {}
    if isinstance(block, dict) and "home" in block:
        unit = ANGLE_UNITS.get(getattr(scene, "units", {}).get("angle", "rad"), 1.0)
        try:
            home = np.asarray(block["home"], dtype=float) * unit
        except (TypeError, ValueError) as exc:
            raise SceneError(f"expected {scene.robot.nq} joint values, got {block['home']!r}",
                             key="program.home") from exc
        return home, "program.home"
    kpi = getattr(scene, "kpi", None)
    configurations = getattr(kpi, "configurations", None) or ()
    if configurations:
        wc = configurations[0]
        return np.asarray(wc.q, dtype=float), f"the KPI working configuration {wc.name!r}"
    return None, "none"


def scene_window(scene) -> JointWindow:
    """The design joint window of a scene (``feasibility.joint_window``, default ``one_turn``)."""
    mode = getattr(scene.feasibility, "joint_window", "one_turn")
    home, source = design_home(scene) if mode == "one_turn" else (None, "")
    return design_window(scene.robot, home, mode, source)
