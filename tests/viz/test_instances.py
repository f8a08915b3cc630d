"""Mesh reuse (calib_oed.viz.instances): every pose's robot from one copy of its geometry.

The page of a 60-pose UR10 design (example-robot-data meshes) is decoded and
checked: the meshes are in it once per drawn robot copy (design poses share
one), each pose's mesh placements are Pinocchio's geometry placements at that
pose, and the page is within the viewer's budget (before mesh reuse: 175 MB,
and the design poses fell back to capsules).
"""

from __future__ import annotations

from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest
import scipy.spatial
import yaml
from page_commands import by_path, decode_commands

from calib_oed.calibration.workflow import setup
from calib_oed.scene.reader import load_scene, scene_from_dict
from calib_oed.viz import sessions
from calib_oed.viz.draw import MESH_BUDGET_BYTES, _visual_model
from calib_oed.viz.instances import (
    CELLS,
    TRIANGLE_BUDGET,
    RobotInstances,
    cluster_vertices,
    vertex_normals,
)

N_POSES = 60


@pytest.fixture(scope="module")
def ur10():
    """The ur5_table cell with a UR10 (meshes), 60 random poses within the joint limits; its page:
    (setup, poses, page size [bytes], the page's commands, view info, (visual model, bytes per copy, note))."""
    source = load_scene("ur5_table").source
    data = yaml.safe_load(Path(source).read_text())
    data["robot"]["name"] = "ur10"
    s = setup(scene_from_dict(data, source=str(source)))
    robot = s.problem.robot
    q = np.random.default_rng(0).uniform(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi),
                                         (N_POSES, robot.nq))
    html, info = sessions.static_html(s, q)
    return s, q, len(html.encode("utf-8")), decode_commands(html), info, _visual_model(robot)


def _model_matrix(mesh: dict) -> np.ndarray:
    return np.array(mesh["matrix"], dtype=float).reshape(4, 4).T  # three.js: column-major


def test_60_pose_ur10_design_keeps_its_meshes_within_the_page_budget(ur10):
    s, q, size, commands, info, (geom, mesh_bytes, _) = ur10
    print(f"\n60-pose UR10 page: {size / 1e6:.1f} MB (meshes {mesh_bytes / 1e6:.1f} MB per copy; "
          f"budget {MESH_BUDGET_BYTES / 1e6:.0f} MB)")
    assert info.robot_drawing == "visual" and info.n_poses == N_POSES
    assert size < MESH_BUDGET_BYTES
    assert N_POSES * mesh_bytes > 4 * MESH_BUDGET_BYTES  # one copy per pose would not fit at all
    # the triangles of the page: one coarsened copy for the design, one full copy per working
    # configuration (60 full copies, 7 million triangles, took minutes a frame in software WebGL)
    robots = f"/meshcat/{info.robots_path}"

    def triangles(path_test):
        return sum(len(g["data"]["index"]["array"].data) // 12  # uint32 triangle corners
                   for c in commands if c["type"] == "set_object" and path_test(c["path"])
                   for g in c["object"].get("geometries", [])
                   if g["type"] == "BufferGeometry" and "index" in g["data"])

    per_copy = sum(g.geometry.num_tris for g in geom.geometryObjects)
    design = triangles(lambda path: path == robots)
    assert triangles(lambda path: path != robots) == len(s.scene.kpi.configurations) * per_copy
    assert N_POSES * design <= TRIANGLE_BUDGET < N_POSES * per_copy
    (note,) = [n for n in info.notes if "coarsened" in n]
    assert f"{design} triangles per robot instead of {per_copy}" in note


def test_each_pose_is_placed_by_pinocchio(ur10):
    s, q, _, commands, info, (geom, _, _) = ur10
    robots = by_path(commands, "set_object")[f"/meshcat/{info.robots_path}"]["object"]
    model = s.problem.robot.model
    geometries = {g["uuid"]: g for g in robots["geometries"]}
    assert len(geometries) == geom.ngeoms  # each geometry object once
    groups = robots["object"]["children"]
    assert [g["name"] for g in groups] == [f"pose_{k:03d}" for k in range(N_POSES)]
    data, gdata = model.createData(), pin.GeometryData(geom)
    for k in (0, 17, N_POSES - 1):
        pin.forwardKinematics(model, data, q[k])
        pin.updateGeometryPlacements(model, data, geom, gdata)
        meshes = groups[k]["children"]
        assert [m["name"] for m in meshes] == [g.name for g in geom.geometryObjects]
        for g, mesh in enumerate(meshes):
            np.testing.assert_allclose(_model_matrix(mesh), gdata.oMg[g].homogeneous, atol=1e-6)
            points = geometries[mesh["geometry"]]["data"]["attributes"]["position"]["array"].data
            vertices = np.frombuffer(points, dtype=np.float32).reshape(-1, 3)
            full = geom.geometryObjects[g].geometry.vertices()
            reach = np.sqrt(3) * max(CELLS) / np.min(geom.geometryObjects[g].meshScale) + 1e-6
            assert len(vertices) <= len(full)
            assert scipy.spatial.cKDTree(full).query(vertices)[0].max() <= reach  # coarsened, not moved
    assert {g["uuid"] for g in groups[0]["children"]} & {g["uuid"] for g in groups[1]["children"]} == set()
    assert [m["geometry"] for m in groups[0]["children"]] == [m["geometry"] for m in groups[1]["children"]]


def test_primitive_cylinder_axis_follows_the_urdf():
    """A URDF cylinder's axis is its z; meshcat's is y: the drawn y axis is the URDF z in the world."""
    import meshcat.geometry as mg

    model = pin.buildSampleModelManipulator()
    joint = model.njoints - 1
    offset = pin.SE3(pin.utils.rotate("x", 0.4) @ pin.utils.rotate("y", -0.9), np.array([0.01, 0.02, 0.3]))
    geom = pin.GeometryModel()
    geom.addGeometryObject(pin.GeometryObject("stick", joint, 0, offset, coal.Cylinder(0.02, 0.5)))
    q = np.zeros((2, model.nq))
    q[1] = 0.3 + 0.1 * np.arange(model.nq)
    lowered = RobotInstances(model, geom, q, [mg.MeshPhongMaterial(), mg.MeshPhongMaterial()]).lower()
    (cylinder,) = lowered["geometries"]
    assert cylinder["type"] == "CylinderGeometry" and cylinder["height"] == pytest.approx(0.5)  # coal: r, length
    data = model.createData()
    for k, group in enumerate(lowered["object"]["children"]):
        pin.forwardKinematics(model, data, q[k])
        world = data.oMi[joint] * offset
        drawn = _model_matrix(group["children"][0])
        np.testing.assert_allclose(drawn[:3, 1], world.rotation[:, 2], atol=1e-12)  # axis
        np.testing.assert_allclose(drawn[:3, 3], world.translation, atol=1e-12)
    assert lowered["materials"][0]["uuid"] != lowered["materials"][1]["uuid"]  # one per pose


def test_vertex_normals_of_an_octahedron_point_outward():
    """By symmetry, each vertex normal of a regular octahedron is the vertex direction."""
    v = np.vstack([np.eye(3), -np.eye(3), [[0.0, 0.0, 5.0]]])  # the last vertex is in no face
    faces = np.array([[0, 1, 2], [1, 3, 2], [3, 4, 2], [4, 0, 2],
                      [1, 0, 5], [3, 1, 5], [4, 3, 5], [0, 4, 5]])
    n = vertex_normals(v, faces)
    np.testing.assert_allclose(n[:6], v[:6], atol=1e-12)
    np.testing.assert_array_equal(n[6], np.zeros(3))
    # reversed winding: inward
    np.testing.assert_allclose(vertex_normals(v, faces[:, ::-1])[:6], -v[:6], atol=1e-12)


def _icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere of 20 * 4**subdivisions triangles, outward winding."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(sphere.vertices), np.asarray(sphere.faces)


def _area(v: np.ndarray, f: np.ndarray) -> float:
    return 0.5 * float(np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())


@pytest.mark.parametrize("cell", [0.05, 0.1, 0.2])
def test_vertex_clustering_coarsens_a_sphere_and_keeps_its_shape(cell):
    v, f = _icosphere(5)  # 20480 triangles, edges about 0.04
    cv, cf = cluster_vertices(v, f, cell)
    assert len(cf) < len(f) and cf.min() >= 0 and cf.max() == len(cv) - 1
    assert scipy.spatial.cKDTree(v).query(cv)[0].max() <= np.sqrt(3) * cell  # within the cube
    assert np.all((cf[:, 0] != cf[:, 1]) & (cf[:, 1] != cf[:, 2]) & (cf[:, 0] != cf[:, 2]))
    assert len(np.unique(np.sort(cf, axis=1), axis=0)) == len(cf)  # no triangle twice
    assert _area(cv, cf) == pytest.approx(4 * np.pi, rel=0.1)
    # the winding stays outward: the normals' mean projection on the radius is positive
    n = np.cross(cv[cf[:, 1]] - cv[cf[:, 0]], cv[cf[:, 2]] - cv[cf[:, 0]])
    assert np.einsum("ij,ij->i", n, cv[cf].mean(axis=1)).min() > 0


def test_the_meshes_are_coarsened_only_beyond_the_triangle_budget():
    """Below the budget the geometry is the mesh itself; above it the finest cell that fits."""
    import meshcat.geometry as mg

    model = pin.buildSampleModelManipulator()
    geom = pin.GeometryModel()
    v, f = _icosphere(5)
    mesh = coal.BVHModelOBBRSS()
    mesh.beginModel(len(f), len(v))
    points, triangles = coal.StdVec_Vec3s(), coal.StdVec_Triangle()
    points.extend(list(0.1 * v))
    triangles.extend([coal.Triangle(*map(int, tri)) for tri in f])
    mesh.addSubModel(points, triangles)
    mesh.endModel()
    geom.addGeometryObject(pin.GeometryObject("ball", model.njoints - 1, 0, pin.SE3.Identity(), mesh))
    q = np.zeros((3, model.nq))
    materials = [mg.MeshPhongMaterial() for _ in q]
    whole = RobotInstances(model, geom, q, materials, triangle_budget=3 * len(f))
    (g,) = whole.lower()["geometries"]
    assert whole.cell is None and whole.triangles == (len(f), len(f))
    assert len(g["data"]["index"]["array"].data) // 12 == len(f)
    coarse = RobotInstances(model, geom, q, materials, triangle_budget=len(f))
    (g,) = coarse.lower()["geometries"]
    count = len(g["data"]["index"]["array"].data) // 12
    assert coarse.cell in CELLS and coarse.triangles == (count, len(f)) and 3 * count <= len(f)
    finer = [c for c in CELLS if c < coarse.cell]  # the finer cells leave too many
    assert all(3 * len(cluster_vertices(0.1 * v, f, c)[1]) > len(f) for c in finer)
