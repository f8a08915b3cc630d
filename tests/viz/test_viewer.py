"""The meshcat inspection view (calib_oed.viz.viewer, calib_oed.viz.sessions).

What the page contains is read back from the written static HTML itself: each
drawing command is a base64 msgpack blob there, decoded here with umsgpack
and checked against quantities computed independently (Pinocchio forward
kinematics, numpy eigh and scipy's chi2 on ``problem.kpi_covariance``). The
page is then rendered in headless Chromium and compared with an empty meshcat
page, pixel by pixel.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import scipy.stats
import yaml
from page_commands import by_path, decode_commands, transform  # tests/viz/page_commands.py

from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.exceptions import (
    ConfidenceLevelError,
    ExportError,
    NonFiniteError,
    ShapeError,
    ViewerSettingError,
)
from calib_oed.scene.reader import load_scene, scene_from_dict
from calib_oed.viz import sessions, viewer
from calib_oed.viz.draw import color_int, nice_length

N_POSES = 10  # the fewest round numbers of poses that determine fms_kr16's KPI (25 free parameters)
CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-extensions", "--hide-scrollbars", "--mute-audio",
    # WebGL without a GPU: SwiftShader (without the opt-in flag Chromium warns that
    # its automatic software fallback is deprecated)
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--window-size=1024,768", "--virtual-time-budget=5000",
)
#: For a probe that reads the page's scene graph, not its pixels: every frame of the virtual time
#: budget is drawn by SwiftShader, and a small window draws it several times faster (the program
#: page's animation probe: 42 s at 1024 x 768, 7 s at 320 x 240).
PROBE_FLAGS = (*CHROMIUM_FLAGS, "--window-size=320,240")


# ------------------------------------------------------------------ helpers
def meshcat_children() -> list[int]:
    """Child processes of this test process running a meshcat server."""
    me, found = os.getpid(), []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            cmd = (entry / "cmdline").read_bytes()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == me and b"meshcat.servers.zmqserver" in cmd:
            found.append(int(entry.name))
    return found


def tool_point(s, q: np.ndarray, point: np.ndarray) -> np.ndarray:
    """A point fixed in the tool frame, in the world, by Pinocchio forward kinematics [m]."""
    robot = s.problem.robot
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return data.oMf[robot.tool_frame_id].act(np.asarray(point, dtype=float))


# ----------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def s(kr16_setup):
    return kr16_setup  # the session's fms_kr16 set-up (tests/conftest.py)


@pytest.fixture(scope="module")
def design(s):
    return heuristic_design(s, N_POSES, seed=0)


@pytest.fixture(scope="module")
def page(s, design, tmp_path_factory):
    """The static page of the design, written once: (path, info, html, commands)."""
    assert not meshcat_children()
    path = tmp_path_factory.mktemp("view") / "scene.html"
    written = sessions.write_static_html(path, s, design)
    html = path.read_text(encoding="utf-8")
    return written.path, written.info, html, decode_commands(html)


# ------------------------------------------------------- (a) scene content
def test_page_has_a_node_for_every_element(s, design, page):
    path, info, html, commands = page
    assert path.is_file() and info.n_poses == N_POSES
    objects = by_path(commands, "set_object")
    root = f"/meshcat/{viewer.ROOT}"

    def under(prefix: str) -> list[str]:
        return [p for p in objects if p.startswith(f"/meshcat/{prefix}/")]

    assert len(info.pose_paths) == N_POSES
    # every pose's URDF visual geometry (kr16: primitives) in one node: geometries once
    assert info.robots_path == f"{viewer.ROOT}/design/robots" and not any("/robot/" in p for p in under(
        f"{viewer.ROOT}/design"))
    robots = objects[f"/meshcat/{info.robots_path}"]["object"]
    assert [g["name"] for g in robots["object"]["children"]] == [p.rsplit("/", 1)[1] for p in info.pose_paths]
    for pose in info.pose_paths:
        assert under(f"{pose}/capsules"), pose
        assert f"/meshcat/{pose}/reflectors/smr0" in objects
        assert f"/meshcat/{pose}/beams" in objects
    assert info.beam_paths == tuple(f"{p}/beams" for p in info.pose_paths + info.kpi_paths)
    assert info.kpi_paths == (f"{viewer.ROOT}/kpi/car_side",)
    assert under(f"{info.kpi_paths[0]}/robot/visuals")
    assert {f"{root}/tracker/head", f"{root}/tracker/triad"} <= set(objects)
    names = {"car_body", "car_cabin", "tracker_stand", "floor", "wall"}
    assert {p.rsplit("/", 1)[1] for p in info.obstacle_paths} == names
    for capsule in ("car_body", "car_cabin", "tracker_stand"):
        assert {f"{root}/cell/{capsule}/{part}" for part in ("body", "end_a", "end_b")} <= set(objects)
    assert {f"{root}/cell/floor", f"{root}/cell/wall"} <= set(objects)
    # design-pose capsules are hidden (toggle in the page), the KPI pose's are shown
    visible = {c["path"]: c["value"] for c in commands
               if c["type"] == "set_property" and c["property"] == "visible"}
    assert visible[f"/meshcat/{info.pose_paths[0]}/capsules"] is False
    assert visible[f"/meshcat/{info.kpi_paths[0]}/capsules"] is True
    # the page opens on pose 0: its beams and reflectors shown, the others' hidden
    for k, p in enumerate(info.pose_paths):
        assert visible[f"/meshcat/{p}/beams"] is (k == 0) and visible[f"/meshcat/{p}/reflectors"] is (k == 0)
    # KPI pose in its own colour; design pose 0 solid, the others faint (ghosts)
    kpi = [c for p, c in objects.items() if p.startswith(f"/meshcat/{info.kpi_paths[0]}/robot/visuals/")]
    assert {c["object"]["materials"][0]["color"] for c in kpi} == {color_int("kpi")}
    materials = {m["uuid"]: m for m in robots["materials"]}
    opacity = [{materials[m["material"]]["opacity"] for m in g["children"]} for g in robots["object"]["children"]]
    assert opacity == [{1.0}] + [{viewer.COLORS["ghost"][3]}] * (N_POSES - 1)
    first = materials[robots["object"]["children"][0]["children"][0]["material"]]
    assert first["color"] == color_int("selected") and first["transparent"] is False


def test_beams_join_the_tracker_and_the_reflector_of_each_pose(s, design, page):
    _, info, _, commands = page
    objects = by_path(commands, "set_object")
    tracker = s.scene.tracker.placement().translation
    offset = s.scene.reflectors[0].offset
    poses = list(design) + [w.q for w in s.scene.kpi.configurations]
    for beam, q in zip(info.beam_paths, poses, strict=True):
        geometry = objects[f"/meshcat/{beam}"]["object"]["geometries"][0]
        raw = geometry["data"]["attributes"]["position"]["array"]  # float32, (3, 2) column-major
        ends = np.frombuffer(raw.data, dtype=np.float32).reshape(2, 3)
        np.testing.assert_allclose(ends[0], tool_point(s, q, offset), atol=1e-6)
        np.testing.assert_allclose(ends[1], tracker, atol=1e-6)


def test_tracker_pose_and_scene_shift(s, page):
    _, info, _, commands = page
    transforms = by_path(commands, "set_transform")
    np.testing.assert_allclose(transform(transforms[f"/meshcat/{info.tracker_path}"]),
                               s.scene.tracker.placement().homogeneous, atol=1e-12)
    shift = transform(transforms[f"/meshcat/{viewer.ROOT}"])
    np.testing.assert_allclose(shift[:3, 3], -info.center)
    np.testing.assert_allclose(shift[:3, :3], np.eye(3))


def test_ellipsoid_is_the_95_percent_region_of_the_kpi_covariance(s, design, page):
    _, info, _, commands = page
    # independent computation: eigh of the 3x3 block, chi2 quantile with 3 dof
    cov = s.problem.kpi_covariance(design)[:3, :3]
    eigenvalues = np.linalg.eigh(cov)[0][::-1]
    r2 = scipy.stats.chi2.ppf(0.95, df=3)
    half_axes = np.sqrt(r2 * eigenvalues)
    np.testing.assert_allclose(info.half_axes_mm[0], half_axes * 1e3, rtol=1e-9)
    (e,) = info.ellipsoids
    scale = info.ellipsoid_scale
    assert e.scale == scale
    mantissa = scale / 10 ** np.floor(np.log10(scale))
    assert np.isclose(mantissa, [1, 2, 5]).any()
    assert 0.025 <= scale * half_axes[0] <= 0.1  # the largest drawn half-axis is about 50 mm
    # the drawing: Ellipsoid = unit sphere with intrinsic diag(radii), placed by set_transform
    name = f"ellipsoid_95pct_x{scale:g}"
    path = f"/meshcat/{info.kpi_paths[0]}/{name}"
    assert e.path == f"{info.kpi_paths[0]}/{name}"
    obj = by_path(commands, "set_object")[path]["object"]
    assert obj["geometries"][0]["type"] == "SphereGeometry" and obj["geometries"][0]["radius"] == 1.0
    radii = np.diag(np.array(obj["object"]["matrix"]).reshape(4, 4))[:3]
    placement = transform(by_path(commands, "set_transform")[path])
    rotation = placement[:3, :3]
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    shape = rotation @ np.diag(radii**2) @ rotation.T  # drawn = {x : x^T shape^-1 x <= 1}
    np.testing.assert_allclose(shape, scale**2 * r2 * cov, rtol=1e-9, atol=1e-12 * scale**2 * r2 * cov.max())
    np.testing.assert_allclose(placement[:3, 3], tool_point(s, s.scene.kpi.q[0], np.zeros(3)), atol=1e-12)
    # the scale is also written in the scene, on the label's text texture
    label = by_path(commands, "set_object")[f"/meshcat/{info.kpi_paths[0]}/ellipsoid_label/text"]
    (texture,) = label["object"]["textures"]
    assert texture["type"] == "_text" and texture["text"] == f"95% ellipsoid \u00d7{scale:g}"


def test_given_scale_and_level_are_used(s, design):
    with sessions.open_viewer(s, design, ellipsoid_scale=1000, level=0.99, selector=False) as live:
        info = live.info
    assert info.ellipsoid_scale == 1000.0 and info.level == 0.99
    assert info.ellipsoids[0].path.endswith("/ellipsoid_99pct_x1000")
    r2 = scipy.stats.chi2.ppf(0.99, df=3)
    eigenvalues = np.linalg.eigh(s.problem.kpi_covariance(design)[:3, :3])[0][::-1]
    np.testing.assert_allclose(info.half_axes_mm[0], np.sqrt(r2 * eigenvalues) * 1e3, rtol=1e-9)
    assert not info.selector and not meshcat_children()


def test_selector_is_sent_with_the_pose_labels(s, design, page):
    _, info, _, commands = page
    (control,) = [c for c in commands if c["type"] == "set_control"]
    assert control["path"] == f"/meshcat/{viewer.ROOT}/design/selector" and control["name"] == "pose"
    assert (control["value"], control["min"], control["max"], control["step"]) == (0, -1, N_POSES - 1, 1)
    assert info.selector and len(info.labels) == N_POSES
    degrees = ", ".join(f"{v:.1f}" for v in np.degrees(design[3]))  # kr16: six revolute joints
    assert info.labels[3] == f"pose 3 (feasible): q = ({degrees}) deg"
    assert all(label in control["callback"] for label in info.labels)
    # the world axes and the scale bar: a 1-2-5 length, written on its label in mm
    objects, transforms = by_path(commands, "set_object"), by_path(commands, "set_transform")
    length = info.scale_bar_length
    for k, a in enumerate("xyz"):  # a bar from the world origin along each axis, labelled
        size = objects[f"/meshcat/{info.axes_path}/{a}"]["object"]["geometries"][0]
        assert [size["width"], size["height"], size["depth"]][k] == pytest.approx(length)
        np.testing.assert_allclose(transform(transforms[f"/meshcat/{info.axes_path}/{a}"])[:3, 3],
                                   0.5 * length * np.eye(3)[k])
        (text,) = objects[f"/meshcat/{info.axes_path}/label_{a}/text"]["object"]["textures"]
        assert text["text"] == f"world {a}"
    mantissa = length / 10 ** np.floor(np.log10(length))
    assert np.isclose(mantissa, [1, 2, 5]).any()
    (texture,) = objects[f"/meshcat/{info.scale_bar_path}/label/text"]["object"]["textures"]
    assert texture["text"] == f"{1e3 * length:g} mm"
    bar = objects[f"/meshcat/{info.scale_bar_path}/bar"]["object"]["geometries"][0]
    assert bar["type"] == "BoxGeometry" and bar["width"] == pytest.approx(length)


def test_ellipsoid_in_the_world_for_a_tracker_frame_kpi(s, design):
    data = yaml.safe_load(Path(s.scene.source).read_text())
    data["kpi"]["frame"] = "tracker"
    s_tracker = setup(scene_from_dict(data, source=str(s.scene.source)))
    (e,) = viewer.world_ellipsoids(s_tracker, design)
    np.testing.assert_allclose(e.center, tool_point(s, s.scene.kpi.q[0], np.zeros(3)), atol=1e-12)
    rot = s.scene.tracker.placement().rotation
    cov_tracker = s_tracker.problem.kpi_covariance(design)[:3, :3]
    np.testing.assert_allclose(e.covariance, rot @ cov_tracker @ rot.T, rtol=1e-9,
                               atol=1e-12 * cov_tracker.max())


def test_scene_without_a_determined_kpi_is_drawn_without_ellipsoid(s, design):
    q = design[:3].copy()
    q[2] = s.problem.robot.upper + 0.05  # beyond the joint limits: infeasible
    with sessions.open_viewer(s, q) as live:
        info = live.info
        assert live.url.startswith("http://127.0.0.1:")
        assert len(meshcat_children()) == 1
    assert not meshcat_children()  # close() stopped the server
    assert info.n_poses == 3 and info.ellipsoids == () and info.ellipsoid_scale is None
    assert any("no KPI ellipsoid" in n and "not identifiable" in n for n in info.notes)
    assert info.infeasible_poses == (2,) and "1 infeasible [2]" in info.summary()
    with sessions.open_viewer(s, None) as live:
        assert live.info.n_poses == 0 and live.info.ellipsoids == () and live.info.kpi_paths


def test_capsule_drawing_and_first_pose_only(s, design):
    html, info = sessions.static_html(s, design[:3], robot_drawing="capsules", ghosts=False, selector=False)
    commands = decode_commands(html)
    paths = set(by_path(commands, "set_object"))
    assert info.robot_drawing == "capsules" and not info.selector and info.robots_path is None
    assert not any("/robot/" in p or p.endswith("/robots") for p in paths)  # no URDF geometry anywhere
    assert not any(c["type"] == "set_control" for c in commands)
    visible = {c["path"]: c["value"] for c in commands
               if c["type"] == "set_property" and c["property"] == "visible"}
    assert [visible[f"/meshcat/{p}"] for p in info.pose_paths] == [True, False, False]
    assert all(visible[f"/meshcat/{p}/capsules"] is True for p in info.pose_paths + info.kpi_paths)
    # pose 0 (the page opens on it) solid, the others faint
    objects = by_path(commands, "set_object")
    first, second = (objects[f"/meshcat/{p}/capsules/link_2_0/body"]["object"]["materials"][0]
                     for p in info.pose_paths[:2])
    assert (first["opacity"], first["color"]) == (1.0, color_int("selected"))
    assert (second["opacity"], second["color"]) == (viewer.COLORS["ghost"][3], color_int("ghost"))
    assert not meshcat_children()


def test_nice_length_is_the_1_2_5_number_at_or_below():
    assert [nice_length(x) for x in (0.7, 1.0, 3.0, 0.19, 0.0999, 12.0)] == [0.5, 1.0, 2.0, 0.1, 0.05, 10.0]


def test_display_scale_is_a_1_2_5_number():
    assert viewer.display_scale(1e-4, 0.05) == 500.0
    assert viewer.display_scale(0.05, 0.05) == 1.0
    assert viewer.display_scale(3e-5, 0.05) == 2000.0
    assert viewer.display_scale(0.2, 0.05) == 0.2


# ------------------------------------------------------------ (b) bad input
@pytest.mark.parametrize(("kwargs", "error", "needle"), [
    ({"ellipsoid_scale": 0.0}, ViewerSettingError, "ellipsoid_scale"),
    ({"ellipsoid_scale": -2.0}, ViewerSettingError, "must be a finite number > 0"),
    ({"ellipsoid_scale": float("nan")}, ViewerSettingError, "ellipsoid_scale"),
    ({"ellipsoid_scale": "big"}, ViewerSettingError, "ellipsoid_scale"),
    ({"target_half_axis": 0.0}, ViewerSettingError, "target_half_axis"),
    ({"level": 1.5}, ConfidenceLevelError, "strictly between 0 and 1"),
    ({"robot_drawing": "meshes"}, ViewerSettingError, "'auto', 'visual', 'capsules'"),
])
def test_bad_settings_are_refused_before_drawing(s, design, kwargs, error, needle):
    with pytest.raises(error, match=re.escape(needle)):
        viewer.build_view(None, s, design, **kwargs)  # vis=None: nothing may be drawn first


@pytest.mark.parametrize(("q", "error", "needle"), [
    (np.zeros((3, 5)), ShapeError, "(n, 6) or (6,)"),
    (np.zeros((2, 3, 6)), ShapeError, "q_design"),
    (np.zeros((0, 6)), ShapeError, "n >= 1"),
    (np.full((2, 6), np.nan), NonFiniteError, "q_design"),
])
def test_bad_designs_are_refused(s, q, error, needle):
    with pytest.raises(error, match=re.escape(needle)):
        viewer.build_view(None, s, q)


def test_bad_design_writes_nothing_and_stops_the_server(s, tmp_path):
    target = tmp_path / "view.html"
    with pytest.raises(ShapeError):
        sessions.write_static_html(target, s, np.zeros((2, 7)))
    assert list(tmp_path.iterdir()) == [] and not meshcat_children()


# ------------------------------------------- (c) offline page, atomic write
def test_page_is_self_contained(page):
    _, _, html, commands = page
    assert html.lstrip().startswith("<!DOCTYPE html>")
    assert "MeshCat.Viewer" in html and len(commands) > 100
    # nothing the browser would load from elsewhere
    assert not re.search(r"<(script|img|iframe|link|source|embed|object)\b[^>]*\b(src|href|data)\s*=", html, re.I)
    assert not re.search(r"url\(\s*['\"]?\s*(https?:)?//", html, re.I)
    assert not re.search(r"@import", html)
    # the only absolute URL is the XHTML namespace name (an identifier, never fetched)
    assert set(re.findall(r"https?://[^\s\"'`)<>]*", html)) <= {"http://www.w3.org/1999/xhtml"}
    # no fetch() at all: the commands are replayed from one inline list (sessions.inline_commands)
    assert "fetch(" not in html.split("var viewer = new MeshCat.Viewer", 1)[1]
    assert html.count(sessions.COMMANDS_BEGIN) == 1 and html.count(sessions.COMMANDS_END) == 1


def test_page_is_written_atomically(s, design, tmp_path, monkeypatch):
    target = tmp_path / "view.html"
    target.write_text("previous page")

    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr("calib_oed.io.atomic.os.replace", fail)
    with pytest.raises((OSError, ExportError), match="disk full"):
        sessions.write_static_html(target, s, design[:2], selector=False)
    assert target.read_text() == "previous page"  # untouched, no temporary left behind
    assert [p.name for p in tmp_path.iterdir()] == ["view.html"]
    assert not meshcat_children()
    with pytest.raises(ExportError, match="does not exist"):
        sessions.write_static_html(tmp_path / "missing" / "view.html", s, design[:2], selector=False)


def test_page_leaves_no_temporary_and_no_server(page):
    path, *_ = page
    assert [p.name for p in path.parent.iterdir()] == [path.name]
    assert not meshcat_children()


# --------------------------------------------------- (d) headless Chromium
def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return "/usr/bin/chromium" if os.access("/usr/bin/chromium", os.X_OK) else None


@pytest.fixture(scope="module")
def chromium():
    exe = find_chromium()
    if exe is None:
        reason = ("!!! CHROMIUM NOT FOUND: the meshcat page was NOT rendered; install Debian's "
                  "chromium (apt-get install chromium; .ci/run installs it and fails without it) !!!")
        if os.environ.get("CALIB_OED_REQUIRE_CHROMIUM"):
            pytest.fail(reason)
        warnings.warn(reason, stacklevel=1)
        pytest.skip(reason)
    return exe


def screenshot(exe: str, html: Path, png: Path) -> np.ndarray:
    """Render a page in headless Chromium; the screenshot as (768, 1024, 3) uint8."""
    from PIL import Image

    profile = png.parent / f"{png.stem}-profile"
    cmd = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--screenshot={png}", html.as_uri()]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)  # SwiftShader on a loaded machine
    assert png.is_file(), f"chromium wrote no screenshot (exit {run.returncode}):\n{run.stderr[-2000:]}"
    with Image.open(png) as im:
        return np.asarray(im.convert("RGB"))


def empty_meshcat_page() -> str:
    """meshcat's static page of a visualizer with nothing added."""
    import meshcat

    with contextlib.redirect_stdout(io.StringIO()):
        vis = meshcat.Visualizer()
    proc = vis.window.server_proc
    try:
        return vis.static_html()
    finally:
        vis.window.zmq_socket.close(linger=0)
        proc.kill()
        proc.wait(timeout=10)
        proc.stdout.close()
        proc.stderr.close()


def test_page_renders_in_headless_chromium(chromium, page, tmp_path):
    path, info, _, _ = page
    empty_html = tmp_path / "empty.html"
    empty_html.write_text(empty_meshcat_page(), encoding="utf-8")
    empty = screenshot(chromium, empty_html, tmp_path / "empty.png")
    scene = screenshot(chromium, path, tmp_path / "scene.png")
    shutil.copy(tmp_path / "scene.png", path.with_suffix(".png"))  # kept for a look (pytest's tmp)
    assert scene.shape == empty.shape == (768, 1024, 3)
    # the empty page itself rendered WebGL: its sky gradient spans many colours
    assert len(np.unique(empty.reshape(-1, 3), axis=0)) > 50, "WebGL did not render the empty page"
    changed = np.abs(scene.astype(int) - empty.astype(int)).max(axis=2) > 24
    colours = len(np.unique(scene.reshape(-1, 3), axis=0))
    print(f"\nscreenshot: {changed.sum()} of {changed.size} pixels differ from the empty page "
          f"({changed.mean():.1%}), {colours} distinct colours")
    assert changed.mean() > 0.10  # the scene covers much of the view
    assert colours > 2000
    # each element in its own colour, counted only where the scene differs from the empty
    # page rendered by the same Chromium (whose sky, grid and axis lines vary by version)
    in_scene = colour_counts(scene, changed)
    print(f"pixels by colour where the scene differs from the empty page: {in_scene}")
    for name, least in (("ellipsoid", 20), ("kpi_robot", 500), ("beams", 100)):
        assert in_scene[name] >= least, (name, in_scene)


def colour_counts(image: np.ndarray, where: np.ndarray) -> dict[str, int]:
    """Pixels among ``where`` of the colours of the ellipsoid (magenta), KPI robot (green)
    and beams (red)."""
    r, g, b = (image[..., i].astype(int) for i in range(3))
    masks = {
        "ellipsoid": (r > 170) & (g < 90) & (b > 150),
        "kpi_robot": (g > r + 60) & (g > b + 30),
        "beams": (r > 170) & (g < 70) & (b < 70),
    }
    return {name: int((mask & where).sum()) for name, mask in masks.items()}


@pytest.mark.slow  # 1-4 min of software WebGL on a shared 2-core machine; timed by bench/bench_viewer_page.py
def test_60_pose_mesh_page_loads_and_renders_in_headless_chromium(chromium, tmp_path):
    """The page of bench/bench_viewer_page.py (a 60-pose UR10 design, meshes) loads in headless
    Chromium and draws: the design robots (coarsened meshes, docs/benchmarks.md) and the selected
    pose solid in its colour. Before issue 34 this page did not finish loading within 600 s."""
    scene = Path(__file__).resolve().parents[2] / "bench" / "scenes" / "ur10_cell.yaml"
    s60 = setup(load_scene(str(scene)))
    written = sessions.write_static_html(tmp_path / "ur10_60.html", s60, heuristic_design(s60, 60, seed=0))
    assert written.info.robot_drawing == "visual" and written.info.n_poses == 60
    empty_html = tmp_path / "empty.html"
    empty_html.write_text(empty_meshcat_page(), encoding="utf-8")
    empty = screenshot(chromium, empty_html, tmp_path / "empty.png")
    image = screenshot(chromium, written.path, tmp_path / "ur10_60.png")
    changed = np.abs(image.astype(int) - empty.astype(int)).max(axis=2) > 24
    assert changed.mean() > 0.10 and len(np.unique(image.reshape(-1, 3), axis=0)) > 2000
    r, g, b = (image[..., i].astype(int) for i in range(3))
    # the selected pose, solid (0.15, 0.35, 0.85): deep blue, far bluer than the faint design
    # poses (0.55, 0.65, 0.85 at opacity 0.35) and the sky
    solid = (b - r > 130) & (b - g > 80)
    assert (solid & changed).sum() >= 100, "the selected pose is not drawn solid in its colour"


#: Run in the page after it loaded: press keys and click the pose list like a user, and
#: after each action read the three.js scene itself (robot groups' material opacity and
#: colour, beam nodes' visibility), the selector's panel and meshcat's pose slider.
PROBE = r"""<script>
setTimeout(() => {
  const find = (path) => {
    let t = viewer.scene_tree;
    for (const p of path) { t = t.children[p]; if (t === undefined) return null; }
    return t;
  };
  const design = ["meshcat", "calib_oed", "design"];
  const state = () => {
    const groups = find(design.concat(["robots", "<object>"])).object.children;
    const materials = groups.map((g) => { const m = []; g.traverse((o) => { if (o.material) m.push(o.material); }); return m; });
    return {
      opacity: materials.map((m) => [...new Set(m.map((x) => x.opacity))]),
      color: materials.map((m) => [...new Set(m.map((x) => x.color.getHex()))]),
      beams: groups.map((g) => find(design.concat([g.name, "beams"])).object.visible),
      head: document.getElementById("calib-oed-pose-current").textContent,
      marked: [...document.querySelectorAll("#calib-oed-poses li")].map((li) => li.style.background !== ""),
      slider: viewer.gui_controllers.pose.getValue(),
    };
  };
  const key = (k) => window.dispatchEvent(new KeyboardEvent("keydown", {key: k, bubbles: true}));
  const out = {opened: state()};
  key("ArrowRight"); out.right = state();
  document.querySelectorAll("#calib-oed-poses li")[5].click(); out.click5 = state();
  key("a"); out.all = state();
  key("ArrowLeft"); out.left_from_all = state();
  const pre = document.createElement("pre");
  pre.id = "probe";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
}, 3000);
</script>"""


def test_pose_selector_works_in_headless_chromium(chromium, page, tmp_path):
    path, info, html, _ = page
    probed = tmp_path / "probed.html"
    probed.write_text(html.replace("</body>", PROBE + "</body>"), encoding="utf-8")
    cmd = [chromium, *PROBE_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", probed.as_uri()]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)  # SwiftShader on a loaded machine
    found = re.search(r'<pre id="probe">(.*?)</pre>', run.stdout, re.S)
    assert found, f"the probe did not run (exit {run.returncode}):\n{run.stderr[-2000:]}"
    states = json.loads(found.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    faint, solid = viewer.COLORS["ghost"][3], color_int("selected")
    for action, selected in (("opened", 0), ("right", 1), ("click5", 5), ("all", -1),
                             ("left_from_all", N_POSES - 1)):
        state = states[action]
        assert state["slider"] == selected, action
        assert state["opacity"] == [[1] if k == selected else [faint] for k in range(N_POSES)], action
        assert state["color"] == [[solid] if k == selected else [color_int("ghost")]
                                  for k in range(N_POSES)], action
        assert state["beams"] == [selected in (-1, k) for k in range(N_POSES)], action
        assert state["marked"] == [k == selected for k in range(N_POSES)], action
        assert state["head"] == (info.labels[selected] if selected >= 0 else f"all {N_POSES} poses"), action


def test_pose_selector_reaches_the_live_viewer(chromium, s, design, tmp_path):
    """The live page (meshcat's server) gets the selector too: it replays the control."""
    with sessions.open_viewer(s, design) as live:
        cmd = [chromium, *PROBE_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", live.url]
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)  # SwiftShader on a loaded machine
        labels = live.info.labels
    head = re.search(r'<div id="calib-oed-pose-current"[^>]*>(.*?)</div>', run.stdout)
    assert head, f"no pose selector in the live page (exit {run.returncode}):\n{run.stderr[-2000:]}"
    assert head.group(1) == labels[0]
    items = re.search(r'<div id="calib-oed-poses".*?<ol[^>]*>(.*?)</ol>', run.stdout, re.S).group(1)
    assert re.findall(r'<li [^>]*title="([^"]*)"', items) == list(labels)
    assert not meshcat_children()


def test_each_pose_carries_its_number_and_reflector_axis(s, design, page):
    """Issue 34: with the selected pose's reflectors, its label (the pose number, placed at
    its own reflector) and the reflector axis (the tool-frame normal in the world)."""
    _, info, _, commands = page
    objects, transforms = by_path(commands, "set_object"), by_path(commands, "set_transform")
    robot = s.problem.robot
    data = robot.model.createData()
    positions = []
    for k, path in enumerate(info.pose_paths):
        (text,) = objects[f"/meshcat/{path}/reflectors/label/text"]["object"]["textures"]
        assert text["text"] == f"pose {k}"
        positions.append(transform(transforms[f"/meshcat/{path}/reflectors/label/text"])[:3, 3])
        pin.framesForwardKinematics(robot.model, data, design[k])
        tool = data.oMf[robot.tool_frame_id]
        axis = objects[f"/meshcat/{path}/reflectors/axes"]["object"]["geometries"][0]
        raw = axis["data"]["attributes"]["position"]["array"]  # float32 (3, 2), as the beams
        ends = np.frombuffer(raw.data, dtype=np.float32).reshape(2, 3)
        np.testing.assert_allclose(ends[1] - ends[0], 0.08 * tool.rotation @ s.scene.reflectors[0].normal,
                                   atol=1e-6)
        np.testing.assert_allclose(ends[0], tool.act(s.scene.reflectors[0].offset), atol=1e-6)
    gaps = [np.linalg.norm(a - b) for i, a in enumerate(positions) for b in positions[i + 1:]]
    assert min(gaps) > 0.01  # every label at its own place


def test_inlined_commands_are_meshcats_in_the_same_order():
    """sessions.inline_commands: the blobs of meshcat's fetch() calls, each once and in page order,
    in one list; a page without such calls is left as it is."""
    import base64

    import umsgpack

    blobs = [base64.b64encode(umsgpack.packb({"type": "set_property", "path": f"/n{k}", "value": k})).decode()
             for k in range(3)]
    fetches = "".join(f'fetch("data:application/octet-binary;base64,{b}")\n    .then(res => res.arrayBuffer())\n'
                      "    .then(buffer => viewer.handle_command_bytearray(new Uint8Array(buffer)));\n    \n"
                      for b in blobs)
    page = f"<script>\nvar viewer = new MeshCat.Viewer(pane);\n{fetches}</script>\n<style>x</style>"
    inlined = sessions.inline_commands(page)
    assert "fetch(" not in inlined and inlined.endswith("</script>\n<style>x</style>")
    assert [c["value"] for c in decode_commands(inlined)] == [0, 1, 2]
    assert decode_commands(inlined) == decode_commands(page)  # the helper reads both forms
    assert sessions.inline_commands("<p>no commands</p>") == "<p>no commands</p>"
