"""Exports read back by their real consumers (cv2.FileStorage, a Kalibr-style reader,
ROS camera_info layout, gtsam), the Kalibr import round trip, golden files, error paths."""

from __future__ import annotations

import importlib.util
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from tests.support import golden_data
from rigcal.exports import formats as export
from rigcal.core import geometry as geo
from rigcal.cli import app
from rigcal.core.rig import Rig, load_rig, parse_rig, rig_from_dict, save_rig
from rigcal.core.stereo import rectify_pair, rectify_pixels

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "tests" / "golden"
CALIBRATED = GOLDEN / "drone-stereo-back-calibrated.yaml"
DECLARED = ROOT / "rigs" / "drone-stereo-back.yaml"

# A forward fisheye pair (equidistant k1..k4) and a pinhole camera looking left,
# listed so that Kalibr's order (pairs adjacent) differs from the rig's.
FISHEYE_RIG = """
rig: fisheye-pair
cameras:
  side:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 310.0, fy: 309.0, cx: 318.0, cy: 242.0}
    distortion: [-0.02, 0.004, 0.0003, -0.0002, 0.0]
    position: [0.0, 0.08, 0.02]
    look: left
  fe_right:
    model: fisheye
    resolution: [800, 600]
    intrinsics: {fx: 280.0, fy: 281.0, cx: 401.0, cy: 298.0}
    distortion: [0.021, -0.006, 0.0012, -0.0002]
    position: [0.12, -0.06, 0.0]
    rotation: [[0.0, -0.0175, 0.99985], [-1.0, 0.0, 0.0], [0.0, -0.99985, -0.0175]]
  fe_left:
    model: fisheye
    resolution: [800, 600]
    intrinsics: {fx: 279.0, fy: 280.5, cx: 399.0, cy: 301.0}
    distortion: [0.018, -0.004, 0.001, -0.0001]
    position: [0.12, 0.06, 0.0]
    axes: [-L, -U, F]
stereo_pairs:
  - [fe_left, fe_right]
"""


def _fix_rotation(text: str) -> str:
    # The hand-written fe_right rotation above is rounded; replace it by an exact one.
    R = geo.R_from_axes(["-L", "-U", "F"]) @ geo.R_from_rotvec(np.radians([1.0, 0.0, 0.0]))
    rows = "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in r) + "]" for r in R) + "]"
    return text.replace("[[0.0, -0.0175, 0.99985], [-1.0, 0.0, 0.0], [0.0, -0.99985, -0.0175]]", rows)


@pytest.fixture(scope="module")
def fisheye_rig() -> Rig:
    return parse_rig(_fix_rotation(FISHEYE_RIG), "fisheye-pair.yaml")


@pytest.fixture(scope="module")
def calibrated() -> Rig:
    return load_rig(CALIBRATED)


def cli(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


def points_seen_by(cam, n: int, seed: int, depth=(0.5, 20.0)) -> np.ndarray:
    """n body-frame points whose pixels fall inside `cam`'s image (seeded)."""
    rng = np.random.default_rng(seed)
    m = cam.intrinsics
    uv = rng.uniform([-0.5, -0.5], [m.width - 0.5, m.height - 0.5], size=(n, 2))
    p_cam = m.unproject(uv) * rng.uniform(*depth, size=(n, 1))
    return geo.transform(cam.T_body_cam, p_cam)


def assert_same_rig_geometry(a: Rig, b: Rig, seed: int = 0) -> None:
    """Same names, resolutions and models; poses to 1e-12; projections of random points to 1e-9 px."""
    assert a.names == b.names
    for ca, cb in zip(a.cameras, b.cameras):
        assert ca.intrinsics.model == cb.intrinsics.model
        assert ca.intrinsics.resolution == cb.intrinsics.resolution
        assert np.abs(ca.T_body_cam - cb.T_body_cam).max() < 1e-12, ca.name
        p_body = points_seen_by(ca, 1000, seed)
        pa, pb = ca.project_body(p_body), cb.project_body(p_body)
        assert pa.valid.all() and pb.valid.all()
        assert np.abs(pa.uv - pb.uv).max() < 1e-9, ca.name


# ----------------------------------------------------------------------------- json


def test_json_round_trip_equals_the_rig(calibrated, fisheye_rig, tmp_path):
    for rig in (calibrated, fisheye_rig):
        back = rig_from_dict(json.loads(export.json_text(rig)), "rig.json")
        assert back == rig
    out = tmp_path / "rig.json"
    r = cli("export", CALIBRATED, "--format", "json", "--out", out)
    assert r.exit_code == 0, r.stderr
    assert rig_from_dict(json.loads(out.read_text()), str(out)) == calibrated


# ----------------------------------------------------------------------------- kalibr


def kalibr_reader_checks(doc: dict) -> None:
    """What Kalibr's CameraChainParameters / CameraParameters (kalibr_common/ConfigReader.py)
    check: the camera count is len(top-level mapping); per camera pinhole [fu, fv, pu, pv]
    as floats, 4 coefficients of radtan/equidistant, integer resolution, a string
    rostopic, cam_overlaps within range, a 4x4 T_cn_cnm1 for cam1.."""
    n = len(doc)
    assert list(doc) == [f"cam{i}" for i in range(n)]
    for i in range(n):
        c = doc[f"cam{i}"]
        assert c["camera_model"] == "pinhole"
        assert len(c["intrinsics"]) == 4 and all(isinstance(x, float) for x in c["intrinsics"])
        assert min(c["intrinsics"]) >= 0.0
        assert c["distortion_model"] in ("radtan", "equidistant")
        assert len(c["distortion_coeffs"]) == 4
        assert len(c["resolution"]) == 2 and all(type(x) is int for x in c["resolution"])
        assert isinstance(c["rostopic"], str)
        assert all(0 <= j < n and j != i for j in c["cam_overlaps"])
        if i:
            T = np.array(c["T_cn_cnm1"], dtype=float)
            assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
            assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
        else:
            assert "T_cn_cnm1" not in c


def test_kalibr_file_passes_kalibr_reader_checks(calibrated, fisheye_rig):
    for rig in (calibrated, fisheye_rig):
        kalibr_reader_checks(yaml.safe_load(export.kalibr_camchain(rig).files["camchain.yaml"]))


def test_kalibr_chain_maps_previous_camera_into_this_one():
    # Textbook rig: front_right sits 0.1 m to the right of front_left with the same axes,
    # so front_left's origin is at x = -0.1 in front_right's frame; the back camera is
    # turned 180 degrees about the camera y axis, 0.2 m behind and 0.05 m to the left.
    doc = yaml.safe_load(export.kalibr_camchain(load_rig(DECLARED)).files["camchain.yaml"])
    assert [doc[k]["rigcal_name"] for k in doc] == ["front_left", "front_right", "back"]
    assert np.allclose(doc["cam1"]["T_cn_cnm1"], geo.make_T(np.eye(3), [-0.1, 0, 0]), rtol=0, atol=1e-15)
    assert np.allclose(doc["cam2"]["T_cn_cnm1"], geo.make_T(np.diag([-1.0, 1, -1]), [-0.05, 0, -0.2]), rtol=0, atol=1e-15)
    assert [doc[k]["cam_overlaps"] for k in doc] == [[1], [0], []]


def test_kalibr_order_puts_pairs_together_and_overlaps_come_from_geometry(fisheye_rig):
    assert export.kalibr_order(fisheye_rig) == ["side", "fe_left", "fe_right"]
    # The left-looking camera and the forward fisheyes (about 190 deg across) share a view;
    # nothing in the rig says so, only the geometry.
    ov = export.camera_overlaps(fisheye_rig)
    assert ov == {"side": ["fe_right", "fe_left"], "fe_right": ["side", "fe_left"], "fe_left": ["side", "fe_right"]}
    narrow = load_rig(DECLARED)
    assert export.camera_overlaps(narrow)["back"] == []


@pytest.mark.parametrize("which", ["calibrated", "fisheye"])
def test_kalibr_export_reimported_with_declared_rig_is_the_same_rig(which, calibrated, fisheye_rig, tmp_path):
    rig = calibrated if which == "calibrated" else fisheye_rig
    declared = tmp_path / "declared.yaml"
    save_rig(rig, declared)
    camchain, imported = tmp_path / "camchain.yaml", tmp_path / "imported.yaml"
    r = cli("export", declared, "--format", "kalibr", "--out", camchain)
    assert r.exit_code == 0, r.stderr
    r = cli("import", "--format", "kalibr", camchain, "--out", imported, "--rig", declared)
    assert r.exit_code == 0, r.stderr
    assert "by rigcal_name" in r.stdout
    back = load_rig(imported)
    assert_same_rig_geometry(rig, back)
    assert [(p.left, p.right) for p in back.stereo_pairs] == [(p.left, p.right) for p in rig.stereo_pairs]


def test_kalibr_import_of_plain_kalibr_file_matches_by_order(calibrated, tmp_path):
    # A camchain from Kalibr itself has no rigcal_name and its own topics: cameras are
    # matched to the declared rig by order, so a re-ordered chain must be read in rig order.
    doc = yaml.safe_load(export.kalibr_camchain(calibrated).files["camchain.yaml"])
    for i, k in enumerate(doc):
        del doc[k]["rigcal_name"]
        doc[k]["rostopic"] = f"/cam{i}/image_raw"
    src = tmp_path / "camchain.yaml"
    src.write_text(yaml.safe_dump(doc))
    back, notes, warnings = export.rig_from_camchain(export.parse_camchain(doc, str(src)), str(src), calibrated, "decl")
    assert "by order" in notes[0] and warnings == []
    assert_same_rig_geometry(calibrated, back)


def test_kalibr_import_warns_when_order_matching_puts_a_camera_far_from_its_declared_pose(calibrated):
    # Swap front_right and back in the declared rig: matched by order, the camera called
    # back now sits where the chain puts front_right, 0.2 m from its declared place.
    doc = yaml.safe_load(export.kalibr_camchain(calibrated).files["camchain.yaml"])
    for i, k in enumerate(doc):
        del doc[k]["rigcal_name"]
        doc[k]["rostopic"] = f"/cam{i}/image_raw"
    cams = calibrated.cameras
    swapped = calibrated.with_cameras([cams[0], cams[2], cams[1]])
    _, notes, warnings = export.rig_from_camchain(export.parse_camchain(doc, "c.yaml"), "c.yaml", swapped, "decl")
    assert "by order" in notes[0]
    assert any("cameras.back" in w and "matched" in w for w in warnings)


def test_kalibr_import_matches_by_rostopic_when_names_are_missing(calibrated):
    doc = yaml.safe_load(export.kalibr_camchain(calibrated).files["camchain.yaml"])
    for k in doc:
        del doc[k]["rigcal_name"]  # topics stay /<name>/image_raw
    cams = calibrated.cameras
    swapped = calibrated.with_cameras([cams[0], cams[2], cams[1]])
    back, notes, warnings = export.rig_from_camchain(export.parse_camchain(doc, "c.yaml"), "c.yaml", swapped, "decl")
    assert "by rostopic" in notes[0] and warnings == []
    assert_same_rig_geometry(swapped, back)


def test_kalibr_import_reads_none_distortion_and_notes_dropped_imu_keys(calibrated):
    doc = yaml.safe_load(export.kalibr_camchain(calibrated).files["camchain.yaml"])
    doc["cam2"].update(distortion_model="none", distortion_coeffs=[])
    doc["cam0"]["T_cam_imu"] = np.eye(4).tolist()
    back, notes, _ = export.rig_from_camchain(export.parse_camchain(doc, "c.yaml"), "c.yaml", body_from="cam0")
    assert back.camera("back").intrinsics.dist == (0.0,) * 5
    assert any("T_cam_imu" in n for n in notes)


def test_kalibr_import_body_from_cam0_gives_poses_relative_to_cam0(calibrated, tmp_path):
    camchain, imported = tmp_path / "camchain.yaml", tmp_path / "imported.yaml"
    assert cli("export", CALIBRATED, "--format", "kalibr", "--out", camchain).exit_code == 0
    r = cli("import", "--format", "kalibr", camchain, "--out", imported, "--body-from", "cam0")
    assert r.exit_code == 0, r.stderr
    assert "cam0's camera frame" in r.stdout and "not the drone's forward" in r.stdout
    back = load_rig(imported)
    T_cam0_body = geo.inv_T(calibrated.camera("front_left").T_body_cam)
    assert np.abs(back.camera("front_left").T_body_cam - np.eye(4)).max() == 0.0
    for c in calibrated.cameras:
        assert np.abs(back.camera(c.name).T_body_cam - T_cam0_body @ c.T_body_cam).max() < 1e-12


def test_kalibr_refuses_significant_k3_and_warns_on_tiny_k3(tmp_path):
    base = DECLARED.read_text()
    # f = 300 at the corner pixel (-0.5, -0.5): r_d = hypot(320.5, 240.5) / 300 = 1.335, and
    # dropping k3 moves the pixel by about f k3 r^7 (k3 small): 0.023 px for k3 = 1e-5.
    rig = parse_rig(base.replace("distortion: [0, 0, 0, 0, 0]\n    position: [0.10, 0.05", "distortion: [0, 0, 0, 0, 1.0e-5]\n    position: [0.10, 0.05"))
    shift, (u, v) = export.truncation_effect_px(rig.camera("front_left").intrinsics, 4)
    r_d = np.hypot(320.5, 240.5) / 300.0
    assert shift == pytest.approx(300.0 * 1e-5 * r_d**7, rel=0.01)
    assert {u, v} <= {-0.5, 639.5, 479.5}
    bad = tmp_path / "bad.yaml"
    bad.write_text(base.replace("distortion: [0, 0, 0, 0, 0]\n    position: [0.10, 0.05", "distortion: [0, 0, 0, 0, 1.0e-5]\n    position: [0.10, 0.05"))
    out = tmp_path / "camchain.yaml"
    r = cli("export", bad, "--format", "kalibr", "--out", out)
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and "cameras.front_left.distortion" in r.stderr and "0.01 px" in r.stderr
    assert not out.exists()
    tiny = tmp_path / "tiny.yaml"
    tiny.write_text(bad.read_text().replace("1.0e-5", "1.0e-6"))
    r = cli("export", tiny, "--format", "kalibr", "--out", out)
    assert r.exit_code == 0 and "warning" in r.stderr and "k3" in r.stderr
    assert yaml.safe_load(out.read_text())["cam0"]["distortion_coeffs"] == [0.0, 0.0, 0.0, 0.0]


# ----------------------------------------------------------------------------- gtsam


def _kalibr_poses_in_cam0(doc: dict) -> list[np.ndarray]:
    """T_cam0_camN from the chain of T_cn_cnm1, as any Kalibr consumer would build it."""
    poses = [np.eye(4)]
    for i in range(1, len(doc)):
        poses.append(poses[-1] @ np.linalg.inv(np.array(doc[f"cam{i}"]["T_cn_cnm1"])))
    return poses


def test_gtsam_cal3ds2_from_kalibr_and_json_numbers_projects_like_rigcal(calibrated):
    gtsam = pytest.importorskip("gtsam")  # declared in the [test] extra; skips only outside it
    # Cal3DS2 has no k3: the calibrated golden rig has k3 = 0 (or no k3 at all).
    doc = yaml.safe_load(export.kalibr_camchain(calibrated).files["camchain.yaml"])
    T_cam0 = _kalibr_poses_in_cam0(doc)
    T_body_cam0 = calibrated.camera(doc["cam0"]["rigcal_name"]).T_body_cam
    rig_json = json.loads(export.json_text(calibrated))
    for i, key in enumerate(doc):
        c = doc[key]
        cam = calibrated.camera(c["rigcal_name"])
        p_body = points_seen_by(cam, 1000, seed=i)
        want = cam.project_body(p_body).uv
        fu, fv, pu, pv = c["intrinsics"]
        k1, k2, p1, p2 = c["distortion_coeffs"]
        K = gtsam.Cal3DS2(fu, fv, 0.0, pu, pv, k1, k2, p1, p2)
        # Kalibr numbers: the camera's pose in cam0's frame, points moved into cam0's frame.
        pose = gtsam.Pose3(gtsam.Rot3(T_cam0[i][:3, :3]), gtsam.Point3(*T_cam0[i][:3, 3]))
        p_cam0 = geo.transform(geo.inv_T(T_body_cam0), p_body)
        camera = gtsam.PinholeCameraCal3DS2(pose, K)
        got = np.array([camera.project(gtsam.Point3(*p)) for p in p_cam0])
        assert np.abs(got - want).max() < 1e-9, key
        # JSON numbers: T_body_cam from rotation + position, intrinsics, OpenCV-order distortion.
        j = rig_json["cameras"][c["rigcal_name"]]
        d = (j["distortion"] + [0.0, 0.0])[:4]
        Kj = gtsam.Cal3DS2(j["intrinsics"]["fx"], j["intrinsics"]["fy"], 0.0, j["intrinsics"]["cx"],
                           j["intrinsics"]["cy"], *d)
        posej = gtsam.Pose3(gtsam.Rot3(np.array(j["rotation"])), gtsam.Point3(*j["position"]))
        cameraj = gtsam.PinholeCameraCal3DS2(posej, Kj)
        got = np.array([cameraj.project(gtsam.Point3(*p)) for p in p_body])
        assert np.abs(got - want).max() < 1e-9, key


def test_gtsam_cal3fisheye_from_kalibr_numbers_projects_like_rigcal(fisheye_rig):
    gtsam = pytest.importorskip("gtsam")
    if not hasattr(gtsam, "Cal3Fisheye"):
        pytest.skip("this gtsam has no Cal3Fisheye")
    doc = yaml.safe_load(export.kalibr_camchain(fisheye_rig).files["camchain.yaml"])
    T_cam0 = _kalibr_poses_in_cam0(doc)
    T_body_cam0 = fisheye_rig.camera(doc["cam0"]["rigcal_name"]).T_body_cam
    checked = 0
    for i, key in enumerate(doc):
        c = doc[key]
        if c["distortion_model"] != "equidistant":
            continue
        cam = fisheye_rig.camera(c["rigcal_name"])
        # In front of the lens only: gtsam's PinholeCamera refuses points behind it.
        p_body = points_seen_by(cam, 1000, seed=10 + i)
        p_cam = geo.transform(geo.inv_T(cam.T_body_cam), p_body)
        p_body, want = p_body[p_cam[:, 2] > 0.05], cam.project_body(p_body[p_cam[:, 2] > 0.05]).uv
        fu, fv, pu, pv = c["intrinsics"]
        K = gtsam.Cal3Fisheye(fu, fv, 0.0, pu, pv, *c["distortion_coeffs"])
        pose = gtsam.Pose3(gtsam.Rot3(T_cam0[i][:3, :3]), gtsam.Point3(*T_cam0[i][:3, 3]))
        camera = gtsam.PinholeCameraCal3Fisheye(pose, K)
        p_cam0 = geo.transform(geo.inv_T(T_body_cam0), p_body)
        got = np.array([camera.project(gtsam.Point3(*p)) for p in p_cam0])
        assert len(got) > 500 and np.abs(got - want).max() < 1e-9, key
        checked += 1
    assert checked == 2


# ----------------------------------------------------------------------------- opencv


CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)


def _read_fs(path: Path) -> cv2.FileStorage:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.isOpened(), path
    return fs


@pytest.mark.parametrize("which", ["calibrated", "fisheye"])
def test_opencv_export_rectifies_like_rigcal(which, calibrated, fisheye_rig, tmp_path):
    rig = calibrated if which == "calibrated" else fisheye_rig
    src = tmp_path / "rig.yaml"
    save_rig(rig, src)
    out = tmp_path / "cv"
    r = cli("export", src, "--format", "opencv", "--out", out)
    assert r.exit_code == 0, r.stderr
    pair = rig.stereo_pairs[0]
    fs = _read_fs(out / f"stereo_{pair.left}_{pair.right}.yaml")
    left, right = rig.camera(pair.left), rig.camera(pair.right)
    rect = rectify_pair(left, right)
    # x_right = R x_left + T, metres
    T_rl = geo.inv_T(right.T_body_cam) @ left.T_body_cam
    assert np.array_equal(fs.getNode("R").mat(), T_rl[:3, :3])
    assert np.array_equal(fs.getNode("T").mat().ravel(), T_rl[:3, 3])
    size = fs.getNode("image_size")
    assert (int(size.at(0).real()), int(size.at(1).real())) == rect.size
    fisheye = left.intrinsics.model == "fisheye"
    undistort = cv2.fisheye.undistortPoints if fisheye else cv2.undistortPoints
    for side, cam, n in (("left", left, "1"), ("right", right, "2")):
        K, D = fs.getNode("K" + n).mat(), fs.getNode("D" + n).mat()
        R, P = fs.getNode("R" + n).mat(), fs.getNode("P" + n).mat()
        assert fs.getNode("model" + n).string() == cam.intrinsics.model
        p_body = points_seen_by(cam, 1000, seed=3, depth=(1.0, 15.0))
        pr = cam.project_body(p_body)
        uv = pr.uv[pr.in_image]
        if fisheye:
            # Rays past ~80 deg from the axis would land far outside the rectified image.
            uv = uv[np.linalg.norm(uv - cam.intrinsics.K[:2, 2], axis=1) < 250]
        got = undistort(uv.reshape(-1, 1, 2), K, D, R=R, P=P, criteria=CRITERIA).reshape(-1, 2)
        want = rectify_pixels(rect, cam, uv, side)
        assert len(uv) > 300
        assert np.abs(got - want).max() < 1e-6, side


def test_opencv_camera_files_hold_the_rig_numbers(calibrated, tmp_path):
    out = tmp_path / "cv"
    assert cli("export", CALIBRATED, "--format", "opencv", "--out", out).exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "camera_back.yaml", "camera_front_left.yaml", "camera_front_right.yaml", "stereo_front_left_front_right.yaml"]
    for cam in calibrated.cameras:
        fs = _read_fs(out / f"camera_{cam.name}.yaml")
        m = cam.intrinsics
        assert fs.getNode("camera_name").string() == cam.name
        assert np.array_equal(fs.getNode("K").mat(), m.K)
        D = fs.getNode("D").mat().ravel()
        assert np.array_equal(D[: len(m.dist)], m.dist) and not D[len(m.dist):].any()
        assert np.array_equal(fs.getNode("T_body_cam").mat(), cam.T_body_cam)
        # OpenCV's own projection with these numbers lands on rigcal's pixels.
        p_body = points_seen_by(cam, 200, seed=5)
        p_cam = geo.transform(geo.inv_T(cam.T_body_cam), p_body)
        uv_cv = cv2.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), fs.getNode("K").mat(), D)[0]
        assert np.abs(uv_cv.reshape(-1, 2) - cam.project_body(p_body).uv).max() < 1e-9


# ----------------------------------------------------------------------------- ros


# camera_calibration_parsers/src/parse_yml.cpp writes exactly these keys, in this order.
ROS_LAYOUT = {
    "image_width": None, "image_height": None, "camera_name": None,
    "camera_matrix": (3, 3), "distortion_model": None, "distortion_coefficients": (1, None),
    "rectification_matrix": (3, 3), "projection_matrix": (3, 4),
}


def check_camera_info(doc: dict) -> None:
    assert list(doc) == list(ROS_LAYOUT)
    assert type(doc["image_width"]) is int and type(doc["image_height"]) is int
    assert isinstance(doc["camera_name"], str)
    for key, shape in ROS_LAYOUT.items():
        if shape is None:
            continue
        block = doc[key]
        assert list(block) == ["rows", "cols", "data"], key
        rows, cols = shape
        assert block["rows"] == rows
        if cols is not None:
            assert block["cols"] == cols
        assert len(block["data"]) == block["rows"] * block["cols"]
        assert all(isinstance(x, float) for x in block["data"])


def test_ros_files_have_the_camera_info_layout_and_models(calibrated, fisheye_rig, tmp_path):
    out = tmp_path / "ros"
    r = cli("export", CALIBRATED, "--format", "ros", "--out", out)
    assert r.exit_code == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["back.yaml", "front_left.yaml", "front_right.yaml"]
    rect = rectify_pair(calibrated.camera("front_left"), calibrated.camera("front_right"))
    for cam in calibrated.cameras:
        doc = yaml.safe_load((out / f"{cam.name}.yaml").read_text())
        check_camera_info(doc)
        assert doc["camera_name"] == cam.name
        assert doc["distortion_model"] == "plumb_bob" and doc["distortion_coefficients"]["cols"] == 5
        d = doc["distortion_coefficients"]["data"]
        assert d[: len(cam.intrinsics.dist)] == list(cam.intrinsics.dist) and not any(d[len(cam.intrinsics.dist):])
        R = np.reshape(doc["rectification_matrix"]["data"], (3, 3))
        P = np.reshape(doc["projection_matrix"]["data"], (3, 4))
        if cam.name == "back":
            assert np.array_equal(R, np.eye(3))
            assert np.array_equal(P, np.column_stack([cam.intrinsics.K, np.zeros(3)]))
        else:
            want_R, want_P = (rect.R1, rect.P1) if cam.name == "front_left" else (rect.R2, rect.P2)
            assert np.array_equal(R, want_R) and np.array_equal(P, want_P)
    # Right camera: P[0, 3] = -fx' * baseline, ROS's stereo convention.
    P2 = np.reshape(yaml.safe_load((out / "front_right.yaml").read_text())["projection_matrix"]["data"], (3, 4))
    assert P2[0, 3] == pytest.approx(-P2[0, 0] * rect.baseline_m, rel=1e-12)

    files = export.ros_files(fisheye_rig).files
    for name, text in files.items():
        check_camera_info(yaml.safe_load(text))
    fe = yaml.safe_load(files["fe_left.yaml"])
    assert fe["distortion_model"] == "equidistant" and fe["distortion_coefficients"]["cols"] == 4


@pytest.mark.parametrize("n, model, cols", [(2, "plumb_bob", 5), (4, "plumb_bob", 5), (5, "plumb_bob", 5),
                                            (8, "rational_polynomial", 8)])
def test_ros_distortion_model_by_coefficient_count(n, model, cols):
    dist = [-0.02, 0.003, 0.0001, -0.0002, 0.0004, 0.001, 0.0002, 0.0001][:n]
    text = DECLARED.read_text().replace("distortion: [0, 0, 0, 0, 0]\n    position: [0.10, 0.05",
                                        f"distortion: {dist}\n    position: [0.10, 0.05")
    doc = yaml.safe_load(export.ros_files(parse_rig(text)).files["front_left.yaml"])
    check_camera_info(doc)
    assert (doc["distortion_model"], doc["distortion_coefficients"]["cols"]) == (model, cols)
    assert doc["distortion_coefficients"]["data"][:n] == dist


# ----------------------------------------------------------------------------- golden files


def _load_regenerate():
    spec = importlib.util.spec_from_file_location("golden_regenerate", GOLDEN / "regenerate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_exports_equal_the_golden_files_as_data(tmp_path):
    # As data with golden_data's tolerance, never byte for byte: the last digit of a
    # quaternion differs between machines.
    regen = _load_regenerate()
    fresh = regen.write_goldens(tmp_path)
    stored = sorted(p for p in regen.EXPORTS.rglob("*") if p.is_file())
    assert [p.relative_to(tmp_path) for p in fresh] == [p.relative_to(regen.EXPORTS) for p in stored], \
        "the set of exported files changed; run `make golden` and review the diff"
    for new, old in zip(fresh, stored):
        diffs = golden_data.file_differences(new, old)
        assert not diffs, f"{old.relative_to(ROOT)} differs from the current export at " + "; ".join(diffs[:5]) + \
            " (run `make golden` and review the diff)"


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"),
                    reason="OPENBLAS_CORETYPE=Prescott names an x86-64 kernel")
def test_goldens_written_with_another_blas_kernel_equal_as_data(tmp_path):
    # Another machine, as far as one machine can be: numpy's OpenBLAS forced onto its
    # oldest x86-64 kernel rewrites the last digits of several exported floats here
    # (4 of 18 files differed as text when this test was written); as data they must agree.
    script = (
        "import importlib.util, sys; from pathlib import Path\n"
        f"spec = importlib.util.spec_from_file_location('r', {str(GOLDEN / 'regenerate.py')!r})\n"
        "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)\n"
        "m.write_goldens(Path(sys.argv[1]))\n")
    env = {**os.environ, "OPENBLAS_CORETYPE": "Prescott"}
    subprocess.run([sys.executable, "-c", script, str(tmp_path)], check=True, env=env, cwd=tmp_path)
    stored = sorted(p for p in (GOLDEN / "exports").rglob("*") if p.is_file())
    for old in stored:
        new = tmp_path / old.relative_to(GOLDEN / "exports")
        assert golden_data.file_differences(new, old) == [], old.relative_to(ROOT)


def _perturbed(doc, rng, scale):
    """doc with every float moved by a relative `scale` (signs random); ints and strings kept."""
    if isinstance(doc, dict):
        return {k: _perturbed(v, rng, scale) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_perturbed(v, rng, scale) for v in doc]
    if isinstance(doc, float):
        return doc * (1 + scale * rng.choice([-1.0, 1.0]))
    return doc


@pytest.mark.parametrize("name", ["drone-stereo-back-calibrated/rig.json",
                                  "drone-stereo-back-calibrated/camchain.yaml",
                                  "drone-stereo-back-calibrated/opencv/stereo_front_left_front_right.yaml",
                                  "drone-stereo-back-calibrated/ros/front_left.yaml"])
def test_golden_comparison_passes_ulps_and_fails_real_changes(name):
    stored, _ = golden_data.load(GOLDEN / "exports" / name)
    rng = np.random.default_rng(0)
    assert golden_data.differences(stored, stored) == []
    # a few ulp everywhere, as another CPU or BLAS gives: equal
    assert golden_data.differences(_perturbed(stored, rng, 4 * np.finfo(float).eps), stored) == []
    # a change of 1e-9 relative in every number: caught, with the key path named
    found = golden_data.differences(_perturbed(stored, rng, 1e-9), stored)
    assert found and all(": " in d for d in found)


def test_golden_comparison_names_the_key_path_of_a_change():
    stored, _ = golden_data.load(GOLDEN / "exports" / "drone-stereo-back-calibrated" / "rig.json")
    changed = json.loads(json.dumps(stored))
    changed["cameras"]["back"]["model"] = "fisheye"
    changed["cameras"]["front_left"]["intrinsics"]["fx"] += 1e-6
    changed["cameras"]["front_right"]["extra_key"] = 1
    found = golden_data.differences(changed, stored)
    assert any(d.startswith("cameras.back.model: 'pinhole' became 'fisheye'") for d in found), found
    assert any(d.startswith("cameras.front_left.intrinsics.fx: ") for d in found), found
    assert any(d.startswith("cameras.front_right: keys ") for d in found), found
    assert len(found) == 3


def test_golden_comparison_reads_opencv_matrices_and_comments(tmp_path):
    src = GOLDEN / "exports" / "drone-stereo-back" / "opencv" / "stereo_front_left_front_right.yaml"
    doc, comments = golden_data.load(src)
    assert doc["K1"]["!!opencv-matrix"]["data"] == [300, 0, 320, 0, 300, 240, 0, 0, 1]
    assert comments and comments[0].startswith("# stereo pair front_left")
    edited = tmp_path / src.name
    edited.write_text(src.read_text().replace("written by rigcal", "written by someone"))
    assert golden_data.file_differences(edited, src) == [f"comment lines changed: {comments} became "
                                                         f"{golden_data.load(edited)[1]}"]


# ----------------------------------------------------------------------------- error paths


def _one_line_error(r, code: int = 2) -> str:
    assert r.exit_code == code, (r.exit_code, r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("rigcal: "), r.stderr
    assert "Traceback" not in r.stderr
    return r.stderr


@pytest.mark.parametrize("fmt", export.FORMATS)
def test_unwritable_out_is_exit_2_one_line(fmt, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    msg = _one_line_error(cli("export", CALIBRATED, "--format", fmt, "--out", blocker / "out"))
    assert "a_file" in msg


def test_rig_file_with_errors_is_exit_2_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(DECLARED.read_text().replace("axes: [-L, -U, F]", "axes: [-L, -U, L]", 1))
    out = tmp_path / "out.json"
    msg = _one_line_error(cli("export", bad, "--format", "json", "--out", out))
    assert "bad.yaml" in msg and "cameras.front_left.axes" in msg
    assert not out.exists()


def test_folder_export_never_replaces_a_non_empty_folder(tmp_path):
    out = tmp_path / "ros"
    out.mkdir()
    (out / "mine.txt").write_text("keep me")
    _one_line_error(cli("export", CALIBRATED, "--format", "ros", "--out", out))
    assert [p.name for p in out.iterdir()] == ["mine.txt"]


def test_failed_folder_export_leaves_nothing_behind(tmp_path):
    # The back camera has no pose but is in a stereo pair: the export fails before writing.
    text = DECLARED.read_text().replace("    position: [-0.10, 0.0, 0.01]\n    axes: [L, -U, -F]\n", "")
    text = text.replace("  - [front_left, front_right]", "  - [front_left, front_right]\n  - [front_left, back]")
    src = tmp_path / "rig.yaml"
    src.write_text(text)
    msg = _one_line_error(cli("export", src, "--format", "opencv", "--out", tmp_path / "cv"))
    assert "cameras.back" in msg and "no pose" in msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]
    msg = _one_line_error(cli("export", src, "--format", "kalibr", "--out", tmp_path / "c.yaml"))
    assert "cameras.back" in msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]


def test_import_needs_a_body_frame(tmp_path):
    camchain = tmp_path / "camchain.yaml"
    assert cli("export", CALIBRATED, "--format", "kalibr", "--out", camchain).exit_code == 0
    msg = _one_line_error(cli("import", "--format", "kalibr", camchain, "--out", tmp_path / "r.yaml"))
    assert "--rig" in msg and "--body-from" in msg
    msg = _one_line_error(cli("import", "--format", "kalibr", camchain, "--out", tmp_path / "r.yaml",
                              "--body-from", "cam7"))
    assert "cam7" in msg
    assert not (tmp_path / "r.yaml").exists()


@pytest.mark.parametrize("edit, where", [
    (lambda d: d["cam1"].update(camera_model="omni"), "cam1.camera_model"),
    (lambda d: d["cam2"].pop("T_cn_cnm1"), "cam2.T_cn_cnm1"),
    (lambda d: d["cam1"].update(distortion_model="fov", distortion_coeffs=[0.9]), "cam1.distortion_model"),
    (lambda d: d["cam1"]["T_cn_cnm1"][0].__setitem__(0, 2.0), "cam1.T_cn_cnm1"),
    (lambda d: d["cam0"].update(resolution=[640.5, 480]), "cam0.resolution"),
    (lambda d: d.update(imu0={}), "imu0"),
])
def test_import_refuses_bad_camchains_naming_the_key(edit, where, calibrated, tmp_path):
    doc = yaml.safe_load(export.kalibr_camchain(calibrated).files["camchain.yaml"])
    edit(doc)
    src = tmp_path / "camchain.yaml"
    src.write_text(yaml.safe_dump(doc))
    msg = _one_line_error(cli("import", "--format", "kalibr", src, "--out", tmp_path / "r.yaml", "--body-from", "cam0"))
    assert where in msg
