"""What every program writer shares: the header text, the step list, angle formatting.

Joint values are the controller's when the scene has a ``controller:`` block
(joint signs, zero offsets, scales, couplings such as FANUC's J2/J3:
:math:`c = A^{-1}(q - b)`, :mod:`calib_oed.model.controller`), else the URDF's
joint angles; every file's header says which. Angles are written in degrees
with 4 decimals (1e-4 deg = 1.7 µrad), URScript's in radians with 6 decimals
(URScript's unit). Pose numbers count from 1: "pose 12" is row 12 of the design.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.program.records import Program
from calib_oed.program.timing import JointDynamics

#: Decimals of the angles written in degrees, and in radians (URScript, CSV).
DEG_DECIMALS = 4
RAD_DECIMALS = 6


@dataclass(frozen=True)
class Step:
    """One target of the program.

    Attributes:
        kind: ``"home"``, ``"via"`` or ``"pose"``.
        q: Joint values to write [rad], (nq,): controller values if the program has a
            controller convention, else URDF angles.
        pose: Pose number (1-based row of the design) for measurement poses, else ``None``.
        name: A target name unique in the program (``HOME``, ``P12``, ``V3``).
        time: The estimated time [s] of the move into this target from the one before, at
            the joint limits of the program's timing (the time of its slowest joint, as the
            cycle time estimate counts it); ``None`` for the first target or without limits.
    """

    kind: str
    q: np.ndarray
    pose: int | None
    name: str
    time: float | None = None


def steps(program: Program) -> list[Step]:
    """The program's targets in order, named (home at both ends, via points numbered)."""
    out, vias, before = [], 0, None
    limits = program.velocity is not None and program.acceleration is not None
    if limits:
        dyn = JointDynamics(np.asarray(program.velocity, float), np.asarray(program.acceleration, float))
    for kind, q, index in program.steps():
        if kind == "via":
            vias += 1
            name = f"V{vias}"
        elif kind == "pose":
            name = f"P{index + 1}"
        else:
            name = "HOME"
        q = np.asarray(q, dtype=float)
        time = float(dyn.move_time(before, q)) if limits and before is not None else None
        before = q
        if program.controller is not None:
            q = program.controller.to_controller(q)
        out.append(Step(kind, q, None if index is None else index + 1, name, time))
    return out


def _at_pose(program: Program) -> str:
    """The header line saying what happens at each measurement pose."""
    hs = program.handshake
    if hs is None:
        return f"at each measurement pose: dwell {program.dwell:.2f} s (settle, tracker measures)"
    if hs.routine is not None:
        return f"at each measurement pose: call {hs.routine} (the tracker's handshake, no dwell)"
    return (f"at each measurement pose: set digital output {hs.output}, wait for digital input "
            f"{hs.input}, reset the output (the tracker's handshake, no dwell)")


@dataclass(frozen=True)
class MeasureWords:
    """How one controller language writes what happens at a measurement pose (docs/program.md).

    Each attribute is a template (:meth:`str.format`) of the lines for one case: ``dwell``
    the blind dwell (keys ``dwell`` [s], ``pose``), ``routine`` the call of the handshake
    routine (keys ``routine``, ``ROUTINE`` its name upper-cased, ``pose``), ``signals`` the
    signal handshake, one template a line (keys ``output``, ``input``: the signal numbers;
    ``output_name``, ``input_name``: their names, :attr:`~calib_oed.program.settings.Handshake.signal_names`; ``pose``).
    ``pose`` is the pose number (from 1).
    """

    dwell: str
    routine: str
    signals: tuple[str, ...]

    def compute_lines(self, program: Program, pose: int) -> list[str]:
        """The lines at measurement pose ``pose``: the dwell, or the program's handshake."""
        hs = program.handshake
        if hs is None:
            return [self.dwell.format(dwell=program.dwell, pose=pose)]
        if hs.routine is not None:
            return [self.routine.format(routine=hs.routine, ROUTINE=hs.routine.upper(), pose=pose)]
        output_name, input_name = hs.signal_names
        return [line.format(output=hs.output, input=hs.input, output_name=output_name,
                            input_name=input_name, pose=pose) for line in self.signals]


def require_six_axes(program: Program, fmt: str) -> None:
    """Controller languages here take 6 robot axes; other robots get the CSV."""
    if len(program.joint_names) != 6:
        raise ProgramError("format", fmt, f"writes 6-axis robots only; this robot has "
                           f"{len(program.joint_names)} joints: use the csv format", ["csv"])


def degrees(q: np.ndarray) -> list[str]:
    """Joint values [rad] as degree strings with :data:`DEG_DECIMALS` decimals."""
    return [f"{v:.{DEG_DECIMALS}f}" for v in np.rad2deg(np.asarray(q, dtype=float))]


#: How a program's header names its joint values (:func:`header_lines`; read back by
#: :func:`calib_oed.program.csv_format.read_program_csv` and :func:`calib_oed.program.compensate.check_written_for`).
URDF_VALUES = "URDF joint angles"
CONTROLLER_VALUES = "controller joint values"


def header_lines(program: Program, units: str) -> list[str]:
    """The header every file carries (without comment markers)."""
    t = program.cycle_times
    joints = ", ".join(program.joint_names)
    ctrl = program.controller
    convention = ([f"joint values: {CONTROLLER_VALUES} in {units}, in the order {joints}",
                   f"from the URDF angles q by the scene's {ctrl.describe()}"] if ctrl else
                  [f"joint values: {URDF_VALUES} in {units}, in the order {joints}",
                   "no controller block in the scene: no controller signs, zero offsets or axis",
                   "couplings are applied; check them against the controller before running"])
    return [
        f"calib_oed measurement program, scene {program.scene}: {len(program.poses)} poses",
        *convention,
        _at_pose(program),
        "pose N = row N of the design file (from 1); via points are not measured",
        f"estimated cycle time {t['optimised']:.1f} s (design order {t['design order']:.1f} s)",
        "every move checked collision-free against the scene's capsule model",
    ] + [f"pose {k + 1} NOT MEASURED: {why}" for k, why in program.skipped] + (
        [f"poses {program.stats['wrapped_poses']}: joint values whole turns from the design's "
         "(--wrap: the same robot geometry, nearer home)"] if program.stats.get("wrapped_poses") else []
    ) + declared_lines(program)


def frame_values(frame) -> tuple[float, ...]:
    """``(x, y, z, a, b, c)`` of a :class:`~calib_oed.program.settings.FrameSpec`: origin [mm] and
    KUKA's ZYX angles [deg] (A about z = yaw, B about y = pitch, C about x = roll)."""
    x, y, z = (1e3 * np.asarray(frame.xyz, float)).tolist()
    roll, pitch, yaw = np.rad2deg(np.asarray(frame.rpy, float)).tolist()
    return x, y, z, yaw, pitch, roll


def declared_lines(program: Program) -> list[str]:
    """Header lines naming the tool, base and payload the program declares (mm, deg, kg)."""
    out = []
    for what, frame in (("tool", program.tool), ("base/user frame", program.base)):
        if frame is not None:
            v = frame_values(frame)
            out.append(f"{what} {frame.number}: X {v[0]:.3f} Y {v[1]:.3f} Z {v[2]:.3f} mm, "
                       f"A {v[3]:.4f} B {v[4]:.4f} C {v[5]:.4f} deg (ZYX)")
    if program.payload is not None:
        c = 1e3 * np.asarray(program.payload.com, float)
        out.append(f"payload {program.payload.number}: {program.payload.mass:.3f} kg at "
                   f"X {c[0]:.3f} Y {c[1]:.3f} Z {c[2]:.3f} mm (flange frame)")
    return out
