r"""One copy of a robot's visual geometry, drawn at many poses (mesh reuse).

A design of a robot with meshes repeats the same meshes at every pose: only
the placements differ. meshcat sends each ``set_object`` as one three.js JSON
object, in which a geometry listed once can be used by any number of meshes.
:class:`RobotInstances` is such an object: every geometry of the URDF visual
model once, and below one group per pose (``pose_000``, ``pose_001``, ...)
one mesh per geometry object, placed by

.. math::
    M_{k,g} = T_{W,G_g}(q_k)\,\mathrm{diag}(s_g, 1)\,I_g ,

:math:`T_{W,G_g}(q_k)` the world placement of geometry object :math:`g` at
pose :math:`k` (Pinocchio's ``updateGeometryPlacements``, world = robot base,
[m]), :math:`s_g` its mesh scale and :math:`I_g` meshcat's intrinsic transform
of the primitive (a cylinder's axis is y there). Each pose has its own
material (so that one pose can be drawn solid and the others faint,
:mod:`calib_oed.viz.selector`). The page then grows by a few hundred bytes per
pose instead of the meshes' size (UR10: 2.8 MB per pose).

Meshes get per-vertex normals here (the area-weighted mean of the adjacent
face normals), because meshcat computes them only for a top-level mesh.
"""

from __future__ import annotations

import uuid
import warnings
from collections.abc import Sequence

import coal
import numpy as np
import pinocchio as pin


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    r"""Unit vertex normals (n, 3) of a triangle mesh: :math:`\sum` of the adjacent faces'
    :math:`(v_1 - v_0) \times (v_2 - v_0)` (area-weighted), normalised; zero where undefined."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals = np.zeros_like(v)
    for corner in range(3):
        np.add.at(normals, f[:, corner], cross)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


#: Most triangles of a design's robots together before their meshes are coarsened.
TRIANGLE_BUDGET = 1_000_000
#: Clustering cells tried in turn, finest first [m].
CELLS = (0.002, 0.005, 0.01, 0.02, 0.05)


def cluster_vertices(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    r"""A coarser copy of a triangle mesh by vertex clustering (Rossignac and Borrel, 1993).

    Every vertex moves to the mean of the vertices in its cube of the grid of
    edge ``cell`` (the mesh's own units); triangles whose corners fall into
    fewer than three cubes, and repeated triangles, are dropped. No vertex moves
    by more than :math:`\sqrt{3}\,`\ ``cell``.

    Returns:
        (vertices (m, 3), faces (k, 3)): the coarse mesh, faces indexing its vertices.
    """
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    keys = np.floor((v - v.min(axis=0)) / cell).astype(np.int64)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.reshape(-1)
    merged = np.zeros((len(counts), 3))
    np.add.at(merged, cluster, v)
    merged /= counts[:, None]
    g = cluster[f]
    g = g[(g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])]
    start = np.argmin(g, axis=1)[:, None]  # corners rolled to start at the least: one key per triangle
    rolled = np.take_along_axis(g, (start + np.arange(3)) % 3, axis=1)
    _, first = np.unique(rolled, axis=0, return_index=True)
    g = g[np.sort(first)]
    used, g = np.unique(g, return_inverse=True)
    return merged[used], g.reshape(-1, 3)


def _meshcat_geometry(geometry_object: pin.GeometryObject):
    """meshcat geometry of a Pinocchio geometry object (Pinocchio's own conversion), or None."""
    from pinocchio.visualize import meshcat_visualizer as pmv

    geom = geometry_object.geometry
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if isinstance(geom, coal.ShapeBase):
            return pmv.loadPrimitive(geometry_object)
        if isinstance(geom, coal.BVHModelBase):
            return pmv.loadMesh(geom)
    return None


def _lower_geometry(geometry, data: dict) -> str:
    """Add ``geometry`` to the object's geometry list (with normals if a triangle mesh); its uuid."""
    import meshcat.geometry as mg

    lowered = geometry.lower(data)
    if isinstance(geometry, mg.TriangularMeshGeometry):
        normals = vertex_normals(geometry.vertices, geometry.faces).astype(np.float32)
        lowered["data"]["attributes"]["normal"] = mg.pack_numpy_array(normals.T)
    data["geometries"].append(lowered)
    return geometry.uuid


def _matrix(homogeneous: np.ndarray) -> list[float]:
    """A 4×4 matrix as three.js reads it (column-major)."""
    return [float(x) for x in np.asarray(homogeneous, dtype=float).flatten(order="F")]


class RobotInstances:
    """A meshcat object: the robot's visual geometry once, a group of meshes per pose.

    Args:
        model: The robot's Pinocchio model.
        geom: Its visual geometry model (meshes already loaded by coal).
        configurations: Poses (n, nq) [rad, or m for prismatic joints].
        materials: One meshcat material per pose.
        visible: Whether each pose's group is shown (default: all).
        triangle_budget: Most triangles of all poses together; above it the meshes are
            coarsened (:func:`cluster_vertices`) with the finest cell of :data:`CELLS`
            that keeps within it (software WebGL draws a 60-pose UR10, 7 million
            triangles, in about a minute a frame; docs/benchmarks.md, issue 34).

    Attributes:
        names: Group name of each pose (``pose_000``, ...).
        skipped: Geometry objects meshcat cannot draw (left out).
        cell: The clustering cell after :meth:`lower` [m], or None (the meshes as they are).
        triangles: Triangles of one pose's robot (after coarsening), and before it.
    """

    def __init__(self, model: pin.Model, geom: pin.GeometryModel, configurations: np.ndarray,
                 materials: Sequence, visible: Sequence[bool] | None = None,
                 triangle_budget: int = TRIANGLE_BUDGET):
        if len(materials) != len(configurations):
            raise ValueError(f"one material per pose: {len(materials)} for {len(configurations)} poses")
        self.uuid = str(uuid.uuid1())
        self.model, self.geom = model, geom
        self.q = np.asarray(configurations, dtype=float)
        self.materials = list(materials)
        self.visible = [True] * len(self.q) if visible is None else [bool(v) for v in visible]
        self.names = tuple(f"pose_{k:03d}" for k in range(len(self.q)))
        self.skipped: list[str] = []
        self.triangle_budget = int(triangle_budget)
        self.cell: float | None = None
        self.triangles = (0, 0)

    def _shapes(self) -> list[tuple[int, object]]:
        """(geometry object index, meshcat geometry), coarsened to the triangle budget."""
        shapes = []
        for g, obj in enumerate(self.geom.geometryObjects):
            shape = _meshcat_geometry(obj)
            if shape is None:
                self.skipped.append(obj.name)
            else:
                shapes.append((g, shape))
        meshes = [k for k, (_, shape) in enumerate(shapes) if hasattr(shape, "faces")]
        full = sum(len(shapes[k][1].faces) for k in meshes)
        self.triangles = (full, full)
        if full * len(self.q) <= self.triangle_budget:
            return shapes
        import meshcat.geometry as mg

        for cell in CELLS:  # the finest that keeps within the budget, else the coarsest
            coarse = dict(shapes)
            for k in meshes:
                g, shape = shapes[k]
                scale = float(np.min(self.geom.geometryObjects[g].meshScale))
                v, f = cluster_vertices(shape.vertices, shape.faces, cell / scale)
                coarse[g] = mg.TriangularMeshGeometry(v.astype(shape.vertices.dtype), f.astype(shape.faces.dtype))
            count = sum(len(coarse[shapes[k][0]].faces) for k in meshes)
            if count * len(self.q) <= self.triangle_budget:
                break
        self.cell, self.triangles = cell, (count, full)
        return list(coarse.items())

    def lower(self) -> dict:
        """The three.js JSON object (meshcat's ``set_object`` payload)."""
        data: dict = {"metadata": {"version": 4.5, "type": "Object"}, "geometries": [], "materials": []}
        shapes = []  # (geometry object index, geometry uuid, intrinsic transform)
        for g, shape in self._shapes():
            obj = self.geom.geometryObjects[g]
            intrinsic = np.diag([*obj.meshScale, 1.0]) @ shape.intrinsic_transform()
            shapes.append((g, _lower_geometry(shape, data), intrinsic))
        material_ids = [m.lower_in_object(data) for m in self.materials]
        pin_data, geom_data = self.model.createData(), pin.GeometryData(self.geom)
        groups = []
        for name, q, material, shown in zip(self.names, self.q, material_ids, self.visible, strict=True):
            pin.forwardKinematics(self.model, pin_data, q)
            pin.updateGeometryPlacements(self.model, pin_data, self.geom, geom_data)
            meshes = [{"uuid": str(uuid.uuid1()), "type": "Mesh", "name": self.geom.geometryObjects[g].name,
                       "geometry": gid, "material": material,
                       "matrix": _matrix(geom_data.oMg[g].homogeneous @ intrinsic)}
                      for g, gid, intrinsic in shapes]
            groups.append({"uuid": str(uuid.uuid1()), "type": "Group", "name": name, "visible": shown,
                           "children": meshes})
        data["object"] = {"uuid": self.uuid, "type": "Group", "name": "robots", "children": groups}
        return data


class _SetObject:
    """meshcat's ``set_object`` command for an object that is not a ``meshcat.geometry.Object``."""

    def __init__(self, obj, path):
        self.obj, self.path = obj, path

    def lower(self) -> dict:
        return {"type": "set_object", "object": self.obj.lower(), "path": self.path.lower()}


def draw_instances(node, instances: RobotInstances) -> None:
    """Send ``instances`` as the object of meshcat node ``node`` (``vis[path]``), one command."""
    node.window.send(_SetObject(instances, node.path))
