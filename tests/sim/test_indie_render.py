"""rigcal against an independent renderer (tests/support/indie_render.py, which imports nothing of rigcal).

rigcal's other round trips render with its own simulator, which shares board geometry and
projection code with the calibrator. Here the scenes come from the contract and OpenCV
alone; `rigcal calibrate` runs as a user runs it (the CLI) and its output file is read
with plain YAML and compared with the truth by hand.

Bounds: each error is held to 4 times the 1-sigma that rigcal itself reports for it
(calibration.sigma in the output; a pair's sigma is the root-sum-square of its two
cameras', which ignores their positive correlation and so overstates it), plus a floor
for what the renderer cannot promise: a systematic corner error of 0.01 px (the box
filter's 1/9 coverage steps and OpenCV's 1/32-texel remap positions, measured by
test_renderer_agrees_with_opencv below: OpenCV's own corners sit
0.004 px from the truth on average, median 0.05 px), i.e. 0.01 px / f in angle, or 0.002 deg and
0.02 mm at 1 m.
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from tests.support import indie_render as ir

from rigcal.cli import app  # noqa: E402

runner = CliRunner()
K_SIGMA = 4.0
FLOOR_DEG, FLOOR_MM, FLOOR_PX = 0.002, 0.02, 0.01


# ----------------------------------------------------------------------------- helpers


def _calibrate(ds: Path) -> tuple[dict, str]:
    out = ds / "calibrated.yaml"
    r = runner.invoke(app, ["calibrate", str(ds), "--out", str(out), "--jobs", "2"])
    assert r.exit_code == 0, r.output
    return yaml.safe_load(out.read_text()), r.output


def _T(cam: dict) -> np.ndarray:
    return ir.pose(np.array(cam["rotation"], float), cam["position"])


def pair_errors(cal: dict, truth: dict) -> dict:
    """(a, b) -> rotation error (deg) and translation error (mm) of T_a_b, camera a to b."""
    names = list(truth["rig"]["cameras"])
    out = {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            est = ir.inv(_T(cal["cameras"][a])) @ _T(cal["cameras"][b])
            tru = ir.inv(_T(truth["rig"]["cameras"][a])) @ _T(truth["rig"]["cameras"][b])
            dR = est[:3, :3] @ tru[:3, :3].T
            ang = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
            out[(a, b)] = {"rot_deg": float(ang), "trans_mm": 1000 * float(np.linalg.norm(est[:3, 3] - tru[:3, 3])),
                           "distance_m": float(np.linalg.norm(tru[:3, 3]))}
    return out


def pair_bounds(cal: dict, a: str, b: str, distance_m: float) -> tuple[float, float]:
    sa, sb = (cal["cameras"][n]["calibration"]["sigma"] for n in (a, b))
    s_rot = np.sqrt(np.sum(np.square(sa["rotation_deg"])) + np.sum(np.square(sb["rotation_deg"])))
    s_pos = np.sqrt(np.sum(np.square(sa["position_mm"])) + np.sum(np.square(sb["position_mm"])))
    return K_SIGMA * s_rot + FLOOR_DEG, K_SIGMA * s_pos + FLOOR_MM * max(1.0, distance_m)


def intrinsic_errors(cal: dict, truth: dict) -> dict:
    out = {}
    for n, c in truth["rig"]["cameras"].items():
        e, t = cal["cameras"][n]["intrinsics"], c["intrinsics"]
        sig = cal["cameras"][n]["calibration"]["sigma"]["intrinsics"]
        out[n] = {k: (e[k] - t[k], K_SIGMA * sig[k] + FLOOR_PX) for k in ("fx", "fy", "cx", "cy")}
    return out


def _check_against_truth(cal: dict, truth: dict) -> None:
    bad = []
    for (a, b), e in pair_errors(cal, truth).items():
        br, bt = pair_bounds(cal, a, b, e["distance_m"])
        if e["rot_deg"] > br or e["trans_mm"] > bt:
            bad.append(f"{a}/{b}: {e['rot_deg']:.4f} deg (bound {br:.4f}), {e['trans_mm']:.3f} mm (bound {bt:.3f})")
    for n, errs in intrinsic_errors(cal, truth).items():
        for k, (err, bound) in errs.items():
            if abs(err) > bound:
                bad.append(f"{n}.{k}: {err:+.4f} px (bound {bound:.4f})")
    assert not bad, "; ".join(bad)


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    ds = tmp_path_factory.mktemp("indie") / "room"
    written = ir.write_dataset(ir.room_scene(n_frames=14, seed=0), ds, seed=0, S=3)
    cal, output = _calibrate(ds)
    return ds, written, yaml.safe_load((ds / "truth.yaml").read_text()), cal, output


@pytest.fixture(scope="module")
def waved(tmp_path_factory):
    ds = tmp_path_factory.mktemp("indie") / "waved"
    written = ir.write_dataset(ir.waved_scene(n_frames=12, seed=0), ds, seed=1, S=3, corrupt=False)
    cal, output = _calibrate(ds)
    return ds, written, yaml.safe_load((ds / "truth.yaml").read_text()), cal, output


# ----------------------------------------------------------------------------- the renderer itself


@pytest.mark.slow
def test_renderer_agrees_with_opencv(room):
    """The renderer's own conventions, checked without rigcal: plain OpenCV ChArUco corners
    in the rendered PNGs land where cv2.projectPoints puts the true board corners (a wrong
    pixel-centre convention would show as a 0.5 px mean offset, a wrong board origin or a
    mirrored print as whole squares or no detection at all)."""
    ds, written, truth, _, _ = room
    scene = ir.room_scene(n_frames=14, seed=0)
    boards = {b.name: b for b in scene.boards}
    # markers once per image, in a dictionary of only the boards' codes (the full one is slow)
    full = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_1000)
    codes = np.concatenate([np.arange(b.first_marker_id, b.first_marker_id + b.n_markers) for b in scene.boards])
    aruco = cv2.aruco.ArucoDetector(cv2.aruco.Dictionary(full.bytesList[codes], full.markerSize,
                                                         full.maxCorrectionBits))
    d = []
    for (cam_name, stem), (path, ext, colour, link) in written["files"].items():
        cam = written["cameras"][cam_name]
        if (cam_name, stem) == written["corrupt"] or cam.model != "pinhole":
            continue
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        mc, mi, _ = aruco.detectMarkers(img)
        if mi is None:
            continue
        mi = codes[np.asarray(mi).reshape(-1)]
        T_world_cam = scene.T_world_body[stem] @ cam.T_body_cam
        for name, T_world_board in scene.T_world_board[stem].items():
            b = boards[name]
            sel = np.flatnonzero((mi >= b.first_marker_id) & (mi < b.first_marker_id + b.n_markers))
            if len(sel) < 2:
                continue
            corners, ids, _, _ = cv2.aruco.CharucoDetector(b.cv_board()).detectBoard(
                img, markerCorners=tuple(mc[i] for i in sel), markerIds=mi[sel].astype(np.int32).reshape(-1, 1))
            if ids is None or len(ids) < 6:
                continue
            ids = np.asarray(ids).reshape(-1)
            p_board = np.asarray(b.cv_board().getChessboardCorners(), float)[ids]
            T = ir.inv(T_world_cam) @ T_world_board
            uv = ir.project(cam, p_board @ T[:3, :3].T + T[:3, 3])
            d.append(np.asarray(corners, float).reshape(-1, 2) - uv)
    d = np.concatenate(d)
    assert len(d) > 300
    assert np.linalg.norm(d.mean(0)) < 0.02, d.mean(0)
    assert np.median(np.linalg.norm(d, axis=1)) < 0.1


def test_ray_interpolation_is_exact_to_a_thousandth_of_a_pixel():
    """pixel_rays asserts this itself on 20000 samples; here for a radtan lens as strong as
    the waved scene's and a fisheye whose corner rays pass 90 degrees. (A much stronger lens,
    f = 200 px with k1 = -0.25 on 640 x 480, interpolates to 0.03 px: pixel_rays refuses it.)"""
    K = np.array([[300.0, 0, 320], [0, 300, 240], [0, 0, 1]])
    pin = ir.Camera("p", "pinhole", (640, 480), K, np.array([-0.2, 0.05, 1e-3, -1e-3, -0.005]), np.eye(4))
    fe = ir.Camera("f", "fisheye", (640, 480), np.array([[200.0, 0, 320], [0, 200, 240], [0, 0, 1]]),
                   np.array([0.02, -0.01, 0.003, -0.0005]), np.eye(4))
    for cam in (pin, fe):
        rays, valid = ir.pixel_rays(cam, 2)
        assert valid.mean() > 0.99
    assert rays[0, 0, 2] < 0  # the fisheye's image corner looks more than 90 degrees off axis


# ----------------------------------------------------------------------------- rigcal on the room


def test_room_pairs_and_intrinsics_within_the_reported_noise(room):
    _, _, truth, cal, _ = room
    _check_against_truth(cal, truth)


def test_room_declared_rig_is_visibly_wrong(room):
    """The truth differs from the declared rig by the mounting errors, so the comparison
    above cannot pass by echoing the declared poses."""
    ds, _, truth, cal, _ = room
    decl = yaml.safe_load((ds / "rig.yaml").read_text())
    for n, c in decl["cameras"].items():
        axes = ir.LOOK[c["look"]] if "look" in c else c["axes"]
        c["rotation"] = ir.axes_R(axes).tolist()
    est, dec = pair_errors(cal, truth), pair_errors(decl, truth)
    for k in est:
        assert dec[k]["rot_deg"] > 0.3 and dec[k]["trans_mm"] > 2.0
        assert dec[k]["rot_deg"] > 20 * est[k]["rot_deg"] and dec[k]["trans_mm"] > 10 * est[k]["trans_mm"]


def test_room_rigcal_compare_reads_the_truth_and_agrees(room):
    """`rigcal compare` reads this truth.yaml (rig-yaml.md's calibrated schema) and finds the
    same pair errors as the hand computation here."""
    from rigcal.results.compare import compare_rigs
    from rigcal.data.truth import load_truth
    from rigcal.core.rig import load_rig

    ds, _, truth, cal, _ = room
    res = compare_rigs(load_rig(ds / "calibrated.yaml"), load_truth(ds / "truth.yaml").rig)
    for k, e in pair_errors(cal, truth).items():
        assert res["pairs"][k]["rot_deg"] == pytest.approx(e["rot_deg"], abs=1e-6)
        assert res["pairs"][k]["trans_mm"] == pytest.approx(e["trans_mm"], abs=1e-6)
    r = runner.invoke(app, ["compare", str(ds / "calibrated.yaml"), str(ds / "truth.yaml")])
    assert r.exit_code == 0, r.output


def test_room_corrupt_image_is_skipped_and_counted(room):
    ds, written, _, cal, output = room
    cam, stem = written["corrupt"]
    assert f"skipped {ds / 'images' / cam / stem}.png" in output.replace("\n", "")
    assert "1 unreadable" in output
    # the camera's frame count in the output leaves the corrupt image out
    seen = {s for (c, s) in written["files"] if c == cam} - {stem}
    assert cal["cameras"][cam]["calibration"]["frames"] <= len(seen)


def test_room_every_format_and_links_gave_board_views(room):
    """png / jpg / bmp / tif, grey and colour, and images behind symbolic links all yield
    board views in rigcal's detection; stems like 'cap_a7' and 'Shot.3' keep their frames."""
    from rigcal.data.dataset import list_dataset
    from rigcal.detect.detect import detect_dataset
    from rigcal.core.rig import load_rig
    from rigcal.core.target import load_target

    ds, written, _, _, _ = room
    rig = load_rig(ds / "rig.yaml")
    images = list_dataset(ds, rig)
    assert set(images.all_frames) == {s for (_, s) in written["files"]}
    det = detect_dataset(images, load_target(ds / "target.yaml"), rig=rig, jobs=2, progress=False)
    with_views = {(v.camera, v.frame) for v in det.views}
    kinds = defaultdict(int)
    for key, (_, ext, colour, link) in written["files"].items():
        if key in with_views:
            kinds[(ext, colour)] += 1
            kinds["link"] += link
    for kind in [(e, c) for e, c in ir.FORMATS] + ["link"]:
        assert kinds[kind] > 0, f"no board view from any {kind} image ({dict(kinds)})"
    missing = set(written["missing"])
    assert not any((v.camera, v.frame) in missing for v in det.views)


# ----------------------------------------------------------------------------- one board waved


@pytest.mark.slow
def test_waved_board_pair_and_intrinsics_within_the_reported_noise(waved):
    _, _, truth, cal, _ = waved
    _check_against_truth(cal, truth)
    (e,) = pair_errors(cal, truth).values()
    assert e["trans_mm"] < 0.5 and e["rot_deg"] < 0.05  # the accuracy target's own scale, whatever sigma says


# ----------------------------------------------------------------------------- the hand-eye room


@pytest.mark.slow
def test_room_without_a_shared_board_calibrates(tmp_path):
    """dataset.md: boards' relative poses are unknown and estimated; nothing requires a board
    seen by both the front pair and the back camera. With the rig only yawing +-20 degrees
    the back camera's pose follows from the rig's rotations (AX = ZB)."""
    ds = tmp_path / "forward"
    ir.write_dataset(ir.room_scene(n_frames=10, seed=3, headings="forward"), ds, seed=3, S=2, drop=0,
                     corrupt=False)
    out = ds / "calibrated.yaml"
    r = runner.invoke(app, ["calibrate", str(ds), "--out", str(out), "--jobs", "2"])
    assert r.exit_code == 0, r.output
    _check_against_truth(yaml.safe_load(out.read_text()), yaml.safe_load((ds / "truth.yaml").read_text()))
