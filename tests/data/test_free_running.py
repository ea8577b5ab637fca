"""Free-running and mixed-rate cameras in a motion dataset (imu.md: "Cameras need not share
stems"): images grouped by time into shared frames for the camera-only start
(rigcal.data.dataset.associate_by_time), and the refusals that name the camera and what
is missing (images taken together, overlap with the IMU, integer stems): exit 2,
one line, nothing written. The datasets here are fabricated (tiny images, a synthetic
IMU stream): every refusal comes before detection."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.data.dataset import (associate_by_time, check_shared_stems, frame_period_ns, list_dataset,
                                 time_groups)
from rigcal.errors import DatasetError
from tests.support.recordings import imu_rows, synthetic_imu

RIGS = Path(__file__).resolve().parents[2] / "rigs"
TARGET = """
boards:
  - {name: b, type: charuco, dictionary: DICT_4X4_50, squares: [5, 4], square_length: 0.04, marker_length: 0.03}
"""
T0 = 1_600_000_000_000_000_000
MS = 1_000_000
runner = CliRunner()


def _dataset(root: Path, stems: dict[str, list[int | str]], imu: bool = True) -> Path:
    """drone-stereo-back-imu's rig, a target, blank 8x8 images named by `stems` and (imu) an
    IMU stream covering them."""
    root.mkdir(parents=True)
    (root / "rig.yaml").write_text((RIGS / "drone-stereo-back-imu.yaml").read_text())
    (root / "target.yaml").write_text(TARGET)
    blank = np.full((8, 8), 128, np.uint8)
    for cam, names in stems.items():
        (root / "images" / cam).mkdir(parents=True)
        for s in names:
            assert cv2.imwrite(str(root / "images" / cam / f"{s}.png"), blank)
    if imu:
        ints = [int(s) for v in stems.values() for s in v if str(s).isdigit()]
        (root / "imu").mkdir()
        (root / "imu" / "imu0.csv").write_text(imu_rows(*synthetic_imu(min(ints), max(ints))))
    return root


def _grid(start_ms: float, period_ms: float, n: int) -> list[int]:
    return [T0 + int(round((start_ms + k * period_ms) * MS)) for k in range(n)]


def _refused(ds: Path, *needles: str, extra=()):
    out = ds.parent / "out.yaml"
    r = runner.invoke(app, ["calibrate", str(ds), "--out", str(out), "--jobs", "1", *extra])
    assert r.exit_code == 2, r.output
    line = r.output.strip()
    assert "\n" not in line and "Traceback" not in line, line
    for n in needles:
        assert n in line, line
    assert not out.exists()
    return line


# ----------------------------------------------------------------------------- grouping by time


def test_time_groups_known_answer():
    # a at 0, 50, 100 ms; b at 10, 62, 140 ms (free-running); c at 0 and 50 (shares a's stems)
    t = {"a": [0, 50, 100], "b": [10, 62, 140], "c": [0, 50]}
    groups = time_groups(t, 12)
    assert groups == [{"a": 0, "c": 0, "b": 10}, {"a": 50, "c": 50, "b": 62}, {"a": 100}, {"b": 140}]
    # tolerance 0: exactly the groups of equal stems
    assert time_groups(t, 0) == [{"a": 0, "c": 0}, {"b": 10}, {"a": 50, "c": 50}, {"b": 62}, {"a": 100},
                                 {"b": 140}]
    # one camera never twice in a group, however close its frames
    assert time_groups({"a": [0, 5]}, 100) == [{"a": 0}, {"a": 5}]


def test_frame_period_is_the_median_interval():
    assert frame_period_ns([0, 50, 100, 300, 350]) == 50.0
    assert frame_period_ns([7]) == float("inf")


def test_free_running_images_are_grouped_and_keep_their_own_times(tmp_path):
    stems = {"front_left": _grid(0.0, 50.0, 20), "front_right": _grid(7.3, 50.0, 20),
             "back": _grid(31.0, 1000 / 30, 30)}  # 20, 20 and 30 Hz, own phases
    images = list_dataset(_dataset(tmp_path / "ds", stems), ["front_left", "front_right", "back"])
    a = associate_by_time(images)
    assert a.renamed and a.tolerance_ns == int(0.25 * 1000 / 30 * MS)
    for cam, own in stems.items():
        got = a.image_t_ns[cam]
        assert sorted(got.values()) == own  # every image kept, at its own time
        for frame, t in got.items():  # a frame's name is its earliest image's stem
            assert int(frame) <= t <= int(frame) + a.tolerance_ns
            assert a.images.frames[cam][frame].name == f"{t}.png"
    # front_left and front_right are 7.3 ms apart (< 8.3 ms): shared unless a back image
    # 1-7 ms before front_left's opened the group (front_right is then 8.3-14 ms after it)
    fl, fr = a.image_t_ns["front_left"], a.image_t_ns["front_right"]
    alone = set(fl) - set(fr)
    assert 0 < len(alone) < len(fl) / 2
    for f in alone:
        assert f in a.image_t_ns["back"] and 0 < fl[f] - int(f) <= a.tolerance_ns
    assert a.shared_frames == len({f for c in stems for f in a.image_t_ns[c]
                                   if sum(f in a.image_t_ns[o] for o in stems) > 1})
    check_shared_stems(a.images, a.tolerance_ns)


def test_synchronised_stems_are_left_as_they_are(tmp_path):
    stems = {c: _grid(0.0, 50.0, 10) for c in ("front_left", "front_right", "back")}
    del stems["back"][3]  # a dropped frame
    images = list_dataset(_dataset(tmp_path / "ds", stems), ["front_left", "front_right", "back"])
    a = associate_by_time(images)
    assert not a.renamed and a.shared_frames == 10
    assert {c: dict(f) for c, f in a.images.frames.items()} == {c: dict(f) for c, f in images.frames.items()}


# ----------------------------------------------------------------------------- refusals (CLI)


def _read(ds: Path, camera_only: bool = False):
    """calibrate's inputs as run() reads them (before detection)."""
    from rigcal.commands.calibrate import CalibrateOptions, _read_inputs

    o = CalibrateOptions()
    return _read_inputs(ds, ds.parent / "out.yaml", None, None, None, 1, None if camera_only else o.imu_step(""))


def test_free_running_cameras_without_an_imu_are_grouped_by_time(tmp_path):
    # no IMU: the views alone shape the motion (imucal.visual_motion); the start groups by time
    stems = {"front_left": _grid(0.0, 50.0, 20), "front_right": _grid(7.3, 50.0, 20), "back": _grid(19.0, 50.0, 20)}
    inp = _read(_dataset(tmp_path / "ds", stems, imu=False))
    assert inp.motion.frame_t_ns is not None
    assert inp.motion.frame_t_ns["back"] and any("continuous-time step" in n for n in inp.motion_notes)


def test_free_running_cameras_with_camera_only_are_grouped_by_time(tmp_path):
    stems = {"front_left": _grid(0.0, 50.0, 40), "front_right": _grid(7.3, 50.0, 40), "back": _grid(3.0, 50.0, 40)}
    inp = _read(_dataset(tmp_path / "ds", stems), camera_only=True)
    assert inp.motion.frame_t_ns is not None and any("continuous-time step" in n for n in inp.motion_notes)


def test_phases_a_third_of_a_period_apart_are_grouped_within_half_a_period(tmp_path):
    stems = {"front_left": _grid(0.0, 50.0, 10), "front_right": _grid(0.0, 50.0, 10), "back": _grid(19.0, 50.0, 10)}
    a = associate_by_time(list_dataset(_dataset(tmp_path / "ds", stems), list(stems)))
    assert a.tolerance_ns == 25 * MS and a.shared_frames == 10
    check_shared_stems(a.images, a.tolerance_ns)


def test_a_camera_never_taken_with_another_is_refused(tmp_path):
    # back records 1.06-2.21 s, in the front cameras' gap (1.0-2.3 s): never within 25 ms of theirs
    front = _grid(0.0, 50.0, 21) + _grid(2300.0, 50.0, 21)
    stems = {"front_left": front, "front_right": front, "back": _grid(1060.0, 50.0, 24)}
    _refused(_dataset(tmp_path / "ds", stems), "camera back", "within 25.0 ms", "taken together")


def test_a_camera_never_taken_with_another_without_an_imu_is_refused(tmp_path):
    # no IMU either: nothing relates back's clock to the others'
    front = _grid(0.0, 50.0, 21) + _grid(2300.0, 50.0, 21)
    stems = {"front_left": front, "front_right": front, "back": _grid(1060.0, 50.0, 24)}
    _refused(_dataset(tmp_path / "ds", stems, imu=False), "camera back", "within 25.0 ms", "taken together")


def test_a_camera_overlapping_the_imu_too_briefly_is_refused(tmp_path):
    # back records for 0.4 s of the front cameras' 2 s: the spline needs 20 knots of 0.05 s
    stems = {"front_left": _grid(0.0, 50.0, 40), "front_right": _grid(3.0, 50.0, 40), "back": _grid(1.0, 50.0, 9)}
    _refused(_dataset(tmp_path / "ds", stems), "camera back", "overlap", "0.40 s", "at least 1 s")


def test_a_stem_that_is_not_an_integer_is_refused(tmp_path):
    stems = {"front_left": _grid(0.0, 50.0, 40), "front_right": _grid(3.0, 50.0, 40),
             "back": [*_grid(1.0, 50.0, 39), "frame_0040"]}
    _refused(_dataset(tmp_path / "ds", stems), "frame_0040.png", "not an integer")


def test_names_and_no_imu_still_get_the_naming_hint(tmp_path):
    # per-camera file names (left01, right01) are not free-running: the old hint stands
    stems = {"front_left": ["fl01", "fl02"], "front_right": ["fr01", "fr02"], "back": ["b01", "b02"]}
    images = list_dataset(_dataset(tmp_path / "ds", stems, imu=False), ["front_left", "front_right", "back"])
    with pytest.raises(DatasetError, match="same stem in every camera folder"):
        check_shared_stems(images)
