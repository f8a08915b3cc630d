r"""Meshcat inspection view of a calibration scene and design (a web page).

One meshcat scene shows:

- every design pose (red if it violates a feasibility constraint): the
  robot's URDF visual geometry, all poses in one node ``calib_oed/design/robots``
  that holds the meshes once (:mod:`calib_oed.viz.instances`: a 60-pose UR10
  design stays a few MB), and per pose a subtree ``calib_oed/design/pose_<k>``
  with its feasibility capsules (hidden; toggle them in meshcat's *Open
  Controls* panel), reflectors and laser beams to the tracker. A pose
  selector (:mod:`calib_oed.viz.selector`: a list with per-pose labels, a
  slider, arrow keys) shows one pose solid with its beams, the others faint;
  the page opens on pose 0;
- each working (KPI) configuration in its own colour, ``calib_oed/kpi/<name>``,
  with its capsules shown and, given a design, the confidence ellipsoid of the
  KPI at the TCP with a text board stating its drawing scale;
- the tracker (a small cylinder with its frame triad), the cell's obstacle
  capsules and half-spaces (thin translucent plates clipped to the scene),
  the world axes (robot base; x red, y green, z blue, labelled) and a scale
  bar labelled in mm.

**The ellipsoid.** With :math:`C_i` the 3×3 block of the KPI covariance
:math:`C_s` of the design (:meth:`~calib_oed.calibration.problem.CalibrationProblem.kpi_covariance`,
[m²]) in world coordinates, the region at level :math:`1-\alpha` is
:math:`\{x : (x - s_i)^\top C_i^{-1} (x - s_i) \le \chi^2_3(1-\alpha)\}`
(:mod:`calib_oed.calibration.confidence`): half-axes :math:`a_k = \sqrt{\chi^2_3(1-\alpha)\,\lambda_k}`
[m] along the eigenvectors of :math:`C_i`. A good design's half-axes are
hundredths of a millimetre, so the ellipsoid is drawn scaled about its centre
by a factor :math:`f` (one for all working configurations): the 1-2-5 number
that brings the largest drawn half-axis nearest to ``target_half_axis``
(50 mm). :math:`f` is in the node name (``ellipsoid_95pct_x500``), on the text
board, and in :class:`ViewInfo`. Ellipsoid and board are drawn on top of
everything, so that the robot's wrist never hides them.

**Frames and units.** Below the root node ``calib_oed``, transforms are world
(robot base, z up) coordinates [m]. The root node itself is shifted by
:math:`-c`, :math:`c` the centre of the scene's bounding box
(:attr:`ViewInfo.center`), because meshcat's orbit controls turn about its
origin; its grid and axes are hidden.

meshcat (which imports IPython and zmq) is imported only when a viewer starts.
This module draws the view into a visualizer (:func:`build_view`);
:mod:`calib_oed.viz.sessions` starts one and shows it, live or as a static page.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from calib_oed.calibration.confidence import (
    MM_PER_M,
    ConfidenceEllipsoid,
    chi2_radius2,
    kpi_ellipsoids,
)
from calib_oed.exceptions import CalibOedError, ShapeError, ViewerSettingError
from calib_oed.viz.draw import (  # TRACKER_SIZE, ellipsoid_node_name: re-exported
    COLORS,
    DEFAULT_TARGET_HALF_AXIS,
    MESH_BUDGET_BYTES,
    ROBOT_DRAWINGS,
    ROOT,
    TRACKER_SIZE,  # noqa: F401
    _camera,
    _material,
    _node,
    _Painter,
    _placement,
    _visual_model,
    color_int,
    draw_guides,
    ellipsoid_node_name,  # noqa: F401
    solid_points,
)
from calib_oed.viz.instances import RobotInstances, draw_instances
from calib_oed.viz.program_view import ProgramView, check_program, draw_program
from calib_oed.viz.selector import add_selector, pose_labels

if TYPE_CHECKING:
    import meshcat

    from calib_oed.calibration.workflow import Setup


@dataclass(frozen=True, eq=False)
class EllipsoidView:
    """A drawn KPI confidence ellipsoid.

    Attributes:
        path: Its meshcat node (the name carries level and scale).
        ellipsoid: The true (unscaled) region, world coordinates [m], [m²].
        scale: Drawing scale :math:`f`: the drawn half-axes are ``scale * ellipsoid.half_axes``.
    """

    path: str
    ellipsoid: ConfidenceEllipsoid
    scale: float

    @property
    def half_axes_mm(self) -> np.ndarray:
        """True half-axes [mm], descending."""
        return self.ellipsoid.half_axes * MM_PER_M


@dataclass(frozen=True, eq=False)
class ViewInfo:
    """What :func:`build_view` drew and where (meshcat paths below ``/meshcat``).

    Attributes:
        center: :math:`c` [m]; the root node ``calib_oed`` is shifted by :math:`-c`.
        pose_paths: One subtree per design pose (``robot``, ``capsules``, ``reflectors``, ``beams``).
        kpi_paths: One subtree per working configuration (the same, plus the ellipsoid).
        beam_paths: Laser-beam nodes: design poses, then working configurations.
        tracker_path: Tracker body and triad (node transform :math:`T_{W,T}`).
        obstacle_paths: Cell capsules and half-space plates.
        ellipsoids: The KPI ellipsoids; empty without a design or when the design
            does not determine the KPI (``notes`` says why).
        ellipsoid_scale: :math:`f`, or ``None`` when no ellipsoid is drawn.
        level: Confidence level :math:`1-\\alpha` of the ellipsoids.
        infeasible_poses: Design poses violating a feasibility constraint (drawn red).
        robot_drawing: How design poses are drawn: ``"visual"`` or ``"capsules"``.
        robots_path: The node holding every design pose's visual geometry (meshes
            once, one group ``pose_<k>`` per pose), or ``None`` (capsules, no design).
        selector: Whether the pose selector is in the page.
        labels: Per design pose: feasibility and joint values (the selector's labels).
        axes_path, scale_bar_path: World axes and scale bar.
        scale_bar_length: Length of the scale bar and the axes [m].
        notes: What was left out, and why.
        program: The animated measurement program (:mod:`calib_oed.viz.program_view`), or ``None``.
    """

    center: np.ndarray
    pose_paths: tuple[str, ...]
    kpi_paths: tuple[str, ...]
    beam_paths: tuple[str, ...]
    tracker_path: str
    obstacle_paths: tuple[str, ...]
    ellipsoids: tuple[EllipsoidView, ...]
    ellipsoid_scale: float | None
    level: float
    infeasible_poses: tuple[int, ...]
    robot_drawing: str
    robots_path: str | None
    selector: bool
    labels: tuple[str, ...]
    axes_path: str
    scale_bar_path: str
    scale_bar_length: float
    notes: tuple[str, ...] = ()
    program: ProgramView | None = None

    @property
    def n_poses(self) -> int:
        """Number of design poses drawn."""
        return len(self.pose_paths)

    @property
    def half_axes_mm(self) -> np.ndarray:
        """True half-axes of the ellipsoids [mm], (t, 3), descending per row."""
        return np.array([e.half_axes_mm for e in self.ellipsoids]).reshape(-1, 3)

    def summary(self) -> str:
        """A few lines for the command line (lengths in mm)."""
        bad = f" {list(self.infeasible_poses)}" if self.infeasible_poses else ""
        lines = [f"{self.n_poses} design pose(s), {len(self.infeasible_poses)} infeasible{bad}"]
        for e in self.ellipsoids:
            axes = ", ".join(f"{a:.4f}" for a in e.half_axes_mm)
            lines.append(f"{100 * self.level:g}% KPI ellipsoid {e.ellipsoid.name!r}: half-axes "
                         f"[{axes}] mm, drawn x{e.scale:g}")
        if self.selector:
            lines.append("pose selector: the list at the top left (hover a pose for its joints), "
                         "the 'pose' slider under Open Controls, or the arrow keys; 'a' shows all poses")
        if self.program is not None:
            lines.append(self.program.summary())
        return "\n".join(lines + [f"note: {n}" for n in self.notes])


# ------------------------------------------------------------ inputs, numbers
def check_design(s: Setup, q_design) -> np.ndarray:
    """``q_design`` as (n, nq) with 1 <= n <= :data:`MAX_VIEW_POSES` (or (0, nq) for None).

    Raises:
        ShapeError, NonFiniteError: not finite (n, nq) with n >= 1.
        ViewerSettingError: more than :data:`MAX_VIEW_POSES` poses.
    """
    robot = s.problem.robot
    if q_design is None:
        return np.zeros((0, robot.nq))
    q = robot.check_configurations(q_design, "q_design")
    if q.shape[0] < 1:
        raise ShapeError("q_design", f"(n, {robot.nq}) with n >= 1 (or None: no design)", q.shape)
    if q.shape[0] > MAX_VIEW_POSES:
        raise ViewerSettingError("q_design", f"{q.shape[0]} poses", (
            f"the viewer draws at most {MAX_VIEW_POSES} poses (each adds ~50 kB to a page and a "
            "row to the pose list; a calibration measures tens to hundreds): view a part of the "
            "design, e.g. its first rows"))
    return q


#: The most design poses the viewer draws (a 10000-pose page would take ~0.5 GB).
MAX_VIEW_POSES = 1000


def _positive(name: str, value, allow_none: bool = False) -> float | None:
    if value is None and allow_none:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (np.isfinite(v) and v > 0.0):
        raise ViewerSettingError(name, value, "must be a finite number > 0"
                                 + (" (or None: automatic)" if allow_none else ""))
    return v


def display_scale(largest_half_axis: float, target: float = DEFAULT_TARGET_HALF_AXIS) -> float:
    """The 1-2-5 number (1, 2, 5, 10, 20, ...) nearest in ratio to ``target / largest_half_axis``.

    Args:
        largest_half_axis: Largest true half-axis [m], > 0.
        target: Wanted largest drawn half-axis [m], > 0.
    """
    ratio = _positive("target", target) / _positive("largest_half_axis", largest_half_axis)
    candidates = 10.0 ** np.floor(np.log10(ratio)) * np.array([1.0, 2.0, 5.0, 10.0])
    best = candidates[np.argmin(np.abs(np.log(candidates / ratio)))]
    return float(f"{best:.1g}")  # without the rounding noise of 10**k


def world_ellipsoids(s: Setup, q_design: np.ndarray, level: float = 0.95) -> list[ConfidenceEllipsoid]:
    r"""KPI confidence ellipsoids of design ``q_design`` (n, nq), in world coordinates.

    A KPI in the tracker frame is mapped to the world: :math:`s^W = T_{W,T}\,s^T`,
    :math:`C^W = R_T\,C^T R_T^\top` (nominal tracker pose).

    Raises:
        NotIdentifiableError: the design does not determine the KPI.
    """
    problem = s.problem
    c_s = problem.kpi_covariance(q_design)
    centers = problem.kpi.compute_values(problem.space)
    if problem.kpi.frame == "tracker":
        t_wt = s.scene.tracker.placement()
        rot = np.kron(np.eye(len(centers)), t_wt.rotation)
        c_s = rot @ c_s @ rot.T
        centers = np.array([t_wt.act(c) for c in centers])
    return kpi_ellipsoids(c_s, centers, level, problem.kpi.names)


# ------------------------------------------------------------ drawing pieces
def _pose_material(color: str, solid: bool):
    """A design pose's material: faint (``COLORS[color]``), or solid when selected
    (``COLORS["selected"]``; an infeasible pose stays red)."""
    if not solid:
        return _material(color)
    material = _material("selected" if color == "ghost" else color)
    material.opacity, material.transparent = 1.0, False
    return material


# ----------------------------------------------------------------- the view
def build_view(
    vis: meshcat.Visualizer,
    s: Setup,
    q_design: np.ndarray | None = None,
    *,
    level: float = 0.95,
    ellipsoid_scale: float | None = None,
    target_half_axis: float = DEFAULT_TARGET_HALF_AXIS,
    ghosts: bool = True,
    selector: bool = True,
    robot_drawing: str = "auto",
    camera: Sequence[float] | None = None,
    program=None,
) -> ViewInfo:
    """Draw scene ``s`` and design ``q_design`` into a meshcat visualizer.

    Args:
        vis: A ``meshcat.Visualizer`` at its root; the view replaces ``/meshcat/calib_oed``.
        s: The scene set-up (:func:`calib_oed.calibration.workflow.setup`).
        q_design: Design configurations (n, nq) [rad, or m for prismatic joints], or
            ``None``: the scene and working configurations only.
        level: Confidence level of the KPI ellipsoids, in (0, 1).
        ellipsoid_scale: Drawing scale :math:`f` (> 0); ``None``: :func:`display_scale`
            of the largest half-axis and ``target_half_axis``.
        target_half_axis: Largest drawn half-axis the automatic scale aims at [m], > 0.
        ghosts: The poses not selected are drawn faint (else hidden); the page opens on pose 0.
        selector: Add the pose selector (list, slider, keys; :mod:`calib_oed.viz.selector`).
        robot_drawing: ``"visual"`` (URDF visual geometry), ``"capsules"`` (feasibility
            capsules), or ``"auto"``: visual, but capsules in the design poses when their
            meshes (one copy for all design poses, one per working configuration)
            would take more than :data:`MESH_BUDGET_BYTES`.
        camera: Camera position, world [m]; default: above the scene, across the beams.
        program: A measurement program read back (:class:`~calib_oed.program.csv_format.ProgramTargets`):
            a robot runs it, animated (:mod:`calib_oed.viz.program_view`); its measurement
            poses must be the design's rows.

    Raises:
        ShapeError, NonFiniteError: ``q_design`` is not finite (n, nq) with n >= 1,
            or ``camera`` not 3 finite numbers.
        ViewerSettingError: a scale <= 0, an unknown ``robot_drawing``.
        ConfidenceLevelError: ``level`` not in (0, 1).
    """
    q = check_design(s, q_design)
    scale = _positive("ellipsoid_scale", ellipsoid_scale, allow_none=True)
    target = _positive("target_half_axis", target_half_axis)
    chi2_radius2(level, 3)  # raises ConfidenceLevelError
    if robot_drawing not in ROBOT_DRAWINGS:
        raise ViewerSettingError("robot_drawing", robot_drawing, f"must be one of {ROBOT_DRAWINGS}",
                                 ROBOT_DRAWINGS)
    eye = None if camera is None else np.asarray(camera, dtype=float)
    if eye is not None and (eye.shape != (3,) or not np.all(np.isfinite(eye))):
        raise ShapeError("camera", "(3,) finite [m]", np.shape(camera))
    if program is not None:
        check_program(s.problem.robot, program, q)

    notes: list[str] = []
    geom, mesh_bytes, note = (None, 0, "") if robot_drawing == "capsules" else _visual_model(s.problem.robot)
    notes += [note] if note else []
    design_geom = geom
    page_bytes = mesh_bytes * (1 + len(s.scene.kpi.configurations))  # design poses share one copy
    if robot_drawing == "auto" and len(q) and page_bytes > MESH_BUDGET_BYTES:
        design_geom = None
        notes.append(f"design poses drawn by their capsules: the robot's meshes would "
                     f"take {page_bytes / 1e6:.0f} MB > {MESH_BUDGET_BYTES / 1e6:.0f} MB "
                     "(robot_drawing='visual' draws them anyway)")
    ellipsoids: list[ConfidenceEllipsoid] = []
    if len(q):
        try:
            ellipsoids = world_ellipsoids(s, q, level)
        except CalibOedError as exc:  # too few or degenerate poses
            notes.append(f"no KPI ellipsoid: {exc}")
    if ellipsoids and scale is None:
        scale = display_scale(max(float(e.half_axes[0]) for e in ellipsoids), target)
    feasible = s.feasibility.compute(q, jacobian=False).feasible if len(q) else np.ones(0, bool)
    infeasible = tuple(int(k) for k in np.flatnonzero(~feasible))

    vis[ROOT].delete()
    painter = _Painter(vis, s)
    pose_paths = [f"{ROOT}/design/pose_{k:03d}" for k in range(len(q))]
    kpi_paths = [f"{ROOT}/kpi/{_node(w.name)}" for w in s.scene.kpi.configurations]
    beam_paths, colors = [], ["infeasible" if k in infeasible else "ghost" for k in range(len(q))]
    instanced = design_geom is not None and len(q) > 0
    for k, (path, qk) in enumerate(zip(pose_paths, q, strict=True)):
        solid = not instanced and k == 0 and colors[k] == "ghost"  # capsules stand for the robot
        beam_paths.append(painter.pose(path, qk, "selected" if solid else colors[k], None,
                                       show_capsules=False, robot_elsewhere=instanced,
                                       label=f"pose {k}"))
        for part in ("beams", "reflectors"):  # the opening state: pose 0 selected
            vis[path][part].set_property("visible", k == 0)
        if not instanced:
            vis[path].set_property("visible", bool(ghosts or k == 0))
    robots_path = f"{ROOT}/design/robots" if instanced else None
    if instanced:
        robots = RobotInstances(s.problem.robot.model, design_geom, q,
                                [_pose_material(c, k == 0) for k, c in enumerate(colors)],
                                visible=[ghosts or k == 0 for k in range(len(q))])
        draw_instances(vis[robots_path], robots)
        if robots.cell is not None:
            notes.append(f"design poses drawn with meshes coarsened to {robots.cell * 1e3:g} mm cells "
                         f"({robots.triangles[0]} triangles per robot instead of {robots.triangles[1]}, "
                         f"{len(q)} poses) so that the page draws quickly; the working configurations' "
                         "robots keep the full meshes")
        if robots.skipped:
            notes.append(f"visual geometry meshcat cannot draw, left out: {', '.join(robots.skipped)}")
    labels, short = pose_labels(s.problem.robot.model, q, infeasible)
    with_selector = bool(selector and len(q))
    if with_selector:
        add_selector(vis, f"{ROOT}/design", [p.rsplit("/", 1)[1] for p in pose_paths], labels, short,
                     [(color_int(c), COLORS[c][3]) for c in colors],
                     [color_int("selected" if c == "ghost" else c) for c in colors], infeasible,
                     instanced=instanced, ghosts=ghosts)
    for path, w in zip(kpi_paths, s.scene.kpi.configurations, strict=True):
        beam_paths.append(painter.pose(path, np.asarray(w.q), "kpi", geom, show_capsules=True))
    obstacle_paths = painter.cell()
    tracker_path = painter.tracker_body()
    shown = None
    if program is not None:
        from calib_oed.program.settings import program_settings_from_scene
        from calib_oed.program.timing import JointDynamics

        dyn = JointDynamics.from_robot(s.problem.robot, program_settings_from_scene(s.scene))
        shown = draw_program(vis, s, program.q, program.kinds, dyn, geom)

    points = np.vstack(painter.points)
    center = 0.5 * (points.min(axis=0) + points.max(axis=0))
    if eye is None:
        obstacles = np.array([0.5 * (c.a + c.b) for c in s.scene.cell.capsules]
                             + [solid_points(x).mean(axis=0) for x in s.scene.cell.solids]).reshape(-1, 3)
        eye = _camera(points, center, painter.tracker.translation, obstacles)
    label_width = 0.25 * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    views = tuple(EllipsoidView(painter.ellipsoid(path, e, scale, eye, label_width), e, scale)
                  for path, e in zip(kpi_paths[:len(ellipsoids)], ellipsoids, strict=True))
    axes_path, bar_path, bar_length = draw_guides(vis, points, eye)

    vis[ROOT].set_transform(_placement(np.eye(3), -center))
    for hidden in ("/Grid", "/Axes"):
        vis[hidden].set_property("visible", False)
    rel = eye - center  # meshcat's camera node is y-up: world (x, y, z) is (x, z, -y) there
    vis["/Cameras/default/rotated/<object>"].set_property("position", [rel[0], rel[2], -rel[1]])
    return ViewInfo(
        center=center, pose_paths=tuple(pose_paths), kpi_paths=tuple(kpi_paths),
        beam_paths=tuple(beam_paths), tracker_path=tracker_path, obstacle_paths=tuple(obstacle_paths),
        ellipsoids=views, ellipsoid_scale=scale if views else None, level=float(level),
        infeasible_poses=infeasible, robot_drawing="visual" if design_geom is not None else "capsules",
        robots_path=robots_path, selector=with_selector, labels=tuple(labels), axes_path=axes_path,
        scale_bar_path=bar_path, scale_bar_length=bar_length, notes=tuple(notes), program=shown,
    )
