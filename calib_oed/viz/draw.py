"""Drawing primitives of the meshcat view (:mod:`calib_oed.viz.viewer`): colours,
capsules, text boards, the robot's geometry per pose, the camera.

Everything here draws in world (robot base, z up) coordinates [m] below the
view's root node; :mod:`calib_oed.viz.viewer` assembles the scene.
"""

from __future__ import annotations

import functools
import re
import warnings
from typing import TYPE_CHECKING

import coal
import numpy as np
import pinocchio as pin

from calib_oed.calibration.confidence import ConfidenceEllipsoid

if TYPE_CHECKING:
    from calib_oed.calibration.workflow import Setup

#: Root node of the view (below meshcat's ``/meshcat``).
ROOT = "calib_oed"
#: Largest drawn half-axis the automatic ellipsoid scale aims at [m].
DEFAULT_TARGET_HALF_AXIS = 0.05
#: ``robot_drawing="auto"`` draws the robot by its capsules when its meshes would
#: take more than this in the page: one copy for all design poses (mesh reuse,
#: :mod:`calib_oed.viz.instances`) and one per working configuration (UR10:
#: 2.8 MB per copy) [bytes].
MESH_BUDGET_BYTES = 25_000_000
#: How the robot can be drawn.
ROBOT_DRAWINGS = ("auto", "visual", "capsules")
#: Colours, RGBA in [0, 1].
COLORS: dict[str, tuple[float, float, float, float]] = {
    "ghost": (0.55, 0.65, 0.85, 0.35),       # feasible design pose
    "selected": (0.15, 0.35, 0.85, 1.00),    # the design pose the selector shows (solid)
    "infeasible": (0.95, 0.15, 0.15, 0.45),  # design pose violating a constraint
    "kpi": (0.15, 0.75, 0.30, 1.00),         # working configuration
    "capsule": (0.30, 0.80, 0.95, 0.15),     # feasibility capsules around the visual geometry
    "reflector": (1.00, 0.84, 0.00, 1.00),
    "beam": (1.00, 0.10, 0.10, 1.00),
    "obstacle": (0.65, 0.35, 0.20, 0.40),
    "halfspace": (0.55, 0.55, 0.55, 0.22),
    "tracker": (0.20, 0.20, 0.22, 1.00),
    "ellipsoid": (0.90, 0.10, 0.85, 0.75),
    "program": (1.00, 0.55, 0.00, 1.00),     # the robot running the program (animated), its TCP path
    "via": (0.10, 0.10, 0.10, 1.00),         # via points of the program
}
TRACKER_SIZE = (0.25, 0.10)  # drawn tracker head: height, radius [m]


#: Length of a reflector's drawn axis [m].
AXIS_LENGTH = 0.08


def ellipsoid_node_name(level: float, scale: float) -> str:
    """Node name of a drawn ellipsoid from its level and scale: ``ellipsoid_95pct_x500``."""
    return _node(f"ellipsoid_{100 * level:g}pct_x{scale:g}")


def _node(name: str) -> str:
    """A meshcat node name: letters, digits and ``_ . + -`` (``link_2#0`` -> ``link_2_0``)."""
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", name) or "_"


def color_int(kind: str) -> int:
    """The ``0xRRGGBB`` integer of ``COLORS[kind]``."""
    r, g, b, _ = COLORS[kind]
    return (int(r * 255) << 16) + (int(g * 255) << 8) + int(b * 255)


def _material(kind: str, **extra):
    import meshcat.geometry as mg

    a = COLORS[kind][3]
    return mg.MeshPhongMaterial(color=color_int(kind), opacity=a, transparent=a < 1.0, **extra)


@functools.cache
def _on_top_mesh() -> type:
    """A meshcat mesh drawn after all others (three.js ``renderOrder``); with
    ``depthTest=False`` in its material it shows through the robot."""
    import meshcat.geometry as mg

    class OnTopMesh(mg.Mesh):
        def __init__(self, geometry, material, order: int = 10):
            super().__init__(geometry, material)
            self.order = order

        def lower(self):
            data = super().lower()
            data["object"]["renderOrder"] = self.order
            return data

    return OnTopMesh


def _placement(rotation, translation) -> np.ndarray:
    """Homogeneous 4×4 matrix of a rotation and a translation [m]."""
    return pin.SE3(np.asarray(rotation, dtype=float), np.asarray(translation, dtype=float)).homogeneous


def _turn(frm, to) -> np.ndarray:
    """A rotation taking direction ``frm`` to direction ``to``."""
    return pin.Quaternion.FromTwoVectors(np.asarray(frm, float), np.asarray(to, float)).toRotationMatrix()


def _draw_capsule(node, a: np.ndarray, b: np.ndarray, radius: float, material) -> None:
    """A capsule from its end points in the world [m]: a cylinder (meshcat's axis is y)
    and two spheres."""
    import meshcat.geometry as mg

    axis = b - a
    length = float(np.linalg.norm(axis))
    if length > 1e-9:
        node["body"].set_object(mg.Cylinder(length, radius), material)
        node["body"].set_transform(_placement(_turn([0.0, 1.0, 0.0], axis), 0.5 * (a + b)))
    for end, point in (("end_a", a), ("end_b", b)):
        node[end].set_object(mg.Sphere(radius), material)
        node[end].set_transform(_placement(np.eye(3), point))


def _draw_text(node, text: str, width: float, position: np.ndarray, toward: np.ndarray) -> None:
    """An upright text board ``width`` [m] wide at ``position``, turned toward ``toward`` [m],
    drawn on top (meshcat's canvas text texture on a white strip)."""
    import meshcat.geometry as mg

    normal = np.asarray(toward, float) - position
    normal[2] = 0.0
    norm = np.linalg.norm(normal)
    normal = normal / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    rotation = np.column_stack([np.cross(up, normal), up, normal])  # box x right, y up, z to viewer
    texture = mg.GenericTexture({"type": "_text", "text": text, "font_size": 64, "font_face": "sans-serif"})
    on_top = _on_top_mesh()
    node["backing"].set_object(on_top(mg.Box([width, 0.18 * width, 0.002]), mg.MeshBasicMaterial(
        color=0xFFFFFF, opacity=0.85, transparent=True, depthTest=False), order=11))
    node["backing"].set_transform(_placement(rotation, position))
    node["text"].set_object(on_top(mg.Box([width, width, 0.002]), mg.MeshBasicMaterial(
        color=0xFFFFFF, map=texture, transparent=True, depthTest=False, side=0), order=12))
    node["text"].set_transform(_placement(rotation, position + 0.003 * normal))


def _visual_model(robot) -> tuple[pin.GeometryModel | None, int, str]:
    """The URDF visual geometry on the robot's (reduced) model: (model, bytes it adds
    to a page per pose, note when it cannot be drawn).

    Meshes are drawn from the triangles coal loaded (already scaled), not from
    their files: meshcat cannot recolour multi-material Collada meshes, and the
    triangles take about a quarter of the page space of the DAE text.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            geom = pin.buildGeomFromUrdfString(robot.model, robot.urdf_text, pin.GeometryType.VISUAL,
                                               package_dirs=list(robot.package_dirs))
    except (RuntimeError, ValueError) as exc:
        return None, 0, f"the URDF visual geometry cannot be loaded ({exc}): robot drawn by its capsules"
    if geom.ngeoms == 0:
        return None, 0, "the URDF has no visual geometry: robot drawn by its capsules"
    page_bytes = 0
    for g in geom.geometryObjects:
        if isinstance(g.geometry, coal.BVHModelBase):
            g.meshPath, g.meshScale = "", np.ones(3)
            page_bytes += 16 * (g.geometry.num_vertices + g.geometry.num_tris)  # float32/uint32, base64
    return geom, page_bytes, ""


def solid_points(solid) -> np.ndarray:
    """Points that span a solid obstacle, world [m]: box corners, cylinder rim points, mesh vertices."""
    from calib_oed.feasibility.shapes import Box, Cylinder

    if isinstance(solid, Box):
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * solid.half
        return solid.center + corners @ solid.rotation.T
    if isinstance(solid, Cylinder):
        u, v, w = solid.rotation.T
        ends = [solid.center + s * 0.5 * solid.length * w + solid.radius * d
                for s in (-1, 1) for d in (u, -u, v, -v)]
        return np.array(ends)
    return np.asarray(solid.vertices, dtype=float)


def solid_drawing(solid):
    """A meshcat geometry of a solid obstacle and its node transform (world [m]).

    Boxes and cylinders as meshcat primitives (a meshcat cylinder's axis is its y, the
    scene's is the cylinder's own z); a mesh as the convex hull of its vertices, the
    shape the feasibility check uses (:class:`~calib_oed.feasibility.shapes.MeshObstacle`).
    """
    import meshcat.geometry as mg
    from scipy.spatial import ConvexHull

    from calib_oed.feasibility.shapes import Box, Cylinder

    if isinstance(solid, Box):
        return mg.Box(solid.size.tolist()), _placement(solid.rotation, solid.center)
    if isinstance(solid, Cylinder):
        rotation = solid.rotation @ _turn([0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
        return mg.Cylinder(solid.length, solid.radius), _placement(rotation, solid.center)
    v = np.asarray(solid.vertices, dtype=float)
    hull = ConvexHull(v)
    faces = hull.simplices.copy()
    centroid = v[hull.vertices].mean(axis=0)
    normal = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    inward = np.einsum("ij,ij->i", normal, v[faces[:, 0]] - centroid) < 0
    faces[inward] = faces[inward][:, ::-1]  # counter-clockwise seen from outside
    return mg.TriangularMeshGeometry(v, faces), np.eye(4)


class _Painter:
    """Draws the parts of one scene into a visualizer."""

    def __init__(self, vis, s: Setup):
        self.vis = vis
        self.s = s
        self.model = s.problem.robot.model
        self.data = self.model.createData()
        self.segments = s.feasibility.segments  # robot and reflector capsules, beams, obstacles
        self.tracker = s.scene.tracker.placement()
        #: Points the view must show, world [m]: capsule ends, tracker, obstacles.
        self.points: list[np.ndarray] = [self.tracker.translation[None, :]]
        self.points += [np.array([c.a, c.b]) for c in s.scene.cell.capsules]
        self.points += [solid_points(x) for x in s.scene.cell.solids]

    def pose(self, path: str, q: np.ndarray, color: str, geom, show_capsules: bool,
             robot_elsewhere: bool = False, label: str | None = None) -> str:
        """Robot, capsules, reflectors and beams at ``q`` under ``path``; the beams' node.

        ``geom`` None draws the robot by its capsules (in ``color``, shown), unless
        ``robot_elsewhere``: its visual geometry is drawn by the caller (mesh reuse).
        With a ``label``, the reflectors' node also gets each reflector's axis (its
        ``normal``, :data:`AXIS_LENGTH` long) and the label on a board above the first
        reflector, so the pose shown says which it is where it is.
        """
        import meshcat.geometry as mg
        from pinocchio.visualize import MeshcatVisualizer

        node = self.vis[path]
        if geom is not None:
            viz = MeshcatVisualizer(self.model, None, geom)
            viz.initViewer(viewer=self.vis)
            viz.loadViewerModel(rootNodeName=f"{path}/robot", visual_color=list(COLORS[color]))
            viz.display(q)
        pin.forwardKinematics(self.model, self.data, q)
        seg, omi = self.segments, self.data.oMi
        a = np.array([omi[int(j)].act(p) for j, p in zip(seg.body_a, seg.a_local, strict=True)])
        b = np.array([omi[int(j)].act(p) for j, p in zip(seg.body_b, seg.b_local, strict=True)])
        drawn = geom is not None or robot_elsewhere
        capsule = _material("capsule" if drawn else color)
        for i, (name, role) in enumerate(zip(seg.names, seg.roles, strict=True)):
            if role in ("robot", "reflector"):
                _draw_capsule(node["capsules"][_node(name)], a[i], b[i], float(seg.radius[i]), capsule)
        node["capsules"].set_property("visible", bool(show_capsules or not drawn))
        beams = [i for i, role in enumerate(seg.roles) if role == "beam"]  # reflector -> tracker
        radius = 0.5 * self.s.scene.feasibility.reflector_radius
        for i, name in zip(beams, self.s.feasibility.reflector_names, strict=True):
            node["reflectors"][_node(name)].set_object(mg.Sphere(radius), _material("reflector"))
            node["reflectors"][_node(name)].set_transform(_placement(np.eye(3), a[i]))
        if label is not None:
            self._label_reflectors(node["reflectors"], q, a[beams], label)
        ends = np.stack([a[beams], b[beams]], axis=1).reshape(-1, 3).astype(np.float32)
        node["beams"].set_object(mg.LineSegments(mg.PointsGeometry(ends.T),
                                                 mg.LineBasicMaterial(color=_material("beam").color)))
        self.points.append(a[[role != "obstacle" for role in seg.roles]])
        return f"{path}/beams"

    def _label_reflectors(self, node, q: np.ndarray, centres: np.ndarray, label: str) -> None:
        """The reflectors' axes (tool-frame normals in the world) and ``label`` above the first."""
        import meshcat.geometry as mg

        robot = self.s.problem.robot
        pin.updateFramePlacements(self.model, self.data)
        rot = self.data.oMf[robot.tool_frame_id].rotation
        axes = np.array([rot @ r.normal for r in self.s.scene.reflectors])
        ends = np.stack([centres, centres + AXIS_LENGTH * axes], axis=1).reshape(-1, 3).astype(np.float32)
        node["axes"].set_object(mg.LineSegments(mg.PointsGeometry(ends.T),
                                                mg.LineBasicMaterial(color=color_int("reflector"), linewidth=3)))
        _draw_text(node["label"], label, 0.3, centres[0] + np.array([0.0, 0.0, 0.12]), self.tracker.translation)

    def cell(self) -> list[str]:
        """Obstacle capsules and spheres, boxes, cylinders, meshes (their convex hulls, the
        shape the check uses), and half-space plates clipped to the scene's points."""
        import meshcat.geometry as mg

        paths = []
        for cap in self.s.scene.cell.capsules:
            paths.append(f"{ROOT}/cell/{_node(cap.name)}")
            _draw_capsule(self.vis[paths[-1]], cap.a, cap.b, cap.radius, _material("obstacle"))
        for solid in self.s.scene.cell.solids:
            paths.append(f"{ROOT}/cell/{_node(solid.name)}")
            shape, placement = solid_drawing(solid)
            self.vis[paths[-1]].set_object(shape, _material("obstacle"))
            self.vis[paths[-1]].set_transform(placement)
        points = np.vstack(self.points)
        middle, margin, thickness = 0.5 * (points.min(axis=0) + points.max(axis=0)), 0.3, 0.01
        for hs in self.s.scene.cell.halfspaces:
            rot = _turn([0.0, 0.0, 1.0], hs.normal)  # plate z = the free side's normal
            on_plane = middle - hs.signed_distance(middle) * hs.normal
            uv = (points - on_plane) @ rot[:, :2]  # in-plane coordinates [m]
            half = np.maximum(0.5 * (uv.max(axis=0) - uv.min(axis=0)) + margin, 0.5)
            center = on_plane + rot[:, :2] @ (0.5 * (uv.max(axis=0) + uv.min(axis=0)))
            paths.append(f"{ROOT}/cell/{_node(hs.name)}")
            node = self.vis[paths[-1]]
            node.set_object(mg.Box([2 * half[0], 2 * half[1], thickness]), _material("halfspace"))
            # on the blocked side, its face 1 mm below the plane
            node.set_transform(_placement(rot, center - (0.5 * thickness + 0.001) * hs.normal))
        return paths

    def tracker_body(self) -> str:
        import meshcat.geometry as mg

        node = self.vis[f"{ROOT}/tracker"]
        node.set_transform(self.tracker.homogeneous)  # children in tracker coordinates
        node["head"].set_object(mg.Cylinder(*TRACKER_SIZE), _material("tracker"))
        node["head"].set_transform(_placement(_turn([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]), np.zeros(3)))
        node["triad"].set_object(mg.triad(0.4))
        return f"{ROOT}/tracker"

    def ellipsoid(self, kpi_path: str, e: ConfidenceEllipsoid, scale: float, eye: np.ndarray,
                  label_width: float) -> str:
        """The ellipsoid scaled by ``scale`` at the TCP, and its text board above it; its node path."""
        import meshcat.geometry as mg

        path = f"{kpi_path}/{ellipsoid_node_name(e.level, scale)}"
        shape = mg.Ellipsoid(scale * e.half_axes)  # a unit sphere stretched along its x, y, z
        self.vis[path].set_object(_on_top_mesh()(shape, _material("ellipsoid", side=0, depthTest=False)))
        self.vis[path].set_transform(_placement(e.axes, e.center))  # axes: right-handed columns
        above = e.center + np.array([0.0, 0.0, scale * e.half_axes[0] + 0.2 * label_width])
        _draw_text(self.vis[f"{kpi_path}/ellipsoid_label"],
                   f"{100 * e.level:g}% ellipsoid \u00d7{scale:g}", label_width, above, eye)
        return path


def nice_length(length: float) -> float:
    """The 1-2-5 number (..., 0.1, 0.2, 0.5, 1, 2, ...) at or below ``length`` > 0."""
    power = 10.0 ** np.floor(np.log10(length))
    return float(f"{power * max(m for m in (1.0, 2.0, 5.0) if m * power <= length * (1 + 1e-9)):.1g}")


def draw_guides(vis, points: np.ndarray, eye: np.ndarray) -> tuple[str, str, float]:
    """World axes at the origin (x red, y green, z blue, labelled "world x", ...) and a scale bar along
    world x at the lower front corner of ``points`` (k, 3) [m], labelled in mm, both
    :func:`nice_length` of a fifth of the scene's extent long; (axes node, bar node, length [m])."""
    import meshcat.geometry as mg

    extent = float(np.ptp(points, axis=0).max())
    length = nice_length(0.2 * extent if extent > 0 else 1.0)
    axes, thick = vis[f"{ROOT}/world_axes"], 0.015 * length
    for k, (name, color) in enumerate(zip("xyz", (0xE02020, 0x20A020, 0x2040E0), strict=True)):
        tip = np.zeros(3)
        tip[k] = length
        size = np.full(3, thick)
        size[k] = length
        axes[name].set_object(mg.Box(size), mg.MeshBasicMaterial(color=color))
        axes[name].set_transform(_placement(np.eye(3), 0.5 * tip))
        _draw_text(axes[f"label_{name}"], f"world {name}", 0.6 * length, tip * 1.15, eye)
    low = points.min(axis=0)
    bar = vis[f"{ROOT}/scale_bar"]
    bar["bar"].set_object(mg.Box([length, 0.01 * length, 0.01 * length]),
                          mg.MeshBasicMaterial(color=0x202020))
    bar["bar"].set_transform(_placement(np.eye(3), low + [0.5 * length, 0.0, 0.0]))
    _draw_text(bar["label"], f"{1e3 * length:g} mm", 1.2 * length,
               low + [0.5 * length, 0.0, 0.15 * length], eye)
    return f"{ROOT}/world_axes", f"{ROOT}/scale_bar", length


def _camera(points: np.ndarray, center: np.ndarray, tracker: np.ndarray, obstacles: np.ndarray) -> np.ndarray:
    """A default camera position, world [m]: above the scene, across the line of sight
    from the tracker, on the side away from the obstacles (k, 3), far enough to see it all."""
    sight = center - tracker
    side = np.array([-sight[1], sight[0], 0.0])
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([1.0, 0.0, 0.0])
    if len(obstacles) and side @ (obstacles.mean(axis=0) - center) > 0:
        side = -side
    direction = (side + [0.0, 0.0, 0.9]) / np.linalg.norm(side + [0.0, 0.0, 0.9])
    radius = float(np.linalg.norm(points - center, axis=1).max())
    return center + direction * radius / np.tan(np.deg2rad(33.0))  # meshcat's field of view: 75°
