"""Detection on real photographs: the committed samples (samples/real/) and, when the shared
copy is present, a few images of the bigger sets linked by samples/real/make_datasets.py."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from rigcal.detect.board_detectors import BoardDetector
from rigcal.data.dataset import list_dataset
from rigcal.detect.detect import detect_dataset
from rigcal.data.image_read import read_gray
from rigcal.core.rig import load_rig
from rigcal.core.target import Target, load_target

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "samples" / "real"
sys.path.insert(0, str(SAMPLES))
import make_datasets  # noqa: E402  (samples/real/make_datasets.py)

shared = pytest.mark.skipif(not make_datasets.REAL.is_dir(), reason="../shared/data/real is not here")


def _detect(dataset: Path, **kw):
    rig = load_rig(dataset / "rig.yaml")
    return detect_dataset(list_dataset(dataset, rig), load_target(dataset / "target.yaml"), rig=rig,
                          progress=False, **kw)


def test_bumblebee2_every_pair_full_board_flagged_ambiguous():
    res = _detect(SAMPLES / "bumblebee2", jobs=2)
    assert res.n_images == {"left": 11, "right": 11}
    assert res.unreadable == [] and res.size_mismatch == []
    for cam in ("left", "right"):
        views = res.views_of(cam)
        assert len(views) == 11
        assert all(len(v.ids) == 24 and v.ambiguous for v in views)


def test_bumblebee2_refined_corners_calibrate_below_a_tenth_of_a_pixel():
    """Left camera alone, BoofCV's lens model (2 radial coefficients). Measured: 0.147 px
    RMS with OpenCV's corners, 0.077 px refined (BoofCV's own reference: 0.083 px)."""
    images = list_dataset(SAMPLES / "bumblebee2", ["left", "right"])
    target = load_target(SAMPLES / "bumblebee2" / "target.yaml")
    board = target.boards[0]
    rms = {}
    for mode in ("none", "symmetric"):
        det = BoardDetector(target, refine=mode)
        obj, img = [], []
        for path in images.frames["left"].values():
            for _, ids, uv, _ in det.detect(read_gray(path)[0])[0]:
                obj.append(board.corners[ids].astype(np.float32))
                img.append(uv.astype(np.float32))
        rms[mode] = cv2.calibrateCamera(obj, img, (640, 480), None, None,
                                        flags=cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3)[0]
    assert rms["symmetric"] < 0.10, rms
    assert rms["none"] > 1.5 * rms["symmetric"], rms


def test_opencv_stereo_every_pair_full_board_in_the_same_order():
    res = _detect(SAMPLES / "opencv_stereo", jobs=1)
    assert res.n_images == {"left": 13, "right": 13}
    left = {v.frame: v for v in res.views_of("left")}
    right = {v.frame: v for v in res.views_of("right")}
    assert len(left) == len(right) == 13
    for frame, vl in left.items():
        vr = right[frame]
        assert len(vl.ids) == len(vr.ids) == 54 and not vl.ambiguous
        # a non-symmetric board keeps its order: corners 0 and 53 are the same physical
        # corners in both cameras (one common disparity), not swapped end for end
        same = np.linalg.norm(vl.uv[0] - vr.uv[0]) + np.linalg.norm(vl.uv[-1] - vr.uv[-1])
        swapped = np.linalg.norm(vl.uv[0] - vr.uv[-1]) + np.linalg.norm(vl.uv[-1] - vr.uv[0])
        assert same < 0.5 * swapped, frame


@shared
def test_caliscope_inverted_board_is_found(tmp_path):
    ds = make_datasets.build_caliscope(tmp_path / "caliscope")
    images = list_dataset(ds, load_rig(ds / "rig.yaml"))
    det = BoardDetector(load_target(ds / "target.yaml"))
    for cam in ("cam_0", "cam_2"):
        paths = list(images.frames[cam].values())[10:14]
        views = [v for p in paths for v in det.detect(read_gray(p)[0])[0]]
        assert len(views) == 4, cam
        assert all(6 <= len(ids) <= 12 and name == "charuco" for name, ids, _, _ in views)


@shared
def test_wideangle_legacy_board_corner_counts(tmp_path):
    """The set's README: a median of 265 / 261 corners per image with legacy_pattern true.
    With the flag wrong, OpenCV reads this 31 x 16 board as one shifted by a square: the
    same pixels get ids off by one (or, in some images, nothing)."""
    from dataclasses import replace

    ds = make_datasets.build_wideangle(tmp_path / "wideangle")
    images = list_dataset(ds, load_rig(ds / "rig.yaml"))
    target = load_target(ds / "target.yaml")
    board = target.boards[0]
    assert board.legacy_pattern
    right, modern = BoardDetector(target), BoardDetector(Target((replace(board, legacy_pattern=False),)))
    counts = []
    for stem in ("p0_1", "p2_6"):
        (_, ids, uv, _), = right.detect(read_gray(images.frames["left"][stem])[0])[0]
        counts.append(len(ids))
    assert min(counts) >= 200
    (_, ids_m, uv_m, _), = modern.detect(read_gray(images.frames["left"]["p0_1"])[0])[0]
    (_, ids_l, uv_l, _), = right.detect(read_gray(images.frames["left"]["p0_1"])[0])[0]
    assert np.allclose(uv_m, uv_l) and np.array_equal(ids_m, ids_l + 1)
    assert modern.detect(read_gray(images.frames["left"]["p2_6"])[0])[0] == []


@shared
def test_trinocular_symmetric_chessboard_is_ambiguous(tmp_path):
    ds = make_datasets.build_trinocular(tmp_path / "trinocular")
    images = list_dataset(ds, load_rig(ds / "rig.yaml"))
    det = BoardDetector(load_target(ds / "target.yaml"))
    views = [v for p in (images.frames["left"]["01"], images.frames["middle"]["01"])
             for v in det.detect(read_gray(p)[0])[0]]
    assert len(views) == 2
    assert all(amb and len(ids) >= 110 for _, ids, _, amb in views)


@shared
def test_make_datasets_links_instead_of_copying(tmp_path):
    ds = make_datasets.build_trinocular(tmp_path / "t")
    files = list((ds / "images" / "left").iterdir())
    assert len(files) == 30 and all(f.is_symlink() for f in files)
    assert make_datasets.main([str(tmp_path / "x"), "nosuchset"]) == 2
