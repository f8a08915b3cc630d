"""Plots: what is drawn equals what is computed independently here; atomic figure files."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest
import scipy.stats

from calib_oed.calibration.confidence import ConfidenceEllipsoid
from calib_oed.calibration.workflow import (
    heuristic_design,
    identify_measurements,
    setup,
    simulated_measurements,
)
from calib_oed.exceptions import ExportError, NonFiniteError, ShapeError, UnknownCriterionError
from calib_oed.oed.objective import DesignObjective
from calib_oed.scene.reader import load_scene
from calib_oed.viz import design_plots, plots

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def kr16(kr16_setup):
    """The session's fms_kr16 set-up (one reflector, one working configuration; tests/conftest.py)
    and a 30-pose design."""
    return kr16_setup, heuristic_design(kr16_setup, 30, 0)


@pytest.fixture(scope="module")
def identified(kr16):
    s, q = kr16
    mset, _ = simulated_measurements(s, q, 1)
    return s, mset, identify_measurements(s, mset)


def _line(ax, gid):
    lines = [ln for ln in ax.get_lines() if ln.get_gid() == gid]
    assert len(lines) == 1, f"expected one line {gid!r}, found {len(lines)}"
    return lines[0]


def _direct_f1(s, q):
    """Unit-scaled weighted sensitivity on the free parameters per pose, (n, 3, n_f), from F_1."""
    problem = s.problem
    assert len(problem.models) == 1  # rows of F_1 are then pose-major, 3 per pose
    free = problem.identifiability.free_indices
    f1 = problem.weighted_jacobian(q)[:, free] * problem.space.unit_scale[free]
    return f1.reshape(len(q), 3, -1)


# ------------------------------------------------------------- ellipses
def test_kpi_ellipse_extents_are_the_marginal_95_percent_intervals(kr16):
    """Half-extent along axis k of a plane = sqrt(chi2_2(0.95) C_kk) [mm], centred at 0."""
    s, q = kr16
    designs = {"30 poses": q, "15 poses": q[:15]}
    fig = plots.plot_kpi_ellipsoids(s.problem, designs)
    r2 = scipy.stats.chi2.ppf(0.95, 2)
    assert [ax.get_title() for ax in fig.axes] == [
        f"{p} plane: marginal 95% region" for p in ("xy", "xz", "yz")]
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    for name, qd in designs.items():
        c = s.problem.kpi_covariance(qd)[:3, :3]  # [m^2]
        sigma_mm = np.sqrt(np.trace(c) / 3) * 1e3
        assert f"{name}: \u03c3 = {sigma_mm:#.3g} mm" in legend
        for ax, (i, j) in zip(fig.axes, [(0, 1), (0, 2), (1, 2)], strict=True):
            line = _line(ax, name)
            x, y = line.get_xdata(), line.get_ydata()
            for data, k in ((x, i), (y, j)):
                half = np.sqrt(r2 * c[k, k]) * 1e3
                assert (data.max() - data.min()) / 2 == pytest.approx(half, rel=1e-4)
                assert abs(data.max() + data.min()) < 1e-9 * half
    # fewer poses, larger region
    xy = fig.axes[0]
    assert np.ptp(_line(xy, "15 poses").get_xdata()) > np.ptp(_line(xy, "30 poses").get_xdata())
    # a Design-like record with .q and another level: the same covariance, scaled radius
    fig90 = plots.plot_kpi_ellipsoids(s, {"30 poses": types.SimpleNamespace(q=q)}, level=0.9)
    ratio = np.sqrt(scipy.stats.chi2.ppf(0.9, 2) / r2)
    assert np.allclose(_line(fig90.axes[0], "30 poses").get_xdata(),
                       ratio * _line(xy, "30 poses").get_xdata(), rtol=1e-10, atol=1e-15)


def test_kpi_ellipsoids_need_a_design(kr16):
    s, _ = kr16
    with pytest.raises(ValueError, match="at least one"):
        plots.plot_kpi_ellipsoids(s.problem, {})


def _tick_label_gaps(fig) -> list[float]:
    """Per panel, the smallest horizontal gap [pixels] between neighbouring x tick labels
    shown inside the axis (negative: two labels overlap), after a real Agg draw."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    renderer = fig.canvas.get_renderer()
    gaps = []
    for ax in fig.axes:
        lo, hi = sorted(ax.get_xlim())
        shown = [t for t in ax.get_xticklabels() if t.get_visible() and t.get_text()
                 and lo <= t.get_position()[0] <= hi]
        boxes = sorted((t.get_window_extent(renderer) for t in shown), key=lambda b: b.x0)
        assert len(boxes) >= 3, [t.get_text() for t in shown]  # a readable axis: >= 3 labels
        gaps.append(min(b.x0 - a.x1 for a, b in zip(boxes[:-1], boxes[1:], strict=True)))
    return gaps


# sigma = 33 um isotropic made matplotlib's automatic ticks overlap by ~5 px in all
# three panels (issue 21); the others are elongated variants and other magnitudes
@pytest.mark.parametrize(("sigma", "stretch"), [
    (3.3e-5, (1, 1, 1)), (3.3e-5, (1, 1, 3)), (3.3e-5, (2, 1, 1)), (1.2e-5, (1, 2, 1)),
    (2e-4, (1, 1, 1)), (4.4e-6, (5, 1, 1)),
])
def test_ellipse_tick_labels_do_not_overlap(sigma, stretch):
    cov = np.diag((sigma * np.array(stretch, dtype=float)) ** 2)
    fig = plots._ellipse_figure(  # the panels of plot_kpi_ellipsoids, on given covariances
        [plots._Curve(n, n, f"C{k}", ConfidenceEllipsoid(np.zeros(3), c, 0.95, n))
         for k, (n, c) in enumerate((("a", cov), ("b", 0.5 * cov)))], 0.95, "ticks", "design")
    gaps = _tick_label_gaps(fig)
    assert min(gaps) > 2.0, gaps


def _scene_with_kpi(**kpi):
    """fms_kr16 with its KPI section changed (and a second working configuration)."""
    import copy
    from pathlib import Path

    import yaml

    from calib_oed.scene.reader import scene_from_dict

    source = load_scene("fms_kr16").source
    data = yaml.safe_load(Path(source).read_text())
    data["kpi"] = {k: v for k, v in copy.deepcopy(data["kpi"]).items() if k != "point"} | kpi
    data["kpi"]["working_configurations"].append({"name": "car_low", "q": [-9, -60, 110, -38, -30, 0]})
    return setup(scene_from_dict(data, source=str(source)))


def test_kpi_plot_names_the_kpi_and_frame_and_draws_every_point(kr16):
    _, q = kr16
    s = _scene_with_kpi(frame="tracker", reflector="smr0")
    designs = {"30 poses": q, "20 poses": q[:20]}
    fig = plots.plot_kpi_ellipsoids(s, designs)
    title = fig.get_suptitle()
    assert "centre of reflector 'smr0', tracker frame" in title and "car_side, car_low" in title
    assert "TCP" not in title and "world" not in title
    assert _title_fits(fig)
    r2 = scipy.stats.chi2.ppf(0.95, 2)
    names = s.problem.kpi.names
    assert names == ("car_side", "car_low")
    for ax, (i, j) in zip(fig.axes, [(0, 1), (0, 2), (1, 2)], strict=True):
        drawn = {ln.get_gid() for ln in ax.get_lines() if ln.get_gid()}
        assert drawn == {f"{d} @ {w}" for d in designs for w in names}  # one line per design and point
        for d, qd in designs.items():
            c_s = s.problem.kpi_covariance(qd)  # tracker frame [m^2]
            for k, w in enumerate(names):
                c = c_s[3 * k : 3 * k + 3, 3 * k : 3 * k + 3]
                line = _line(ax, f"{d} @ {w}")
                for data, axis in ((line.get_xdata(), i), (line.get_ydata(), j)):
                    assert np.ptp(data) / 2 == pytest.approx(np.sqrt(r2 * c[axis, axis]) * 1e3, rel=1e-4)
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    sigma = np.sqrt(np.trace(s.problem.kpi_covariance(q)) / 6) * 1e3  # RMS over the 2 points
    assert legend[0] == f"30 poses: \u03c3 = {sigma:#.3g} mm (RMS over 2 points)" and len(legend) == 2
    # a problem without its scene numbers the reflector
    bare = plots.plot_kpi_ellipsoids(s.problem, designs)
    assert "centre of reflector 0, tracker frame, at car_side, car_low" in bare.get_suptitle()


def _title_fits(fig) -> bool:
    """Whether the figure title, drawn by Agg, lies within the figure (not clipped)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    box, page = fig._suptitle.get_window_extent(), fig.bbox
    return page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1


def test_kpi_plot_title_fits_for_many_points(kr16):
    """Thirty working configurations with long names: the title lists three and the count."""
    _, q = kr16
    s = _scene_with_kpi(working_configurations=[
        {"name": f"gauge_point_on_the_side_{k:02d}", "q": [-9, -73 + k, 104, -38, -13, 0]} for k in range(29)])
    fig = plots.plot_kpi_ellipsoids(s, {"30 poses": q})
    title = fig.get_suptitle()
    assert "gauge_point_on_the_side_02, \u2026 (30 points)" in title and "gauge_point_on_the_side_03" not in title
    assert _title_fits(fig), title
    assert len({ln.get_gid() for ln in fig.axes[0].get_lines() if ln.get_gid()}) == 30


def test_kpi_description_of_a_tool_point(kr16):
    s = _scene_with_kpi(point=[0, 0, 120])
    assert plots.kpi_description(s.problem.kpi) == "tool point (0, 0, 120) mm, world frame"
    assert plots.kpi_description(kr16[0].problem.kpi) == "TCP position, world frame"


# --------------------------------------------------- pose contributions
def test_leave_one_out_matches_a_direct_recomputation(kr16):
    """phi(M without pose i)/phi(M) - 1 from F_1 and numpy's inverse, for kpi and params."""
    s, q = kr16
    f = _direct_f1(s, q)
    free = s.problem.identifiability.free_indices
    g = s.problem.kpi_jacobian()[:, free] * s.problem.space.unit_scale[free] * 1e3  # [mm/mm, mm/mrad]

    def kpi(rows):
        c = np.linalg.inv(rows.T @ rows)
        return np.trace(g @ c @ g.T) / g.shape[0]

    def params(rows):
        return np.trace(np.linalg.inv(rows.T @ rows)) / rows.shape[1]

    full = f.reshape(-1, f.shape[-1])
    for name, phi in (("kpi", kpi), ("params", params)):
        loo = design_plots.pose_contributions(s.problem, q, name)
        assert loo.shape == (len(q),)
        assert np.all(loo >= 0.0)  # removing a pose never helps an A-criterion
        for i in (0, 7, 29):
            rest = np.delete(f, i, axis=0).reshape(-1, f.shape[-1])
            assert loo[i] == pytest.approx(phi(rest) / phi(full) - 1.0, rel=1e-8)
    # a DesignObjective's own criterion is used when none is given
    obj = DesignObjective(s.problem, "params")
    assert np.allclose(design_plots.pose_contributions(obj, q), design_plots.pose_contributions(s, q, "params"),
                       rtol=1e-12)


def test_sensitivities_obey_the_equivalence_theorem(kr16):
    """Sum of -dlogQ/dw_i is 1 for A and n_f for D; leave-one-out >= sensitivity >= 0 (convexity)."""
    s, q = kr16
    n_f = len(s.problem.identifiability.free_indices)
    f = _direct_f1(s, q)
    c = np.linalg.inv(np.einsum("jdf,jdg->fg", f, f))
    leverage = np.einsum("jdf,fg,jdg->j", f, c, f)  # tr(F_i C F_i^T)
    for name, total in (("kpi", 1.0), ("params", 1.0), ("D", n_f)):
        sens = design_plots.pose_contributions(s.problem, q, name, kind="sensitivity")
        loo = design_plots.pose_contributions(s.problem, q, name)
        assert sens.sum() == pytest.approx(total, rel=1e-8)
        assert np.all(sens >= 0.0)
        assert np.all(loo >= sens * (1 - 1e-10))
        if name == "D":  # det C ratio 1/det(I - F_i C F_i^T); first order: the leverage
            assert np.allclose(sens, leverage, rtol=1e-8)
            i = 3
            ratio = 1.0 / np.linalg.det(np.eye(3) - f[i] @ c @ f[i].T)
            assert loo[i] == pytest.approx(ratio - 1.0, rel=1e-7)
    with pytest.raises(ValueError, match="'leave_one_out', 'sensitivity'"):
        design_plots.pose_contributions(s.problem, q, kind="gradient")
    with pytest.raises(UnknownCriterionError, match="'kpi'"):
        design_plots.pose_contributions(s.problem, q, "A-optimal")


def test_pose_contribution_bars_show_the_values(kr16):
    s, q = kr16
    loo = design_plots.pose_contributions(s.problem, q)
    sens = design_plots.pose_contributions(s.problem, q, kind="sensitivity")
    ax = design_plots.plot_pose_contributions(s.problem, q).axes[0]
    bars = [p for p in ax.patches if (p.get_gid() or "").startswith("pose ")]
    assert [b.get_gid() for b in bars] == [f"pose {i}" for i in range(len(q))]
    assert np.allclose([b.get_height() for b in bars], 100.0 * loo, rtol=1e-12)
    assert np.allclose(_line(ax, "sensitivity").get_ydata(), 100.0 * sens, rtol=1e-12)
    assert "[%]" in ax.get_ylabel()
    assert [t.get_text() for t in ax.get_xticklabels()] == [str(i) for i in range(len(q))]


def test_an_indispensable_pose_contributes_infinity(kr16):
    """9 poses give 27 rows for 25 free parameters: without any one of them M is singular."""
    s, q = kr16
    q9 = q[:9]
    assert np.isfinite(DesignObjective(s.problem).compute_value(q9))
    assert np.all(np.isinf(design_plots.pose_contributions(s.problem, q9)))
    sens = design_plots.pose_contributions(s.problem, q9, kind="sensitivity")
    ax = design_plots.plot_pose_contributions(s.problem, q9).axes[0]
    bars = [p for p in ax.patches if (p.get_gid() or "").startswith("pose ")]
    heights = {b.get_height() for b in bars}
    assert len(heights) == 1 and heights.pop() > 100.0 * sens.max()  # drawn above every finite value
    assert sum(t.get_text() == "\u221e" for t in ax.texts) == 9


# ------------------------------------------------------------ residuals
def test_residual_plot_counts_every_component(identified):
    s, mset, res = identified
    fig = plots.plot_residuals(res)
    scatter, hist = fig.axes[0], fig.axes[-1]
    assert len(fig.axes) == 2  # position data: no rotation panel
    counts = [p.get_height() for p in hist.patches]
    assert sum(counts) == res.residuals.size == 90
    width = hist.patches[0].get_width()
    normal = _line(hist, "normal")
    peak = normal.get_ydata()[np.argmin(np.abs(normal.get_xdata()))]
    assert peak == pytest.approx(90 * width * scipy.stats.norm.pdf(0.0), rel=1e-4)
    pos_mm = res.block_residuals[0] * 1e3
    xs = [ln for ln in scatter.get_lines() if ln.get_label() in ("x", "y", "z")]
    for c, ln in enumerate(xs):
        assert np.array_equal(ln.get_xdata(), np.arange(30))
        assert np.allclose(ln.get_ydata(), pos_mm[:, c], rtol=1e-12)
    assert all(ln.get_gid() != "outliers" for ln in scatter.get_lines())


def test_pose_residuals_get_a_rotation_panel(kr16):
    s, q = kr16
    # 6-D probe rows: the tracker error model and repeatability are position-only (the scene
    # reader refuses them with measurement: pose), so the isotropic sigma and sigma_angle
    scene = s.scene
    s6 = setup(dataclasses.replace(scene, measurement="pose", repeatability=0.0,
                                   tracker=dataclasses.replace(scene.tracker, noise=None)))
    mset, _ = simulated_measurements(s6, q[:20], 2)
    res = identify_measurements(s6, mset)
    fig = plots.plot_residuals(res)
    assert len(fig.axes) == 3 and "[mrad]" in fig.axes[1].get_ylabel()
    rot = [ln for ln in fig.axes[1].get_lines() if ln.get_label() in ("x", "y", "z")]
    assert np.allclose(np.stack([ln.get_ydata() for ln in rot], axis=1),
                       res.block_residuals[0][:, 3:] * 1e3, rtol=1e-12)
    assert sum(p.get_height() for p in fig.axes[-1].patches) == res.residuals.size == 120


def test_residual_plot_marks_outliers(identified):
    """2 mm added to measurements 4 and 17: circled there; clipped values still counted."""
    s, mset, _ = identified
    pos = np.array(mset.positions)
    pos[[4, 17]] += 2e-3 / np.sqrt(3)
    from calib_oed.calibration.robust import identify_robust

    rob = identify_robust(s.problem.space, dataclasses.replace(mset, positions=pos).blocks(
        error_model=s.scene.error_model()), s.problem.identifiability, model_error=s.scene.discrepancy())
    assert np.flatnonzero(rob.flagged).tolist() == [4, 17]  # the report's rule
    res = rob.linear  # (the plain fit's residuals, flags of the report's rule)
    fig = plots.plot_residuals(res, [(0, 4), (0, 17)], "noise + model error", ["smr0"])
    marks = _line(fig.axes[0], "outliers")
    assert marks.get_label() == "flagged (noise + model error): 2"
    assert sorted(set(marks.get_xdata())) == [4, 17]
    assert np.allclose(sorted(marks.get_ydata()),
                       np.sort(res.block_residuals[0][[4, 17]].ravel() * 1e3))
    hist = fig.axes[-1]
    assert sum(p.get_height() for p in hist.patches) == res.residuals.size
    assert np.abs(res.residuals).max() > plots.HISTOGRAM_LIMIT  # some were clipped into the edge bins


# ------------------------------------------------------- study figure
def test_improvement_plot_marks_mean_and_median():
    rng = np.random.default_rng(5)
    data = {"vs heuristic": rng.normal(68.0, 6.0, 200), "vs C_p-optimal": rng.gamma(9.0, 5.0, 150)}
    fig = design_plots.plot_improvement_distribution(data, xlabel="improvement [%]")
    ax = fig.axes[0]
    for name, v in data.items():
        assert np.allclose(_line(ax, f"{name}: mean").get_xdata(), np.mean(v), rtol=1e-14)
        assert np.allclose(_line(ax, f"{name}: median").get_xdata(), np.median(v), rtol=1e-14)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert f"vs heuristic (N = 200): mean {np.mean(data['vs heuristic']):.1f} %, " \
           f"median {np.median(data['vs heuristic']):.1f} %" in labels
    assert ax.get_xlabel() == "improvement [%]"
    with pytest.raises(ShapeError):
        design_plots.plot_improvement_distribution({"a": []})
    with pytest.raises(NonFiniteError):
        design_plots.plot_improvement_distribution({"a": [1.0, np.nan]})


# ----------------------------------------------------------- save_figure
@pytest.fixture(scope="module")
def small_figure():
    return design_plots.plot_improvement_distribution({"vs heuristic": [10.0, 20.0, 25.0, 40.0]})


def test_save_figure_writes_png_svg_pdf(tmp_path, small_figure):
    out = plots.save_figure(small_figure, tmp_path / "fig.png")
    assert out == tmp_path / "fig.png" and out.read_bytes()[:8] == PNG_MAGIC
    assert b"<svg" in plots.save_figure(small_figure, tmp_path / "fig.svg").read_bytes()[:500]
    assert plots.save_figure(small_figure, str(tmp_path / "FIG.PDF")).read_bytes()[:5] == b"%PDF-"
    # the figure stays usable, and overwriting replaces the file
    assert plots.save_figure(small_figure, tmp_path / "fig.png").read_bytes()[:8] == PNG_MAGIC
    assert sorted(p.name for p in tmp_path.iterdir()) == ["FIG.PDF", "fig.png", "fig.svg"]


def test_save_figure_refuses_unknown_suffix_and_leaves_nothing(tmp_path, small_figure):
    with pytest.raises(ExportError, match=r"'\.jpg'.*'\.png', '\.svg', '\.pdf'"):
        plots.save_figure(small_figure, tmp_path / "fig.jpg")
    with pytest.raises(ExportError, match="no suffix"):
        plots.save_figure(small_figure, tmp_path / "fig")
    with pytest.raises(ExportError, match="does not exist"):
        plots.save_figure(small_figure, tmp_path / "missing" / "fig.png")
    assert list(tmp_path.iterdir()) == []


def test_failed_render_leaves_no_partial_file(tmp_path, small_figure, monkeypatch):
    target = tmp_path / "fig.png"
    target.write_bytes(b"old")

    def broken(fh, **kwargs):
        fh.write(PNG_MAGIC + b"half a picture")
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(small_figure, "savefig", broken)
    with pytest.raises(RuntimeError, match="renderer crashed"):
        plots.save_figure(small_figure, target)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["fig.png"]


def test_no_pyplot_figures_are_left_open(kr16):
    import matplotlib.pyplot as plt

    s, q = kr16
    before = plt.get_fignums()
    plots.plot_kpi_ellipsoids(s.problem, {"h": q})
    design_plots.plot_pose_contributions(s.problem, q[:12])
    assert plt.get_fignums() == before
