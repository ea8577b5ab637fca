"""`rigcal view`: a self-contained plotly page of the rig's camera frames."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.core import io as rio
from rigcal.cli import app
from rigcal.errors import OutputError
from rigcal.core.rig import load_rig, parse_rig
from rigcal.results.view import frustum_rays, rig_figure, run

ROOT = Path(__file__).resolve().parents[2]
GOLDEN_RIG = ROOT / "rigs" / "drone-stereo-back.yaml"


def _xyz(trace) -> np.ndarray:
    return np.column_stack([np.array([np.nan if v is None else v for v in a], dtype=float)
                            for a in (trace.x, trace.y, trace.z)])


def test_figure_draws_each_camera_axis_at_its_pose():
    rig = load_rig(GOLDEN_RIG)
    fig = rig_figure(rig)
    names = [t.name for t in fig.data]
    assert [n for n in names if n.startswith("body ")] == ["body F", "body L", "body U"]
    for cam in rig.cameras:
        for i, axis in enumerate("xyz"):
            traces = [t for t in fig.data if t.name == f"{cam.name} {axis}"]
            assert len(traces) == 1  # one trace per camera axis
            pts = _xyz(traces[0])
            np.testing.assert_allclose(pts[0], cam.T_body_cam[:3, 3])  # starts at the pinhole
            direction = (pts[1] - pts[0]) / np.linalg.norm(pts[1] - pts[0])
            np.testing.assert_allclose(direction, cam.T_body_cam[:3, i], atol=1e-12)  # along that axis
            assert traces[0].line.color == {"x": "red", "y": "green", "z": "blue"}[axis]
        z_trace = next(t for t in fig.data if t.name == f"{cam.name} z")
        assert cam.name in z_trace.text  # labelled with the camera's name
        assert sum(t.name == f"{cam.name} frustum" for t in fig.data) == 1
    assert len(fig.data) == 3 + 4 * len(rig.cameras)
    body_labels = [t.text[-1] for t in fig.data[:3]]
    assert body_labels == ["F", "L", "U"]
    assert fig.layout.scene.aspectmode == "data"


def test_frustum_goes_through_the_image_corners():
    rig = load_rig(GOLDEN_RIG)
    m = rig.camera("front_left").intrinsics
    rays = frustum_rays(m)
    # the top-left pixel corner (-0.5, -0.5) of a 640x480, f = 300 camera
    corner = np.array([-320.5 / 300, -240.5 / 300, 1.0])
    np.testing.assert_allclose(rays[0], corner / np.linalg.norm(corner), atol=1e-12)
    np.testing.assert_allclose(rays[0], rays[-1])  # the outline is closed


def test_fisheye_frustum_is_clipped_to_the_lens_field():
    rig = load_rig(ROOT / "rigs" / "fisheye-stereo.yaml")
    rays = frustum_rays(rig.camera("left").intrinsics)
    assert np.isfinite(rays).all()
    theta = np.degrees(np.arccos(rays[:, 2]))
    assert theta.max() <= 110.0 and theta.max() > 90.0  # corners pulled in to the model's limit, past 90 deg


def test_html_is_self_contained(tmp_path):
    out = tmp_path / "rig.html"
    r = CliRunner().invoke(app, ["view", str(GOLDEN_RIG), "--out", str(out)])
    assert r.exit_code == 0, r.stderr
    assert f"wrote {out}" in r.stdout
    html = out.read_text(encoding="utf-8")
    assert html.lstrip().lower().startswith("<html") or html.lstrip().lower().startswith("<!doctype")
    assert re.search(r"plotly\.js v\d", html) and len(html) > 1_000_000  # the library itself, inline
    assert not re.search(r"<script[^>]+src\s*=\s*[\"']?(https?:)?//", html, flags=re.I)
    for name in ("front_left x", "front_right y", "back z", "body F"):
        assert f'"name":"{name}"' in html


def test_cameras_without_a_pose_are_listed_and_skipped(tmp_path):
    rig_path = tmp_path / "half.yaml"
    rig_path.write_text(
        "cameras:\n"
        "  a: {resolution: [640, 480], intrinsics: {focal: 300}, position: [0.1, 0, 0], look: forward}\n"
        "  b: {resolution: [640, 480], intrinsics: {focal: 300}}\n")
    text = run(rig_path, tmp_path / "half.html")
    assert "b: no pose in the rig file; not drawn" in text
    names = [t.name for t in rig_figure(load_rig(rig_path)).data]
    assert "a x" in names and not any(n.startswith("b ") for n in names)


def test_a_rig_with_no_poses_still_draws_the_body(tmp_path):
    rig = parse_rig("cameras:\n  a: {resolution: [64, 48], intrinsics: {focal: 50}}\n")
    fig = rig_figure(rig)
    assert [t.name for t in fig.data] == ["body F", "body L", "body U"]


def test_write_is_atomic(tmp_path, monkeypatch):
    out = tmp_path / "rig.html"
    out.write_text("previous page")

    def fail(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(rio.os, "replace", fail)
    with pytest.raises(OutputError, match="No space left"):
        run(GOLDEN_RIG, out)
    assert out.read_text() == "previous page"  # the old page is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.html"]  # and no temporary file is left


def test_unwritable_output_is_exit_2(tmp_path):
    out = tmp_path / "a-directory"
    out.mkdir()
    r = CliRunner().invoke(app, ["view", str(GOLDEN_RIG), "--out", str(out)])
    assert r.exit_code == 2
    assert len(r.stderr.strip().splitlines()) == 1 and str(out) in r.stderr
