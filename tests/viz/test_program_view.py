"""The measurement program in the viewer (calib_oed.viz.program_view) and the cell's solids.

The page's commands are decoded (tests/viz/page_commands.py) and the animation's
keys compared with Pinocchio's geometry placements at the program's targets;
headless Chromium then seeks the animation in the page (three.js) to the
arrival times and reads the robot's node placements back.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from page_commands import by_path, decode_commands, transform  # tests/viz/page_commands.py
from test_viewer import PROBE_FLAGS, find_chromium  # tests/viz/test_viewer.py

from calib_oed.cli import EXIT_OK, main
from calib_oed.exceptions import ProgramError
from calib_oed.program.csv_format import read_program_csv
from calib_oed.program.settings import ProgramSettings
from calib_oed.program.timing import JointDynamics
from calib_oed.viz.draw import _visual_model
from calib_oed.viz.program_view import FPS, check_program

ROOT = "/meshcat/calib_oed/program"


#: Solids added to fms_kr16's cell, far from the robot and the tracker (mm, deg).
SOLIDS = {
    "boxes": [{"name": "crate", "center": [-3000, 0, 400], "size": [1000, 600, 800], "rpy": [0, 0, 30]}],
    "cylinders": [{"name": "column", "center": [0, -3500, 1000], "radius": 150, "length": 2000,
                   "rpy": [90, 0, 0]}],
    "spheres": [{"name": "ball", "center": [0, 3500, 500], "radius": 100}],
    "meshes": [{"name": "fixture", "file": "octa.obj", "scale": [200, 100, 100], "xyz": [-3000, 2500, 300]}],
}
#: An octahedron of half-diagonal 1 (file units), as OBJ text.
OCTA_OBJ = "\n".join(
    [f"v {x} {y} {z}" for x, y, z in np.vstack([np.eye(3), -np.eye(3)]).astype(int)]
    + ["f 1 2 3", "f 2 4 3", "f 4 5 3", "f 5 1 3", "f 2 1 6", "f 4 2 6", "f 5 4 6", "f 1 5 6"]) + "\n"


@pytest.fixture(scope="module")
def made(kr16_scene, kr16_poses, tmp_path_factory):
    """A 6-pose program of fms_kr16 written by ``calib-oed program``, one via point added to its CSV
    (the midpoint of the second move), shown by ``calib-oed view --program --html`` in fms_kr16
    with :data:`SOLIDS` added: (targets read back, view JSON, page, commands, design file)."""
    folder = tmp_path_factory.mktemp("program")
    robot = kr16_scene.robot
    design = folder / "design.csv"
    np.savetxt(design, kr16_poses[:6], delimiter=",", header=",".join(robot.joint_names), comments="")
    prog = folder / "prog"
    assert main(["program", "fms_kr16", str(design), "--format", "csv", "-o", str(prog), "--quiet"]) == EXIT_OK
    (csv_file,) = prog.glob("*.csv")
    lines = csv_file.read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if ln.startswith("step,")) + 1
    a, b = (np.array(lines[first + i].split(","), dtype=object) for i in (1, 2))
    via = a.copy()
    via[1:4] = ["via", "", "0.00"]
    via[4:] = [f"{0.5 * (float(x) + float(y)):.10f}" for x, y in zip(a[4:], b[4:], strict=True)]
    csv_file.write_text("\n".join(lines[:first + 2] + [",".join(via)] + lines[first + 2:]) + "\n")
    (folder / "octa.obj").write_text(OCTA_OBJ)
    data = yaml.safe_load(Path(kr16_scene.source).read_text())
    data["cell"].update(SOLIDS)
    (folder / "scene.yaml").write_text(yaml.safe_dump(data))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["view", str(folder / "scene.yaml"), str(design), "--program", str(prog),
                     "--html", str(folder / "page.html"), "--json"]) == EXIT_OK
    html = (folder / "page.html").read_text(encoding="utf-8")
    targets = read_program_csv(prog, robot.joint_names)
    return targets, json.loads(out.getvalue()), html, decode_commands(html), design


def _expected_placements(robot, q):
    """Pinocchio's world placements of the URDF visual geometry at ``q``, by node name."""
    geom, _, _ = _visual_model(robot)
    model = robot.model
    data, gdata = model.createData(), pin.GeometryData(geom)
    pin.forwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geom, gdata)
    return {re.sub(r"[^A-Za-z0-9_.+-]", "_", o.name): gdata.oMg[g] for g, o in enumerate(geom.geometryObjects)}


def _arrivals(robot, targets) -> np.ndarray:
    """When the robot reaches each target [s]: PTP move times of the URDF limits, 0.5 s held at poses."""
    dyn = JointDynamics.from_robot(robot, ProgramSettings())
    moves = dyn.move_time(targets.q[:-1], targets.q[1:])
    held = 0.5 * np.array([k == "pose" for k in targets.kinds[1:]])
    return np.concatenate([[0.0], np.cumsum(moves + held) - held])


def _animated(commands) -> dict[str, dict]:
    (anim,) = [c for c in commands if c["type"] == "set_animation"]
    return {a["path"]: a["clip"] for a in anim["animations"]}


def test_animation_moves_the_robot_through_every_target_in_order(kr16_scene, made):
    targets, out, _, commands, _ = made
    robot = kr16_scene.robot
    clips = _animated(commands)
    objects = by_path(commands, "set_object")
    geom, _, _ = _visual_model(robot)
    assert set(clips) == {f"{ROOT}/robot/visuals/{n}" for n in _expected_placements(robot, targets.q[0])}
    assert set(clips) <= set(objects)
    assert targets.kinds.count("via") == 1
    assert out["program"] == {"targets": len(targets.kinds), "poses": 6, "via_points": 1,
                              "animation_s": pytest.approx(_arrivals(robot, targets)[-1])}
    arrivals = _arrivals(robot, targets)
    for path, clip in clips.items():
        name = path.rsplit("/", 1)[1]
        assert clip["fps"] == FPS
        tracks = {t["name"]: t["keys"] for t in clip["tracks"]}
        times = np.array([key["time"] for key in tracks[".position"]]) / FPS
        assert np.all(np.diff(times) >= 0) and times[-1] == pytest.approx(arrivals[-1])
        assert np.diff(times).max() <= 0.5 + 1e-9  # keys 0.1 s apart in moves, 0.5 s holds
        for k in range(len(targets.kinds)):  # at each arrival the robot is at the target
            i = int(np.argmin(np.abs(times - arrivals[k])))
            assert times[i] == pytest.approx(arrivals[k], abs=1e-9)
            want = _expected_placements(robot, targets.q[k])[name]
            x, y, z, w = tracks[".quaternion"][i]["value"]
            assert np.allclose(tracks[".position"][i]["value"], want.translation, atol=1e-9), (name, k)
            assert np.allclose(pin.Quaternion(w, x, y, z).toRotationMatrix(), want.rotation, atol=1e-9)


def test_tcp_path_via_point_and_the_animation_length(kr16_scene, made):
    targets, out, _, commands, design = made
    objects, transforms = by_path(commands, "set_object"), by_path(commands, "set_transform")
    robot = kr16_scene.robot
    data = robot.model.createData()
    (k,) = [i for i, kind in enumerate(targets.kinds) if kind == "via"]
    pin.framesForwardKinematics(robot.model, data, targets.q[k])
    assert np.allclose(transform(transforms[f"{ROOT}/via/1"])[:3, 3], data.oMf[robot.tool_frame_id].translation)
    assert f"{ROOT}/tcp_path" in objects
    # without the added via point: the program's estimated travel time, 0.5 s instead of each dwell
    header = [ln for ln in targets.path.read_text().splitlines() if "estimated cycle" in ln]
    cycle = float(re.search(r"cycle time ([\d.]+) s", header[0]).group(1))
    keep = np.array([kind != "via" for kind in targets.kinds])
    direct = targets._replace(kinds=tuple(np.array(targets.kinds)[keep]), q=targets.q[keep])
    assert _arrivals(robot, direct)[-1] == pytest.approx(cycle - 6 * 2.0 + 6 * 0.5, abs=0.06)


def test_program_of_another_design_or_without_csv_is_refused(kr16_scene, kr16_poses, made, tmp_path):
    targets = made[0]
    robot = kr16_scene.robot
    check_program(robot, targets, kr16_poses[:6])  # its own design
    with pytest.raises(ProgramError, match="pose .* differs from the design's row"):
        check_program(robot, targets, kr16_poses[:6][::-1])
    with pytest.raises(ProgramError, match="0 CSV files"):
        read_program_csv(tmp_path, robot.joint_names)


def test_cell_solids_are_drawn(made):
    commands = made[3]
    objects, transforms = by_path(commands, "set_object"), by_path(commands, "set_transform")
    cell = "/meshcat/calib_oed/cell"
    for name in ("crate", "column", "fixture", "floor", "wall", "car_body"):
        assert any(p.startswith(f"{cell}/{name}") for p in objects), name
    # box: its size, and the corner (+h) placed at R h + c (rpy 30 deg about z)
    geometry = objects[f"{cell}/crate"]["object"]["geometries"][0]
    assert [geometry[k] for k in ("width", "height", "depth")] == pytest.approx([1.0, 0.6, 0.8])
    rz = pin.rpy.rpyToMatrix(0, 0, np.deg2rad(30))
    corner = transform(transforms[f"{cell}/crate"]) @ [0.5, 0.3, 0.4, 1.0]
    assert corner[:3] == pytest.approx(rz @ [0.5, 0.3, 0.4] + [-3.0, 0.0, 0.4])
    # cylinder: meshcat's axis (y) along the cylinder's own z, turned by roll 90 deg to world -y
    geometry = objects[f"{cell}/column"]["object"]["geometries"][0]
    assert (geometry["radiusTop"], geometry["height"]) == pytest.approx((0.15, 2.0))
    placed = transform(transforms[f"{cell}/column"])
    assert np.allclose(placed[:3, 1], [0.0, -1.0, 0.0], atol=1e-12) and np.allclose(placed[:3, 3], [0, -3.5, 1])
    # sphere: a capsule of zero length (its two end spheres)
    assert {f"{cell}/ball/end_a", f"{cell}/ball/end_b"} <= set(objects)
    # mesh: its convex hull, outward faces, volume of the octahedron 4/3 a b c
    attrs = objects[f"{cell}/fixture"]["object"]["geometries"][0]["data"]
    v = np.frombuffer(attrs["attributes"]["position"]["array"].data, dtype=np.float32).reshape(-1, 3)
    f = np.frombuffer(attrs["index"]["array"].data, dtype=np.uint32).reshape(-1, 3)
    volume = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0
    assert volume == pytest.approx(4.0 / 3.0 * 0.2 * 0.1 * 0.1, rel=1e-5)
    assert v.min(axis=0) == pytest.approx([-3.2, 2.4, 0.2]) and v.max(axis=0) == pytest.approx([-2.8, 2.6, 0.4])
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", normals, v[f].mean(axis=1) - v.mean(axis=0)) > 0)


# ------------------------------------------------------------ headless Chromium
#: Pause the animation, seek it to given times and read the animated nodes' placements (three.js).
PROBE = r"""<script>
setTimeout(() => {
  const animator = viewer.animator;
  animator.pause();
  const out = {duration: animator.duration, at: []};
  for (const t of TIMES) {
    animator.seek(t);
    const nodes = {};
    for (const path of PATHS) {
      const o = viewer.scene_tree.find(path.split("/").filter((x) => x)).object;
      nodes[path] = {p: o.position.toArray(), q: o.quaternion.toArray()};
    }
    out.at.push(nodes);
  }
  const pre = document.createElement("pre");
  pre.id = "probe";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
}, 3000);
</script>"""


def test_animation_plays_in_headless_chromium(kr16_scene, made, tmp_path):
    exe = find_chromium()
    if exe is None:
        warnings.warn("!!! CHROMIUM NOT FOUND: the program animation was NOT run in a browser !!!", stacklevel=1)
        pytest.skip("chromium not found")
    targets, _, html, commands, _ = made
    robot = kr16_scene.robot
    arrivals = _arrivals(robot, targets)
    picks = [1, 2, 4, len(targets.kinds) - 1]  # a pose, the via point, a pose, home at the end
    times = [float(arrivals[k]) for k in picks]
    paths = sorted(_animated(commands))
    probe = PROBE.replace("TIMES", json.dumps(times)).replace("PATHS", json.dumps(paths))
    page = tmp_path / "probed.html"
    page.write_text(html.replace("</body>", probe + "</body>"), encoding="utf-8")
    cmd = [exe, *PROBE_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", page.as_uri()]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    found = re.search(r'<pre id="probe">(.*?)</pre>', run.stdout, re.S)
    assert found, f"the probe did not run (exit {run.returncode}):\n{run.stderr[-2000:]}"
    out = json.loads(found.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert out["duration"] == pytest.approx(arrivals[-1], abs=1e-5)
    for k, nodes in zip(picks, out["at"], strict=True):
        want = _expected_placements(robot, targets.q[k])
        for path, got in nodes.items():
            x, y, z, w = got["q"]
            name = path.rsplit("/", 1)[1]
            assert np.allclose(got["p"], want[name].translation, atol=1e-5), (k, name)
            assert np.allclose(pin.Quaternion(w, x, y, z).toRotationMatrix(), want[name].rotation, atol=1e-5)
