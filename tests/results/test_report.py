"""The HTML report from a synthetic calibration (no images): one embedded plotly.js, no
network, every figure and table there, and the figures' data consistent with the
calibration statistics and the depth check they illustrate."""

from __future__ import annotations

import html

import dataclasses
import functools
import re
from types import SimpleNamespace

import numpy as np
import plotly.offline
import pytest

import rigcal
from rigcal.camcal import stereo_checks as checks
from rigcal.core import geometry as geo
from rigcal.results import outputs
from rigcal.results import report
from rigcal.camcal.pipeline import calibrate_views

from tests.support.synthetic_obs import noisy_room, perturb

from tests.support.report_page import FIGURE_IDS, N_FRAMES, PLANTED, RIG, synthetic_calibration, synthetic_report_html


@pytest.fixture(scope="module")
def built():
    cal, out_rig, pairs, n_spoiled = synthetic_calibration()
    return cal, out_rig, pairs, synthetic_report_html(), n_spoiled


def test_plotly_js_embedded_exactly_once(built):
    page = built[3]
    bundle = plotly.offline.get_plotlyjs()
    assert page.count(bundle[:2000]) == 1
    assert page.count("* plotly.js v") == 1
    # the rest of the page (tables, figure data) is small next to the bundle
    assert len(page) < len(bundle) + 2_000_000


def test_page_needs_no_network(built):
    page = built[3]
    tags = re.findall(r"<script\b[^>]*>", page, flags=re.I)
    assert tags, "no script at all: the figures cannot draw"
    assert not [t for t in tags if re.search(r"\bsrc\s*=", t, flags=re.I)]
    assert not re.search(r"<link\b[^>]*\bhref\s*=\s*[\"']https?:", page, flags=re.I)


def test_every_figure_div_is_there(built):
    page = built[3]
    assert page.count('class="plotly-graph-div"') == len(FIGURE_IDS)
    for div_id in FIGURE_IDS:
        assert f'id="{div_id}"' in page
    for heading in ("Rig in the body frame (FLU)", "Per-frame RMS", "Board and frame poses",
                    "Depth error versus distance: front_left / front_right", "Camera back: coverage and residuals"):
        assert f"<h2>{heading}</h2>" in page


def test_tables_name_every_camera_and_the_baseline(built):
    cal, out_rig, pairs, page = built[:4]
    tables = page[:page.index("<h2>Rig in the body frame")]
    for name in out_rig.names:
        assert tables.count(f'<td class="name">{name}</td>') == 2  # intrinsics and pose tables
    chk = pairs[("front_left", "front_right")]
    assert f"{1000 * chk['baseline_m']:.3f}" in tables
    vd = chk["depth_check"]["vertical_disparity_rms_px"]
    assert f"{vd:.4f}" in tables
    assert f"{chk['sanity_10m']['disparity_px']:.3f}" in tables
    for band in chk["depth_check"]["bands"]:
        assert f"<td>{band['count']}</td>" in tables
    st = cal.stats["back"]
    assert f"{out_rig.camera('back').intrinsics.fx:.3f} &plusmn; {st.sigma_intrinsics['fx']:.3f}" in tables
    assert " ".join(f"{x:.3f}" for x in st.sigma_position_mm) in tables
    assert f"{int((~cal.inliers).sum())} outliers rejected" in tables
    assert "No detection step" in tables


def test_model_choice_is_explained(built):
    cal, out_rig, _, page = built[:4]
    section = page[page.index("<h3>Distortion model choice</h3>"):page.index("<h2>Cameras: pose")]
    for name in out_rig.names:
        st = cal.stats[name]
        assert f"<li>{name}: {st.distortion_model}" in section
        assert st.model_selection and all(html.escape(line) in section for line in st.model_selection)


def test_rejected_corners_are_reported(built):
    cal = built[0]
    n_rejected = int((~cal.inliers).sum())
    # the planted 15 px errors, and nothing else at 0.1 px noise, are rejected by the solver
    assert n_rejected == PLANTED * built[4]
    e = report.all_residuals(cal)
    assert np.all(np.linalg.norm(e[~cal.inliers], axis=1) > 5.0)
    figs = {div_id: fig for _, div_id, fig in report.figures(cal, built[1], built[2])}
    rejected = [t for k in range(3) for t in figs[f"fig-camera-{k}"].data if t.name == "rejected corners"]
    assert sum(len(t.x) for t in rejected if t.type == "scatter") == 2 * n_rejected  # coverage + residual panels
    assert sum(int(np.sum(t.y)) for t in rejected if t.type == "bar") == n_rejected


def test_residuals_of_the_inliers_are_the_solvers(built):
    cal = built[0]
    e = report.all_residuals(cal)
    assert e.shape == (len(cal.obs), 2)
    np.testing.assert_allclose(e[cal.inliers].ravel(), cal.problem.residuals(cal.problem.x0()), atol=1e-9)


def test_frame_rms_adds_up_to_each_cameras_rms(built):
    cal = built[0]
    rms, n_in, n_out = report.frame_rms(cal, report.all_residuals(cal))
    assert rms.shape == (3, N_FRAMES)
    assert n_out.sum() == (~cal.inliers).sum()
    for c, name in enumerate(cal.cam_names):
        seen = n_in[c] > 0
        total = np.sqrt(np.sum(rms[c, seen] ** 2 * n_in[c, seen]) / n_in[c].sum())
        assert total == pytest.approx(cal.stats[name].rms_px, rel=1e-9)
        assert n_in[c].sum() == cal.stats[name].observations


def test_depth_scatter_is_the_depth_check_data(built):
    cal, _, pairs = built[:3]
    z, rel, frames = report.depth_samples(cal, "front_left", "front_right")
    overall = pairs[("front_left", "front_right")]["depth_check"]["overall"]
    assert len(z) == overall["count"]
    assert np.median(np.abs(rel)) * 100 == pytest.approx(overall["median_rel_error_pct"], abs=1e-4)
    assert np.percentile(np.abs(rel), 95) * 100 == pytest.approx(overall["p95_rel_error_pct"], abs=1e-4)
    assert np.all((z > 0.5) & (z < 5.0))  # the room's boards are 2 m from the rig centre


def test_nearest_axes():
    R = geo.R_from_axes(["-L", "-U", "F"])
    assert report.nearest_axes(R) == ("[-L, -U, F]", pytest.approx(0.0, abs=1e-9))
    tilted = geo.R_from_rotvec([0.0, np.radians(1.5), 0.0]) @ R
    axes, off = report.nearest_axes(tilted)
    assert axes == "[-L, -U, F]" and off == pytest.approx(1.5, abs=1e-9)
    yawed = geo.R_from_rotvec([0.0, 0.0, np.radians(50.0)])  # nearer to a 90 degree yaw than to none
    axes, off = report.nearest_axes(yawed)
    assert axes == "[L, -F, U]" and off == pytest.approx(40.0, abs=1e-9)
    a = np.sqrt(0.5)
    tie = np.array([[a, -a, 0.0], [a, a, 0.0], [0.0, 0.0, 1.0]])  # exactly halfway: no nearest mounting
    assert report.nearest_axes(tie)[0] == "-"


def test_detection_section_from_a_detection_result(built):
    cal, out_rig, pairs = built[:3]
    views = [SimpleNamespace(camera="front_left"), SimpleNamespace(camera="front_left"),
             SimpleNamespace(camera="back")]
    det = SimpleNamespace(views=views, n_images={"front_left": 12, "front_right": 12, "back": 11},
                          no_board={"front_right": ["a.png", "b.png"]}, dropped={"back": 4},
                          unreadable=[("images/back/000009.png", "not an image")], seconds=2.5,
                          summary=lambda: "detected 3 board views in 35 images <all>")
    html = report.build_report(cal, out_rig, det, pairs, {"detection_s": 2.5})
    section = html[html.index("<h2>Detection</h2>"):html.index("<h2>Timings</h2>")]
    assert "detected 3 board views in 35 images &lt;all&gt;" in section
    rows = re.findall(r"<tr><td class=\"name\">(\w+)</td><td>([\d-]+)</td><td>(\d+)</td><td>([\d-]+)</td>"
                      r"<td>([\d-]+)</td></tr>", section)
    assert rows == [("front_left", "12", "2", "-", "-"), ("front_right", "12", "0", "2", "-"),
                    ("back", "11", "1", "-", "4")]
    assert "images/back/000009.png: skipped (not an image)" in section


def test_warnings_are_on_the_page(built):
    cal, out_rig, pairs = built[:3]
    st = cal.stats["back"]
    spoiled = dataclasses.replace(cal, stats=dict(cal.stats, back=dataclasses.replace(
        st, sigma_position_mm=np.array([0.1, 7.5, 0.1]))))
    html = report.build_report(spoiled, out_rig, None, pairs, {})
    assert "warning: back: position along body L is poorly constrained" in html


def test_same_calibration_same_page(built):
    assert synthetic_report_html() == built[3]
