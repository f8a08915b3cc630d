r"""The measurement program in the viewer: one robot that runs the whole program (meshcat animation).

``calib-oed view SCENE DESIGN --program DIR`` reads the program's CSV
(:func:`calib_oed.program.csv_format.read_program_csv`: home, via points and
measurement poses in program order, URDF angles [rad]) and adds to the view
(:func:`calib_oed.viz.viewer.build_view`), below ``calib_oed/program``:

- ``robot``: the robot in its own colour, moved by a meshcat animation through
  every target in order, home to home, via points included;
- ``tcp_path``: the path of the tool frame's origin over the whole program
  (a line), and ``via/<k>``: a small sphere at the tool frame at each via point.

**Timing.** Every move is the straight joint-space segment the continuous check
certified, :math:`q(t) = q_a + s(t)(q_b - q_a)`, with the synchronised PTP
profile :math:`s(t)` of :func:`calib_oed.program.timing.move_fraction` and the
move time :math:`T(q_a, q_b)` of :class:`~calib_oed.program.timing.JointDynamics`
(the scene's ``program:`` block): the animation runs at the estimated speed of
the robot. At a measurement pose it holds ``dwell_shown`` seconds (0.5 s by
default, not the program's dwell, so that a 60-pose program plays in about a
minute; meshcat's *Animations* panel has play, pause, a time scrubber and a
time scale).

Keys are set every ``key_step`` (0.1 s) of a move and at its ends; three.js
interpolates positions linearly and orientations by slerp in between. The robot
is drawn by its URDF visual geometry (nodes ``robot/visuals/<geometry>``, placed
by :math:`T_{W,G_g}(q)`), or by its capsules, each in its link frame (nodes
``robot/<capsule>``, placed by :math:`T_{W,L}(q)`). World (robot base) frame [m].
The animation is a meshcat ``set_animation`` command: a live viewer and the
static page (meshcat's export replays it) both play it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ProgramError
from calib_oed.program.timing import JointDynamics, move_fraction
from calib_oed.viz.draw import COLORS, ROOT, _draw_capsule, _material, _node, _placement

#: Frames per second of meshcat's animation clip (key times are frame / FPS).
FPS = 30.0


@dataclass(frozen=True, eq=False)
class Timeline:
    """Configurations of the animated robot over time.

    Attributes:
        times: Key times [s], (K,), non-decreasing.
        q: Configurations at the keys [rad], (K, nq).
        arrivals: Time the robot reaches each target [s], (k,) (the first is 0).
    """

    times: np.ndarray
    q: np.ndarray
    arrivals: np.ndarray


def program_timeline(targets: np.ndarray, kinds, dyn: JointDynamics, dwell_shown: float = 0.5,
                     key_step: float = 0.1) -> Timeline:
    """The key times and configurations of the program through ``targets`` (k, nq) [rad].

    Args:
        targets: Home, via points, poses, home, in program order [rad].
        kinds: ``"home"``, ``"via"`` or ``"pose"`` per target; the robot holds
            ``dwell_shown`` [s] at every ``"pose"``.
        dyn: Joint velocity and acceleration limits of the move times.
        dwell_shown: Hold at a measurement pose in the animation [s].
        key_step: Largest time between keys during a move [s].
    """
    targets = np.asarray(targets, dtype=float)
    times, qs, arrivals = [0.0], [targets[0]], [0.0]
    now = 0.0
    for qa, qb, kind in zip(targets[:-1], targets[1:], list(kinds)[1:], strict=True):
        total, t_acc = dyn.acceleration_phase(qa, qb)
        n = max(1, int(np.ceil(total / key_step)))
        t = np.linspace(0.0, total, n + 1)[1:]
        s = move_fraction(t, total, t_acc)
        times += list(now + t)
        qs += list(qa + s[:, None] * (qb - qa))
        now += total
        arrivals.append(now)
        if kind == "pose" and dwell_shown > 0:
            now += dwell_shown
            times.append(now)
            qs.append(qb)
    return Timeline(np.array(times), np.array(qs), np.array(arrivals))


@dataclass(frozen=True, eq=False)
class ProgramView:
    """What :func:`draw_program` drew.

    Attributes:
        path: Its node (``calib_oed/program``).
        robot_path: The animated robot's node.
        animated_paths: The nodes the animation moves (one per geometry or capsule).
        timeline: Key times and configurations.
        duration: Length of the animation [s].
        n_targets, n_poses, n_via: Targets in the program; of them measurement poses and via points.
        drawing: ``"visual"`` or ``"capsules"``.
    """

    path: str
    robot_path: str
    animated_paths: tuple[str, ...]
    timeline: Timeline
    duration: float
    n_targets: int
    n_poses: int
    n_via: int
    drawing: str

    def summary(self) -> str:
        return (f"program: {self.n_targets} targets ({self.n_poses} measurement poses, {self.n_via} via "
                f"points), animated over {self.duration:.1f} s (moves at the estimated joint speeds, "
                "0.5 s shown per measurement pose); play/pause/time scale under Open Controls > Animations")


def _robot_nodes(vis, s, path: str, geom):
    """Draw the robot once below ``path``; per animated node ``(node path, placement function)``,
    the function mapping (model, data, geometry data) after forward kinematics to a 4×4 matrix."""
    model = s.problem.robot.model
    if geom is not None:
        from pinocchio.visualize import MeshcatVisualizer

        viz = MeshcatVisualizer(model, None, geom)
        viz.initViewer(viewer=vis)
        viz.loadViewerModel(rootNodeName=path, visual_color=list(COLORS["program"]))
        nodes = []
        for g, obj in enumerate(geom.geometryObjects):
            scale = np.diag([*obj.meshScale, 1.0])
            nodes.append((f"{viz.getViewerNodeName(obj, pin.GeometryType.VISUAL)}",
                          lambda data, gdata, g=g, scale=scale: gdata.oMg[g].homogeneous @ scale))
        return nodes
    seg = s.feasibility.segments
    nodes = []
    for i, (name, role) in enumerate(zip(seg.names, seg.roles, strict=True)):
        body = int(seg.body_a[i])
        if role not in ("robot", "reflector") or body != int(seg.body_b[i]):
            continue
        node = f"{path}/{_node(name)}"
        _draw_capsule(vis[node], np.asarray(seg.a_local[i]), np.asarray(seg.b_local[i]),
                      float(seg.radius[i]), _material("program"))
        nodes.append((node, lambda data, gdata, body=body: data.oMi[body].homogeneous))
    return nodes


def draw_program(vis, s, targets, kinds, dyn: JointDynamics, geom=None, dwell_shown: float = 0.5,
                 key_step: float = 0.1, play: bool = True) -> ProgramView:
    """Draw the animated program into ``vis`` (below ``calib_oed/program``).

    Args:
        vis: The ``meshcat.Visualizer`` of the view (:func:`calib_oed.viz.viewer.build_view`).
        s: The scene set-up.
        targets: The program's targets in order [rad], (k, nq), URDF angles.
        kinds: ``"home"``, ``"via"`` or ``"pose"`` per target.
        dyn: Joint limits of the move times.
        geom: The robot's visual geometry model, or ``None``: drawn by its capsules.
        dwell_shown: Hold at each measurement pose [s].
        key_step: Largest time between keys [s].
        play: Start playing when the page opens.
    """
    import meshcat.geometry as mg
    from meshcat.animation import Animation

    robot = s.problem.robot
    model = robot.model
    kinds = tuple(kinds)
    timeline = program_timeline(targets, kinds, dyn, dwell_shown, key_step)
    path = f"{ROOT}/program"
    robot_path = f"{path}/robot"
    vis[path].delete()
    nodes = _robot_nodes(vis, s, robot_path, geom)
    data = model.createData()
    gdata = pin.GeometryData(geom) if geom is not None else None
    animation = Animation(default_framerate=FPS)
    tcp = []
    for t, q in zip(timeline.times, timeline.q, strict=True):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacement(model, data, robot.tool_frame_id)
        if geom is not None:
            pin.updateGeometryPlacements(model, data, geom, gdata)
        frame = animation.at_frame(vis, float(t * FPS))
        for node, placement in nodes:
            frame[node].set_transform(placement(data, gdata))
            if t == 0.0:  # the robot at home when not playing; and the nodes' own transforms:
                # three.js re-applies a track only when its value changes, so a constant track
                # (a link that does not move) would otherwise keep the placement drawn above
                vis[node].set_transform(placement(data, gdata))
        tcp.append(data.oMf[robot.tool_frame_id].translation.copy())
    tcp = np.array(tcp, dtype=np.float32)
    vis[f"{path}/tcp_path"].set_object(mg.Line(mg.PointsGeometry(tcp.T), mg.LineBasicMaterial(
        color=_material("program").color)))
    vias = [k for k, kind in enumerate(kinds) if kind == "via"]
    for n, k in enumerate(vias, start=1):
        pin.framesForwardKinematics(model, data, np.asarray(targets[k], dtype=float))
        vis[f"{path}/via/{n}"].set_object(mg.Sphere(0.02), _material("via"))
        vis[f"{path}/via/{n}"].set_transform(_placement(np.eye(3), data.oMf[robot.tool_frame_id].translation))
    vis.set_animation(animation, play=play, repetitions=1)
    return ProgramView(path, robot_path, tuple(n for n, _ in nodes), timeline, float(timeline.times[-1]),
                       len(kinds), sum(k == "pose" for k in kinds), len(vias),
                       "visual" if geom is not None else "capsules")


def check_program(robot, program, q_design: np.ndarray, atol: float = 1e-6) -> None:
    """A program read back must belong to the design shown: each measurement pose ``N`` equal to
    the design's row ``N`` up to whole turns (``--wrap``; within ``atol`` [rad]), and every
    target within the joint limits.

    Raises:
        ProgramError: naming the first pose that differs, or the target outside the limits.
    """
    q = np.asarray(program.q, dtype=float)
    if q.ndim != 2 or q.shape[1] != robot.nq:
        raise ProgramError("program", str(program.path), f"targets of {q.shape[-1]} joints for a robot of "
                           f"{robot.nq}")
    outside = np.flatnonzero(np.any((q < robot.lower - atol) | (q > robot.upper + atol), axis=1))
    if len(outside):
        raise ProgramError("program", str(program.path), f"target {int(outside[0]) + 1} is outside the "
                           "robot's joint limits: a program of another robot?")
    if not len(q_design):
        return
    for k, (kind, pose) in enumerate(zip(program.kinds, program.poses, strict=True)):
        if kind != "pose":
            continue
        if not 1 <= pose <= len(q_design):
            raise ProgramError("program", str(program.path), f"pose {pose} (target {k + 1}) is not a row "
                               f"of the design (1..{len(q_design)})")
        diff = q[k] - q_design[pose - 1]
        gap = float(np.max(np.abs(diff - 2 * np.pi * np.round(diff / (2 * np.pi)))))  # --wrap: whole turns
        if gap > atol:
            raise ProgramError("program", str(program.path), f"pose {pose} differs from the design's row "
                               f"{pose} by {np.rad2deg(gap):.4g} deg: the program was made from another "
                               "design")
