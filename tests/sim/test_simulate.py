"""rigcal.sim.simulate / rigcal.sim.render: exact rendering, truth, coverage, determinism, bad input.

The renders here are small; bench/archive/bench_simulate.py has the big ones (and --accuracy
prints the figures quoted in the README)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.core import geometry as geo
from rigcal.sim import render
from rigcal.core.camera import CameraModel
from rigcal.cli import app
from rigcal.errors import InputError, OutputError
from rigcal.core.rig import load_rig, rig_from_dict
from rigcal.sim.simulate import (board_visibility, default_scene, make_target_for_rig, perturb_rig, simulate_dataset)
from rigcal.core.target import load_target, parse_target

RIGS = Path(__file__).resolve().parents[2] / "rigs"
runner = CliRunner()


# ----------------------------------------------------------------------------- helpers


def detections(dataset: Path):
    """Per camera: list of (frame, board, ids, detected (N, 2), true (N, 2), incidence deg (N,)),
    the truth read back from truth.yaml and projected through the true rig."""
    truth = yaml.safe_load((dataset / "truth.yaml").read_text())
    rig = rig_from_dict(truth["rig"])
    target = load_target(dataset / "target.yaml")
    out = {}
    for cam in rig.cameras:
        rows = []
        for stem, fr in truth["frames"].items():
            img = cv2.imread(str(dataset / "images" / cam.name / f"{stem}.png"), cv2.IMREAD_GRAYSCALE)
            T_world_body = geo.make_T(np.array(fr["rotation"]), fr["position"])
            T_cam_world = geo.inv_T(T_world_body @ cam.T_body_cam)
            markers = _markers(img, target)
            for b in target.boards:
                pose = fr.get("boards", {}).get(b.name, truth["boards"].get(b.name))
                mc, mids = markers[b.dictionary]
                sel = [i for i, m in enumerate(mids) if b.first_marker_id <= m < b.first_marker_id + b.n_markers]
                if pose is None or not sel:
                    continue
                # CharucoDetector on the markers found once per image (detecting them again per board is slow)
                corners, ids, _, _ = cv2.aruco.CharucoDetector(b.cv_board()).detectBoard(
                    img, markerCorners=tuple(mc[i] for i in sel), markerIds=mids[sel].reshape(-1, 1))
                if ids is None or len(ids) < 4:
                    continue
                ids = ids.reshape(-1)
                T_cam_board = T_cam_world @ geo.make_T(np.array(pose["rotation"]), pose["position"])
                p_cam = geo.transform(T_cam_board, b.corners[ids])
                uv, valid = cam.intrinsics.project(p_cam)
                assert valid.all()
                cos = np.abs(p_cam @ T_cam_board[:3, 2]) / np.linalg.norm(p_cam, axis=1)
                rows.append((stem, b.name, ids, corners.reshape(-1, 2).astype(float), uv, np.degrees(np.arccos(cos))))
        out[cam.name] = rows
    return out


def _markers(img: np.ndarray, target) -> dict:
    out = {}
    for name in {b.dictionary for b in target.boards}:
        det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)))
        mc, mids, _ = det.detectMarkers(img)
        out[name] = (mc, np.zeros(0, int) if mids is None else mids.reshape(-1))
    return out


def rms(rows, max_incidence=90.0) -> float:
    e = np.concatenate([np.linalg.norm(r[3] - r[4], axis=1)[r[5] < max_incidence] for r in rows])
    return float(np.sqrt(np.mean(e**2)))


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    out = tmp_path_factory.mktemp("room") / "drone"
    res = simulate_dataset(load_rig(RIGS / "drone-stereo-back.yaml"), out, frames=24, jobs=2, seed=3,
                           rig_text=(RIGS / "drone-stereo-back.yaml").read_text())
    return res, detections(out)


@pytest.fixture(scope="module")
def board_pinhole(tmp_path_factory):
    out = tmp_path_factory.mktemp("bp") / "stereo"
    res = simulate_dataset(load_rig(RIGS / "stereo-forward.yaml"), out, frames=8, noise=0.0, jobs=2, seed=1)
    return res, detections(out)


@pytest.fixture(scope="module")
def board_fisheye(tmp_path_factory):
    out = tmp_path_factory.mktemp("bf") / "fisheye"
    res = simulate_dataset(load_rig(RIGS / "fisheye-stereo.yaml"), out, frames=8, noise=0.0, jobs=2, seed=1)
    return res, detections(out)


# ----------------------------------------------------------------------------- rays and rendering


@pytest.mark.parametrize("model", [
    CameraModel("pinhole", 64, 48, 61.0, 60.0, 32.4, 23.1, (-0.05, 0.02, 4e-4, -3e-4, 0.001)),
    CameraModel("pinhole", 64, 48, 40.0, 41.0, 31.0, 24.0, (-0.2, 0.05, 1e-3, 0.0, 0.0, 0.01, 0.0, 0.0, 1e-3, 0, 0, 0)),
    CameraModel("fisheye", 80, 80, 25.0, 25.2, 40.3, 39.6, (0.02, -0.01, 0.002, -0.0005)),
])
def test_fast_ray_map_equals_camera_unproject(model):
    rays = render.ray_map(model, 2)
    u, v = render.sample_grid(model.width, model.height, 2)
    U, V = np.meshgrid(u, v)
    ref = model.unproject(np.column_stack([U.ravel(), V.ravel()]))
    got = rays.reshape(-1, 3).astype(float)
    known = np.isfinite(ref).all(axis=1)
    assert np.abs(got[known] - ref[known]).max() < 1e-6  # float32 storage
    assert np.all(got[~known] == 0)  # no ray past the lens's field: a zero ray, never a wrong one
    if model.model == "fisheye":
        assert (~known).any()  # this fisheye's corners lie outside its field


def _render_one(model: CameraModel, T_cam_board: np.ndarray, board, ss: int = 2) -> np.ndarray:
    rays = render.sample_rays(render.ray_map(model, ss))
    fg, alpha = render.render_boards(model, rays, [T_cam_board], [render.BoardTexture(board)], [(20.0, 230.0)], ss)
    return fg + (1.0 - alpha) * 128.0, alpha


BOARD = parse_target("boards:\n  - {name: a, type: charuco, dictionary: DICT_5X5_1000, squares: [8, 6], "
                     "square_length: 0.06, marker_length: 0.042}\n").boards[0]


@pytest.mark.parametrize("model", [
    CameraModel("pinhole", 640, 480, 500.0, 498.0, 322.3, 236.9, (-0.08, 0.03, 5e-4, -4e-4, 0.0)),
    CameraModel("fisheye", 640, 640, 220.0, 221.0, 318.2, 322.7, (0.02, -0.01, 0.002, -0.0005)),
])
def test_rendered_corners_sit_at_the_true_projection(model):
    """Geometry of the renderer itself: refine each corner from its true position with a
    small window on a noise-free render; it must stay put (no bias, no drift)."""
    rng = np.random.default_rng(5)
    errors = []
    for _ in range(4):
        R = geo.R_from_rotvec(np.r_[rng.normal(0, 0.3, 2), rng.uniform(-0.4, 0.4)])
        w, h = BOARD.size_m
        centre = np.r_[rng.uniform(-0.1, 0.1, 2), rng.uniform(0.55, 0.8)]
        T = geo.make_T(R, centre - R @ np.r_[w / 2, h / 2, 0])
        img, _ = _render_one(model, T, BOARD)
        img8 = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        uv, valid = model.project(geo.transform(T, BOARD.corners))
        keep = valid & model.in_image(uv, 8)
        start = uv[keep].astype(np.float32).reshape(-1, 1, 2)
        refined = cv2.cornerSubPix(img8, start.copy(), (3, 3), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)).reshape(-1, 2)
        errors.append(refined - uv[keep])
    e = np.concatenate(errors)
    assert len(e) > 80
    # cornerSubPix's own pixel locking is most of this (measured 0.06-0.085 px); a half-pixel
    # convention slip or a wrong distortion sign would give several tenths
    assert np.sqrt((e**2).sum(axis=1).mean()) < 0.1
    assert np.abs(e.mean(axis=0)).max() < 0.01  # and there is no bias


def test_render_matches_the_exact_raster_for_a_frontal_board():
    """A board parallel to the image plane of a distortion-free camera is the board's own
    raster, shifted and scaled: compare with Board.coverage blurred by the same amount."""
    f, d = 400.0, 1.0
    model = CameraModel("pinhole", 320, 240, f, f, 159.5, 119.5, (0.0,) * 5)
    ppm = f / d  # 400 px per metre; board origin on a pixel edge
    T = geo.make_T(np.eye(3), [(-159.5 + 20 - 0.5) / ppm, (-119.5 + 20 - 0.5) / ppm, d])
    img, alpha = _render_one(model, T, BOARD, ss=2)
    white = (img - (1 - alpha) * 128.0 - 20.0 * alpha) / 210.0  # back to coverage
    ref = BOARD.coverage(ppm, 20)
    h, w = ref.shape
    inner = (slice(22, h - 22), slice(22, w - 22))
    diff = white[:h, :w][inner] - ref[inner]
    assert abs(diff.mean()) < 2e-3  # the same amount of black, to within the texture's rounding
    assert np.abs(diff).max() < 0.25  # only the (symmetric) anti-aliasing blur differs


def test_nearest_board_wins_and_nothing_behind_the_camera_renders():
    model = CameraModel("pinhole", 200, 150, 150.0, 150.0, 99.5, 74.5, (0.0,) * 5)
    w, h = BOARD.size_m
    near = geo.make_T(np.eye(3), [-w / 2, -h / 2, 0.6])
    far = geo.make_T(np.eye(3), [-w / 2 + 0.1, -h / 2, 1.2])
    behind = geo.make_T(np.eye(3), [-w / 2, -h / 2, -0.6])
    rays = render.sample_rays(render.ray_map(model, 2))
    tex = [render.BoardTexture(BOARD), render.BoardTexture(BOARD)]
    only_near, _ = render.render_boards(model, rays, [near], tex[:1], [(0.0, 100.0)], 2)
    both, _ = render.render_boards(model, rays, [far, near], tex, [(0.0, 200.0), (0.0, 100.0)], 2)
    assert np.allclose(both, only_near, atol=1e-3)  # the far board, drawn first, is hidden
    both2, _ = render.render_boards(model, rays, [near, far], tex, [(0.0, 100.0), (0.0, 200.0)], 2)
    assert np.allclose(both2, only_near, atol=1e-3)  # and drawing order does not matter
    nothing, a = render.render_boards(model, rays, [behind], tex[:1], [(0.0, 100.0)], 2)
    assert not a.any() and not nothing.any()


# ----------------------------------------------------------------------------- truth and scenes


def test_perturb_rig_is_seeded_and_realistic():
    rig = load_rig(RIGS / "drone-stereo-back.yaml")
    a = perturb_rig(rig, np.random.default_rng(7))
    b = perturb_rig(rig, np.random.default_rng(7))
    assert a == b
    for cd, ct in zip(rig.cameras, a.cameras):
        dpos = np.linalg.norm(ct.T_body_cam[:3, 3] - cd.T_body_cam[:3, 3])
        drot = geo.rotation_angle_deg(ct.T_body_cam[:3, :3] @ cd.T_body_cam[:3, :3].T)
        assert 0 < dpos < 0.03 and 0 < drot < 5
        m, md = ct.intrinsics, cd.intrinsics
        assert m.fx != m.fy and abs(m.fx / md.fx - 1) < 0.1
        assert 0 < abs(m.cx - md.cx) <= 5 and 0 < abs(m.cy - md.cy) <= 5
        assert len(m.dist) == 5 and 0.01 <= abs(m.dist[0]) <= 0.05 and m.dist[4] == md.dist[4]
    zero = perturb_rig(rig, np.random.default_rng(7), 0.0, 0.0, 0.0)
    assert all(np.allclose(c.T_body_cam, d.T_body_cam) for c, d in zip(zero.cameras, rig.cameras))


def test_perturb_rig_keeps_lens_errors_when_the_distortion_draw_is_refused():
    """A fisheye whose image circle crosses the image border: a principal-point shift alone
    can move border pixels out of the field, so no distortion draw passes the field check.
    That once dropped the focal and principal-point errors too (the true lens equalled the
    declared one); now every camera's truth has its own fx, cx, cy, and a refused draw
    leaves exactly the declared distortion."""
    from rigcal.sim.simulate import field_border

    rig = load_rig(RIGS / "fisheye-stereo.yaml")
    kept, refused = 0, 0
    for seed in range(12):
        truth = perturb_rig(rig, np.random.default_rng([seed, 1]))
        for cd, ct in zip(rig.cameras, truth.cameras):
            m, md = ct.intrinsics, cd.intrinsics
            assert m.fx != md.fx and m.fy != md.fy and m.cx != md.cx and m.cy != md.cy, (seed, cd.name)
            if m.dist == md.dist:
                refused += 1
            else:  # a kept distortion error never costs a border pixel the ray the declared lens has there
                assert np.all(field_border(m) | ~field_border(md)), (seed, cd.name)
                kept += 1
    assert kept > 0 and refused > 0  # these seeds exercise both branches


def test_default_scene_and_generated_targets():
    assert default_scene(load_rig(RIGS / "drone-stereo-back.yaml")) == "room"  # the back camera shares no view
    assert default_scene(load_rig(RIGS / "surround-6.yaml")) == "room"  # no view common to all six
    assert default_scene(load_rig(RIGS / "stereo-forward.yaml")) == "board"
    assert default_scene(load_rig(RIGS / "fisheye-stereo.yaml")) == "board"
    room = make_target_for_rig(load_rig(RIGS / "down-nav.yaml"), "room")
    assert [b.name for b in room.boards] == ["wall_n", "wall_e", "wall_s", "wall_w", "floor"]  # a camera looks down
    firsts = [b.first_marker_id for b in room.boards]
    assert all(b.first_marker_id + b.n_markers <= c for b, c in zip(room.boards, firsts[1:]))


@pytest.mark.slow
def test_room_dataset_layout_truth_and_coverage(room):
    res, det = room
    out = res.out_dir
    assert sorted(p.name for p in out.iterdir()) == ["images", "rig.yaml", "target.yaml", "truth.yaml"]
    assert (out / "rig.yaml").read_text() == (RIGS / "drone-stereo-back.yaml").read_text()  # declared, unchanged
    assert sorted(p.name for p in (out / "images").iterdir()) == sorted(res.declared.names)
    for cam in res.declared.names:
        files = sorted((out / "images" / cam).iterdir())
        assert [f.name for f in files] == [f"{i:06d}.png" for i in range(24)]
        img = cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED)
        assert img.shape == (480, 640) and img.dtype == np.uint8
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    assert set(truth) == {"rig", "boards", "frames", "render"}
    assert truth["render"]["seed"] == 3 and truth["render"]["noise_sigma"] == 2.0
    true_rig = rig_from_dict(truth["rig"])
    assert true_rig == res.truth
    for cd, ct in zip(res.declared.cameras, true_rig.cameras):
        assert np.abs(ct.T_body_cam - cd.T_body_cam).max() > 1e-4  # the truth is not the declared rig
        assert ct.intrinsics != cd.intrinsics
    # every camera detects every board at least 5 times (ChArUco detector on the noisy images)
    target = load_target(out / "target.yaml")
    for cam, rows in det.items():
        views = {b.name: sum(r[1] == b.name and len(r[2]) >= 6 for r in rows) for b in target.boards}
        assert min(views.values()) >= 5, (cam, views)
        planned = res.coverage[cam].board_views
        assert all(views[b] >= 0.6 * planned[b] for b in views), (cam, views, planned)


def test_room_truth_matches_detections(room):
    _, det = room
    for cam, rows in det.items():
        assert rms(rows) < 0.3, cam  # 2 grey levels of noise: corners still land on the truth


@pytest.mark.slow
def test_board_scene_pinhole_accuracy_and_coverage(board_pinhole):
    res, det = board_pinhole
    for cam, rows in det.items():
        frames = {r[0] for r in rows if len(r[2]) >= 6}
        assert len(frames) >= 0.7 * len(res.frames), cam
        assert rms(rows) < 0.1, cam  # noise-free render, raw CharucoDetector corners
    # the pair sees the board together in most frames
    both = {r[0] for r in det["left"]} & {r[0] for r in det["right"]}
    assert len(both) >= 0.7 * len(res.frames)
    truth = yaml.safe_load((res.out_dir / "truth.yaml").read_text())
    assert all("boards" in f for f in truth["frames"].values())  # the moving board's pose per frame


@pytest.mark.slow
def test_board_scene_fisheye_accuracy_and_coverage(board_fisheye):
    res, det = board_fisheye
    for cam, rows in det.items():
        frames = {r[0] for r in rows if len(r[2]) >= 6}
        assert len(frames) >= 0.7 * len(res.frames), cam
        # raw CharucoDetector corners on the noise-free render; at grazing angles the
        # detector itself degrades (0.2 px RMS beyond 60 degrees, README), not the render
        assert rms(rows, max_incidence=60.0) < 0.15, cam
        assert rms(rows) < 0.25, cam


@pytest.mark.slow
def test_coverage_of_every_image_cell(board_pinhole, room):
    for res, _ in (board_pinhole, room):
        for cam, cov in res.coverage.items():
            assert cov.cells_covered >= 0.9, (cam, cov)


def test_board_visibility_basics():
    rig = load_rig(RIGS / "stereo-forward.yaml")
    cam = rig.camera("left")
    board = make_target_for_rig(rig, "board").boards[0]
    w, h = board.size_m
    R_cam_board = np.eye(3)
    T_cam_board = geo.make_T(R_cam_board, [-w / 2, -h / 2, 1.5])
    T_body_board = cam.T_body_cam @ T_cam_board
    assert board_visibility(cam, T_body_board, board).count == board.n_corners
    flipped = cam.T_body_cam @ geo.make_T(geo.R_from_rotvec([0, np.pi, 0]), [w / 2, -h / 2, 1.5])
    assert board_visibility(cam, flipped, board).count == 0  # the back of the board


# ----------------------------------------------------------------------------- determinism and the command


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_same_seed_same_bytes_whatever_the_workers(tmp_path):
    rig = load_rig(RIGS / "down-nav.yaml")
    simulate_dataset(rig, tmp_path / "a", frames=2, seed=11, jobs=1)
    simulate_dataset(rig, tmp_path / "b", frames=2, seed=11, jobs=2)
    simulate_dataset(rig, tmp_path / "c", frames=2, seed=12, jobs=2)
    a, b, c = _digest(tmp_path / "a"), _digest(tmp_path / "b"), _digest(tmp_path / "c")
    assert a == b
    assert a["images/down/000000.png"] != c["images/down/000000.png"]


def test_cli_simulate_writes_a_dataset(tmp_path):
    out = tmp_path / "sim" / "drone"
    r = runner.invoke(app, ["simulate", str(RIGS / "drone-stereo-back.yaml"), "--out", str(out), "--frames", "4",
                            "--seed", "2", "--blur", "1.5", "--jobs", "2"])
    assert r.exit_code == 0, r.output
    assert "room scene, 4 frames, 12 images" in r.output
    assert len(list((out / "images").rglob("*.png"))) == 12
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    assert truth["render"]["blur_px"] == 1.5 and len(truth["frames"]) == 4


@pytest.mark.slow
def test_cli_simulate_with_given_target_and_scene(tmp_path):
    t = tmp_path / "t.yaml"
    t.write_text("boards:\n  - {name: big, type: charuco, dictionary: DICT_6X6_250, squares: [7, 5], "
                 "square_length: 0.09, marker_length: 0.065, first_marker_id: 40}\n")
    out = tmp_path / "d"
    r = runner.invoke(app, ["simulate", str(RIGS / "stereo-forward.yaml"), "--out", str(out), "--frames", "3",
                            "--scene", "board", "--target", str(t), "--noise", "0", "--jobs", "1"])
    assert r.exit_code == 0, r.output
    assert (out / "target.yaml").read_text() == t.read_text()
    img = cv2.imread(str(out / "images" / "left" / "000000.png"), cv2.IMREAD_GRAYSCALE)
    b = load_target(t).boards[0]
    _, ids, _, _ = cv2.aruco.CharucoDetector(b.cv_board()).detectBoard(img)
    assert ids is not None and len(ids) >= 6


BAD_TARGETS = {
    "unknown dictionary": {"dictionary": "DICT_9X9_1000"},
    "marker not smaller": {"marker_length": "0.2"},
    "non-positive size": {"square_length": "0"},
    "too many markers": {"dictionary": "DICT_4X4_50", "squares": "[12, 10]"},
}


@pytest.mark.parametrize("case", sorted(BAD_TARGETS))
def test_cli_simulate_bad_target(tmp_path, case):
    fields = {"dictionary": "DICT_5X5_1000", "squares": "[5, 4]", "square_length": "0.1", "marker_length": "0.07"}
    fields.update(BAD_TARGETS[case])
    body = ", ".join(f"{k}: {v}" for k, v in fields.items())
    t = tmp_path / "t.yaml"
    t.write_text(f"boards:\n  - {{name: a, type: charuco, {body}}}\n")
    out = tmp_path / "d"
    r = runner.invoke(app, ["simulate", str(RIGS / "stereo-forward.yaml"), "--out", str(out), "--target", str(t)])
    assert r.exit_code == 2, r.output
    assert len(r.output.strip().splitlines()) == 1 and str(t) in r.output
    assert not out.exists()


def test_cli_simulate_overlapping_ids(tmp_path):
    t = tmp_path / "t.yaml"
    t.write_text("boards:\n"
                 "  - {name: a, type: charuco, dictionary: DICT_5X5_1000, squares: [5, 4], square_length: 0.1, marker_length: 0.07}\n"
                 "  - {name: b, type: charuco, dictionary: DICT_5X5_1000, squares: [5, 4], square_length: 0.1, marker_length: 0.07, first_marker_id: 9}\n")
    r = runner.invoke(app, ["simulate", str(RIGS / "drone-stereo-back.yaml"), "--out", str(tmp_path / "d"), "--target", str(t)])
    assert r.exit_code == 2 and "'b'" in r.output and "'a'" in r.output
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("args, msg", [
    (["--frames", "0"], "--frames"),
    (["--frames", "-3"], "--frames"),
    (["--noise", "-1"], "--noise"),
    (["--jobs", "0"], "--jobs"),
])
def test_cli_simulate_bad_options(tmp_path, args, msg):
    out = tmp_path / "d"
    r = runner.invoke(app, ["simulate", str(RIGS / "drone-stereo-back.yaml"), "--out", str(out)] + args)
    assert r.exit_code == 2 and msg in r.output and len(r.output.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_simulate_refuses_non_empty_out_unless_forced(tmp_path):
    out = tmp_path / "d"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    args = ["simulate", str(RIGS / "down-nav.yaml"), "--out", str(out), "--frames", "1", "--jobs", "1"]
    r = runner.invoke(app, args)
    assert r.exit_code == 2 and "--force" in r.output
    assert (out / "keep.txt").read_text() == "mine"
    r = runner.invoke(app, args + ["--force"])
    assert r.exit_code == 0, r.output
    assert not (out / "keep.txt").exists() and (out / "truth.yaml").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["d"]  # no temporary folder left behind


def test_cli_simulate_unwritable_and_unposed(tmp_path):
    (tmp_path / "file").write_text("")
    r = runner.invoke(app, ["simulate", str(RIGS / "down-nav.yaml"), "--out", str(tmp_path / "file" / "d"), "--frames", "1"])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1
    rig = tmp_path / "r.yaml"
    rig.write_text("cameras:\n  a:\n    resolution: [64, 48]\n    intrinsics: {focal: 50}\n")
    r = runner.invoke(app, ["simulate", str(rig), "--out", str(tmp_path / "d"), "--frames", "1"])
    assert r.exit_code == 2 and "cameras.a" in r.output and "pose" in r.output
    assert not (tmp_path / "d").exists()


def test_library_errors_are_rigcal_errors(tmp_path):
    rig = load_rig(RIGS / "down-nav.yaml")
    with pytest.raises(InputError):
        simulate_dataset(rig, tmp_path / "x", frames=0)
    with pytest.raises(InputError):
        simulate_dataset(rig, tmp_path / "x", scene="garden")
    (tmp_path / "y").mkdir()
    (tmp_path / "y" / "f").write_text("")
    with pytest.raises(OutputError):
        simulate_dataset(rig, tmp_path / "y", frames=1)


def test_chessboard_target_is_planned_whole_and_rendered_in_opencvs_corner_order(tmp_path):
    rig = parse_rig_text("cameras:\n  cam:\n    resolution: [640, 480]\n    intrinsics: {focal: 500}\n"
                         "    position: [0, 0, 0]\n    look: forward\n")
    target = parse_target("boards:\n  - {name: chess, type: chessboard, inner_corners: [9, 6], square_length: 0.04}\n")
    res = simulate_dataset(rig, tmp_path / "d", frames=3, noise=0.0, target=target, jobs=1, seed=4)
    cam = res.truth.cameras[0]
    board = target.boards[0]
    for fi, stem in enumerate(res.frames):
        img = cv2.imread(str(tmp_path / "d" / "images" / "cam" / f"{stem}.png"), cv2.IMREAD_GRAYSCALE)
        ok, found = cv2.findChessboardCorners(img, board.inner_corners)
        assert ok, stem
        T_cam_board = geo.inv_T(cam.T_body_cam) @ res.scene_poses.T_world_board[fi, 0]
        uv, _ = cam.intrinsics.project(geo.transform(T_cam_board, board.corners))
        err = np.linalg.norm(found.reshape(-1, 2) - uv, axis=1)
        assert np.sqrt(np.mean(err**2)) < 0.15, stem  # row index == corner id, as Board.corners says


def parse_rig_text(text: str):
    from rigcal.core.rig import parse_rig

    return parse_rig(text, "r.yaml")
