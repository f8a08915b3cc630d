"""Records of a measurement program: its moves and the ordered program (SI: rad, s, m)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_oed.model.controller import ControllerConvention
from calib_oed.program.continuous import MoveCheck
from calib_oed.program.planner import PlannedPath
from calib_oed.program.settings import FrameSpec, Handshake, PayloadSpec


@dataclass(frozen=True, eq=False)
class Move:
    """One move of the program, between two nodes (0 = home, k = design pose k, 1-based).

    Attributes:
        start, end: Nodes.
        waypoints: Start, via points, end [rad], (k, nq).
        time: Travel time [s] (stopping at every via point).
        direct: The continuous check of the direct joint-space move.
        plan: The planner's path if the direct move was blocked, else ``None``.
    """

    start: int
    end: int
    waypoints: np.ndarray
    time: float
    direct: MoveCheck
    plan: PlannedPath | None = None

    @property
    def via_points(self) -> np.ndarray:
        """Via points [rad], (k - 2, nq)."""
        return self.waypoints[1:-1]

    def reversed(self) -> Move:
        """The same move the other way (moves are symmetric)."""
        return Move(self.end, self.start, self.waypoints[::-1].copy(), self.time, self.direct, self.plan)


@dataclass(frozen=True, eq=False)
class Program:
    """An ordered, collision-checked measurement program.

    Attributes:
        scene: Scene name.
        joint_names: The robot's joints.
        home: Home configuration [rad], (nq,).
        poses: The design's poses in design order [rad], (n, nq).
        order: Design indices (0-based) in the order they are measured, (n,).
        moves: The n + 1 moves home -> ... -> home, with their via points.
        dwell: Settle and measure time at every pose [s].
        cycle_times: Estimated cycle time [s] of ``"design order"``, ``"nearest neighbour"``
            and ``"optimised"``, moves through planned via points where blocked.
        solver: Which order the optimised tour is (``"lkh"``, or
            ``"nearest neighbour"`` when LKH's tour was not better).
        stats: Counts and times of the build (moves checked, blocked, planned, ...).
        settings_note: How home, velocities and accelerations were chosen.
        velocity: Joint velocity limits of the timing [rad/s], (nq,), or ``None``.
        acceleration: Joint acceleration limits of the timing [rad/s²], (nq,), or ``None``.
        controller: The scene's controller convention: the writers write controller
            values :math:`c = A^{-1}(q - b)` instead of URDF angles; ``None``: URDF angles.
        skipped: Poses left out (design index, 0-based; why): no certified path from home.
        handshake: What the writers put at each measurement pose instead of the dwell, or
            ``None`` (the dwell).
        tool, base, payload: What the program declares (``program.tool``, ``.base``,
            ``.payload``), or ``None``.
    """

    scene: str
    joint_names: tuple[str, ...]
    home: np.ndarray
    poses: np.ndarray
    order: np.ndarray
    moves: tuple[Move, ...]
    dwell: float
    cycle_times: dict[str, float]
    solver: str
    stats: dict = field(default_factory=dict)
    settings_note: str = ""
    velocity: np.ndarray | None = None
    acceleration: np.ndarray | None = None
    controller: ControllerConvention | None = None
    skipped: tuple[tuple[int, str], ...] = ()
    handshake: Handshake | None = None
    tool: FrameSpec | None = None
    base: FrameSpec | None = None
    payload: PayloadSpec | None = None

    @property
    def cycle_time(self) -> float:
        """Estimated cycle time of the program [s]: moves plus dwells."""
        return self.cycle_times["optimised"]

    def steps(self) -> list[tuple[str, np.ndarray, int | None]]:
        """What the controller does, in order: ``("home" | "via" | "pose", q, design index)``;
        the design index (0-based) is set for measurement poses only."""
        out: list[tuple[str, np.ndarray, int | None]] = [("home", self.home, None)]
        for move in self.moves:
            for via in move.via_points:
                out.append(("via", via, None))
            if move.end == 0:
                out.append(("home", self.home, None))
            else:
                out.append(("pose", self.poses[move.end - 1], move.end - 1))
        return out

    def summary(self) -> str:
        """A few lines for the command line (times in s, clearances in mm)."""
        st = self.stats
        t = self.cycle_times
        lines = [
            f"program for scene {self.scene!r}: {len(self.order)} of {len(self.poses)} poses, home and back, "
            f"dwell {self.dwell:.2f} s per pose",
            "estimated cycle time [s] (moves at the joint velocity/acceleration limits, via points "
            "stopped at, plus dwells):",
            f"  design order {t['design order']:.1f}, nearest neighbour {t['nearest neighbour']:.1f}, "
            f"optimised ({self.solver}) {t['optimised']:.1f}: "
            f"{100 * (1 - t['optimised'] / t['design order']):.0f} % shorter than the design order",
            f"moves looked at: {st['moves_checked']} (a first batch of samples, then the "
            f"continuous check for those a tour used), direct moves blocked: {st['blocked']} "
            f"({100 * st['blocked'] / max(st['moves_checked'], 1):.0f} %), planned: "
            f"{st['planned']} ({st['planner_failures']} without a plan), planner CPU "
            f"{st['planner_cpu_s']:.2f} s",
            f"the program's {len(self.moves)} moves: {st['program_blocked']} through via points "
            f"({st['via_points']} via points), every move certified collision-free "
            f"(clearance margin less at most {st['move_tolerance_mm']:.1f} mm)",
            (f"design order: {st['design_order_blocked']} of its {len(self.moves)} direct moves "
             "blocked, planned" if st["design_order_planned"] else
             f"design order: at least {st['design_order_blocked']} of its {len(self.moves)} direct "
             "moves blocked (colliding at their first samples), priced at their direct time: a "
             "lower bound, the gain above is understated"),
            f"line of sight lost during {st['sight_lost_moves']} moves (reported: the tracker "
            "re-locks before the pose is measured)",
            f"built in {st['cpu_s']:.2f} s CPU",
        ]
        if st.get("wrapped_poses"):
            lines.append(f"poses measured at joint values whole turns from the design's (--wrap): "
                         f"{st['wrapped_poses']}")
        for k, why in self.skipped:
            lines.append(f"NOT MEASURED: pose {k + 1}: {why}")
        if self.settings_note:
            lines.append(self.settings_note)
        return "\n".join(lines)
