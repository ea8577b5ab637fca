"""Calibration on real photographs against published references (docs/accuracy.md, "Real image sets").

Each test compares with an independent answer: a published calibration, or OpenCV's own
stereoCalibrate run on the same corners. Gaps to the published numbers are measured and
explained in README ("Real image sets"); the bounds here are those measured figures with
a small margin, not loosened until they pass.
"""

from __future__ import annotations

import subprocess
import sys
try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: tomllib is 3.11+
    import tomli as tomllib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

import rigcal
from rigcal.core import geometry as geo
from rigcal.camcal.pipeline import calibrate_views
from rigcal.data.dataset import list_dataset
from rigcal.detect.detect import detect_dataset
from rigcal.core.target import load_target

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "samples" / "real"
SHARED = ROOT.parent / "shared" / "data" / "real"


def _detect(ds: Path, rig=None):
    rig = rig or rigcal.load_rig(ds / "rig.yaml")
    target = load_target(ds / "target.yaml")
    det = detect_dataset(list_dataset(ds, rig), target, rig=rig, jobs=1, progress=False)
    views = [replace(v, sigma=None) for v in det.views]
    return rig, target, views


def _baseline(cal) -> float:
    p = cal.rig.stereo_pairs[0]
    return float(np.linalg.norm(cal.rig.camera(p.left).T_body_cam[:3, 3] - cal.rig.camera(p.right).T_body_cam[:3, 3]))


@pytest.fixture(scope="module")
def bumblebee():
    return _detect(SAMPLES / "bumblebee2")


def test_bumblebee2_baseline_against_boofcv(bumblebee):
    """BoofCV's reference (radial2 model): 120.05 mm; the target is 0.2 mm. With the
    same model rigcal is 0.10 mm away.

    `auto` estimates decentering (radtan4, the floor of auto; pipeline.py says why) and must
    not take k3, the term that overfits this 11-pair set (120.48 mm). Its
    baseline, 120.27 mm, is 0.22 mm from BoofCV's radial2 figure: the joint solve finds
    both cameras' decentering significant (Wald 9 and 35 against 6 at 5 %), so the 0.11 mm
    between radial2 and radtan4 is the model, not noise (docs/accuracy.md, "Real image sets")."""
    rig, target, views = bumblebee
    corners = {b.name: b.corners for b in target.boards}
    cal2 = calibrate_views(views, rig, corners, distortion="radial2")
    assert abs(1000 * _baseline(cal2) - 120.05) < 0.2
    assert cal2.flips == 1  # pair 11: the right camera's corner order is reversed (README of the set)
    auto = calibrate_views(views, rig, corners, distortion="auto")
    assert [auto.stats[n].distortion_model for n in ("left", "right")] == ["radtan4", "radtan4"]
    four = calibrate_views(views, rig, corners, distortion="radtan4")
    assert abs(_baseline(auto) - _baseline(four)) < 1e-6
    assert auto.rms_px < 0.1
    # focal lengths within 0.2 % of BoofCV's
    for name, fx in (("left", 524.6142), ("right", 526.4373)):
        assert abs(cal2.rig.camera(name).intrinsics.fx / fx - 1) < 2e-3


def test_opencv_sample_pairs_against_opencv_on_the_same_corners():
    """The baseline in squares equals OpenCV's stereoCalibrate run on rigcal's corners to
    0.1 %, and is within 0.6 % of the published 3.345 squares, which came from cornerSubPix
    corners that fit 2.6x worse (0.45 px RMS against rigcal's 0.17 px)."""
    rig, target, views = _detect(SAMPLES / "opencv_stereo")
    board = target.boards[0]
    cal = calibrate_views(views, rig, {board.name: board.corners}, distortion="radtan5")
    squares = _baseline(cal) / board.square_length
    # OpenCV's own stereo calibration on exactly these corners (full views only)
    by = {}
    for v in views:
        if len(v.ids) == board.n_corners:
            by.setdefault(v.frame, {})[v.camera] = v.uv[np.argsort(v.ids)].astype(np.float32)
    frames = [f for f in sorted(by) if len(by[f]) == 2]
    obj = [board.corners.astype(np.float32)] * len(frames)
    left = [by[f]["left"] for f in frames]
    right = [by[f]["right"] for f in frames]
    _, K1, D1, _, _ = cv2.calibrateCamera(obj, left, (640, 480), None, None)
    _, K2, D2, _, _ = cv2.calibrateCamera(obj, right, (640, 480), None, None)
    out = cv2.stereoCalibrate(obj, left, right, K1, D1, K2, D2, (640, 480), flags=cv2.CALIB_FIX_INTRINSIC)
    opencv_squares = float(np.linalg.norm(out[6])) / board.square_length
    assert abs(squares / opencv_squares - 1) < 1e-3
    assert abs(squares / 3.345 - 1) < 6e-3
    assert cal.rms_px < 0.25


def _caliscope(tmp_path_factory):
    if not (SHARED / "caliscope_4cam_charuco_a").is_dir():
        pytest.skip("../shared/data/real is not beside this checkout")
    out = tmp_path_factory.mktemp("real")
    subprocess.run([sys.executable, str(SAMPLES / "make_datasets.py"), str(out), "caliscope"], check=True,
                   capture_output=True)
    return out / "caliscope"


def _caliscope_reference():
    doc = tomllib.loads((SHARED / "caliscope_4cam_charuco_a" / "camera_array.toml").read_text())
    cams = {}
    for k, v in doc["cameras"].items():
        R, t = np.array(v["rotation"]), np.array(v["translation"])  # world -> camera
        cams[f"cam_{k}"] = dict(T_cam_world=geo.make_T(R, t), K=np.array(v["matrix"]), dist=v["distortions"],
                                size=v["size"])
    return cams


@pytest.fixture(scope="module")
def caliscope(tmp_path_factory):
    ds = _caliscope(tmp_path_factory)
    ref = _caliscope_reference()
    rig_doc = yaml.safe_load((ds / "rig.yaml").read_text())
    # The reference's intrinsics came from separate recordings; declare them, as caliscope did.
    for name, c in ref.items():
        K = c["K"]
        rig_doc["cameras"][name]["intrinsics"] = {"fx": float(K[0, 0]), "fy": float(K[1, 1]),
                                                  "cx": float(K[0, 2]), "cy": float(K[1, 2])}
        rig_doc["cameras"][name]["distortion"] = [float(x) for x in c["dist"]]
    rig = rigcal.core.rig.rig_from_dict(rig_doc, "caliscope-with-reference-intrinsics")
    rig_plain, target, views = _detect(ds)
    return rig, rig_plain, target, views, ref


def _pair_errors(cal, ref):
    out = {}
    names = cal.rig.names
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            T_ab = geo.inv_T(cal.rig.camera(a).T_body_cam) @ cal.rig.camera(b).T_body_cam  # b -> a
            R_ab = ref[a]["T_cam_world"] @ geo.inv_T(ref[b]["T_cam_world"])
            out[(a, b)] = (1000 * abs(np.linalg.norm(T_ab[:3, 3]) - np.linalg.norm(R_ab[:3, 3])),
                           1000 * np.linalg.norm(T_ab[:3, 3] - R_ab[:3, 3]),
                           geo.rotation_angle_deg(T_ab[:3, :3] @ R_ab[:3, :3].T))
    return out


@pytest.mark.slow
def test_caliscope_four_cameras_with_reference_intrinsics(caliscope):
    """Inverted board, software sync (up to 43 ms), no declared poses: with caliscope's own
    intrinsics every pair lands within 2.5 cm and 2 deg of caliscope's extrinsics."""
    rig, _, target, views, ref = caliscope
    cal = calibrate_views(views, rig, {b.name: b.corners for b in target.boards}, fix_intrinsics=True)
    for pair, (d_dist, d_vec, d_rot) in _pair_errors(cal, ref).items():
        assert d_vec < 25.0 and d_rot < 2.0, (pair, d_dist, d_vec, d_rot)


@pytest.mark.slow
def test_caliscope_four_cameras_from_the_images_alone(caliscope):
    """From these images alone (a 12-corner board, 26-45 views per camera, software sync):
    the joint solve fits 0.9 px against 0.04-0.08 px per camera alone, so rigcal takes the
    intrinsics from each camera's own views (pipeline.rigidity_check), with fx = fy and the
    principal point at the image centre unless its own views reject them. They
    land within 1.6 % of caliscope's focal lengths (the joint solve had bent them 10-16 %),
    and the pairs 0.7-4.2 cm and 1.4-3.2 deg from caliscope's solution: the issue's
    2.5 cm / 2 deg is not met from these images alone (docs/accuracy.md, "Real image sets": the gap
    is the principal points, which these views cannot place)."""
    _, rig_plain, target, views, ref = caliscope
    cal = calibrate_views(views, rig_plain, {b.name: b.corners for b in target.boards})
    assert set(cal.rig.names) == {"cam_0", "cam_1", "cam_2", "cam_3"}
    assert any("disagree with one rigid rig per frame" in n for n in cal.notes), cal.notes
    for n in cal.rig.names:
        K = ref[n]["K"]
        m = cal.rig.camera(n).intrinsics
        assert abs(m.fx / K[0, 0] - 1) < 0.02 and abs(m.fy / K[1, 1] - 1) < 0.02, (n, m.fx, m.fy)
    errs = _pair_errors(cal, ref)
    assert max(e[1] for e in errs.values()) < 60.0 and max(e[2] for e in errs.values()) < 4.0, errs
    # the focal lengths are never resolved apart on these views; each camera's choice is logged
    models = {n: cal.stats[n].intrinsics_model for n in cal.rig.names}
    assert sum(m["focal"] == "fx=fy" for m in models.values()) >= 2, models
    assert all(any("own views:" in x for x in cal.stats[n].model_selection) for n in cal.rig.names)
