"""The dataset layout (../shared/spec/dataset.md): which file is which camera's which frame,
and the layout faults (undeclared folder, missing folder, missing frame)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.data.dataset import (DatasetImages, check_shared_stems, dataset_rig_path, dataset_target_path,
                                 frame_sort_key, list_dataset)
from rigcal.errors import DatasetError

RIG = """
rig: t
body_frame: FLU
cameras:
  left: {model: pinhole, resolution: [64, 48], intrinsics: {focal: 50.0}, position: [0, 0.05, 0], look: forward}
  right: {model: pinhole, resolution: [64, 48], intrinsics: {focal: 50.0}, position: [0, -0.05, 0], look: forward}
"""
TARGET = """
boards:
  - {name: b, type: charuco, dictionary: DICT_4X4_50, squares: [5, 4], square_length: 0.04, marker_length: 0.03}
"""


def _img(path: Path) -> Path:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.full((48, 64), 128, np.uint8))
    return path


def _dataset(root: Path, frames: dict[str, list[str]], ext: str = ".png") -> Path:
    (root / "rig.yaml").parent.mkdir(parents=True, exist_ok=True)
    (root / "rig.yaml").write_text(RIG)
    (root / "target.yaml").write_text(TARGET)
    for cam, stems in frames.items():
        (root / "images" / cam).mkdir(parents=True, exist_ok=True)
        for s in stems:
            _img(root / "images" / cam / f"{s}{ext}")
    return root


def test_lists_frames_in_natural_order_and_allows_a_missing_frame(tmp_path):
    ds = _dataset(tmp_path / "d", {"left": ["img10", "img2", "img1"], "right": ["img1", "img10"]})
    images = list_dataset(ds, ["left", "right"])
    assert isinstance(images, DatasetImages)
    assert images.cameras == ("left", "right")
    assert list(images.frames["left"]) == ["img1", "img2", "img10"]
    assert list(images.frames["right"]) == ["img1", "img10"]  # right lacks img2: fine
    assert images.all_frames == ("img1", "img2", "img10")
    assert images.n_images == 5
    assert [(c, f) for c, f, _ in images.items()] == [("left", "img1"), ("left", "img2"), ("left", "img10"),
                                                       ("right", "img1"), ("right", "img10")]
    assert images.frames["left"]["img2"] == ds / "images" / "left" / "img2.png"


def test_accepts_a_rig_object_and_every_extension_in_any_case(tmp_path):
    from rigcal.core.rig import load_rig

    ds = _dataset(tmp_path / "d", {"left": [], "right": []})
    for i, ext in enumerate([".png", ".JPG", ".jpeg", ".Bmp", ".tif", ".TIFF"]):
        _img(ds / "images" / "left" / f"{i:02d}{ext}")
        _img(ds / "images" / "right" / f"{i:02d}{ext}")
    (ds / "images" / "left" / "notes.txt").write_text("not an image")
    (ds / "images" / "left" / ".hidden.png").write_bytes(b"")
    images = list_dataset(ds, load_rig(ds / "rig.yaml"))
    assert list(images.frames["left"]) == [f"{i:02d}" for i in range(6)]
    assert images.frames["left"]["01"].name == "01.JPG"


def test_symbolic_links_to_images_and_to_camera_folders_work(tmp_path):
    store = tmp_path / "store"
    a, b = _img(store / "a.png"), _img(store / "b.png")
    ds = _dataset(tmp_path / "d", {"left": []})
    os.symlink(a, ds / "images" / "left" / "0001.png")
    os.symlink(b, ds / "images" / "left" / "0002.png")
    os.symlink(ds / "images" / "left", ds / "images" / "right", target_is_directory=True)
    images = list_dataset(ds, ["left", "right"])
    assert list(images.frames["right"]) == ["0001", "0002"]
    assert images.frames["left"]["0001"].resolve() == a.resolve()


def test_folder_for_an_undeclared_camera_names_folder_and_declared_cameras(tmp_path):
    ds = _dataset(tmp_path / "d", {"left": ["1"], "right": ["1"], "back": ["1"]})
    with pytest.raises(DatasetError) as e:
        list_dataset(ds, ["left", "right"])
    msg = str(e.value)
    assert "images/back/" in msg and "not a camera of the rig" in msg and "left, right" in msg
    assert "\n" not in msg


def test_declared_camera_without_folder_names_both(tmp_path):
    ds = _dataset(tmp_path / "d", {"left": ["1"]})
    with pytest.raises(DatasetError) as e:
        list_dataset(ds, ["left", "right"])
    msg = str(e.value)
    assert "camera right has no folder images/right/" in msg and "left, right" in msg


def test_misspelt_folder_gets_both_faults_and_a_hint(tmp_path):
    ds = _dataset(tmp_path / "d", {"left": ["1"], "rigth": ["1"]})
    with pytest.raises(DatasetError) as e:
        list_dataset(ds, ["left", "right"])
    msg = str(e.value)
    assert "images/rigth/" in msg and "camera right has no folder" in msg and "images/rigth/ -> images/right/?" in msg


def test_missing_images_folder_and_missing_dataset(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(DatasetError, match=r"images: missing .*images/left/"):
        list_dataset(tmp_path / "d", ["left"])
    (tmp_path / "d" / "images").write_text("not a folder")
    with pytest.raises(DatasetError, match=r"images: not a folder \(expected .*images/left/"):
        list_dataset(tmp_path / "d", ["left"])
    with pytest.raises(DatasetError, match="not a folder"):
        list_dataset(tmp_path / "nowhere", ["left"])


def test_empty_camera_folder_and_duplicate_frame_are_refused(tmp_path):
    ds = _dataset(tmp_path / "d", {"left": ["1"], "right": []})
    with pytest.raises(DatasetError, match=r"right: no images"):
        list_dataset(ds, ["left", "right"])
    _img(ds / "images" / "right" / "1.png")
    _img(ds / "images" / "right" / "1.jpg")
    with pytest.raises(DatasetError, match=r"1.jpg and 1.png are the same frame '1'"):
        list_dataset(ds, ["left", "right"])


def test_a_camera_sharing_no_frame_stem_is_refused_with_both_namings(tmp_path):
    """Files named per camera (left01.jpg / right01.jpg, as many capture tools write them)
    share no instant: this used to surface after detection as 'cannot connect every camera'."""
    ds = _dataset(tmp_path / "d", {"left": ["left01", "left02"], "right": ["right01", "right02"]})
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml"), "--jobs", "1"])
    assert res.exit_code == 2, res.output
    assert ("camera left shares no frame with the other cameras (its file stems: left01, left02; right's: "
            "right01, right02)") in res.output
    _img(ds / "images" / "right" / "left02.png")  # one shared instant is enough to link
    check_shared_stems(list_dataset(ds, ["left", "right"]))


def test_default_rig_and_target_paths(tmp_path):
    ds = _dataset(tmp_path / "d", {"left": ["1"]})
    assert dataset_rig_path(ds) == ds / "rig.yaml"
    assert dataset_target_path(ds) == ds / "target.yaml"
    assert dataset_rig_path(ds, "elsewhere.yaml") == Path("elsewhere.yaml")
    (ds / "target.yaml").unlink()
    with pytest.raises(DatasetError, match=r"target.yaml: missing \(put target.yaml in the dataset or pass --target FILE\)"):
        dataset_target_path(ds)
    assert dataset_target_path(ds, tmp_path / "t.yaml") == tmp_path / "t.yaml"


def test_frame_sort_key_is_natural():
    stems = ["p10_3", "p2_11", "p2_2", "10", "9", "b", "a"]
    assert sorted(stems, key=frame_sort_key) == ["9", "10", "a", "b", "p2_2", "p2_11", "p10_3"]


@pytest.mark.parametrize("frames, expected", [
    ({"left": ["1"], "right": ["1"], "back": ["1"]}, "images/back/ is not a camera of the rig"),
    ({"left": ["1"]}, "camera right has no folder images/right/"),
])
def test_calibrate_refuses_a_bad_layout_with_exit_2(tmp_path, frames, expected):
    ds = _dataset(tmp_path / "d", frames)
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml")])
    assert res.exit_code == 2, res.output
    assert expected in res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "cal.yaml").exists()
