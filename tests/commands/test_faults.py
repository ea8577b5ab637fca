"""Bad input and faults: one test per row of the fault table (docs/how-it-works.md, Robustness).

Every command either works around the fault and says what it skipped, or stops with
one stderr line (file, key, expected vs got) and exit code 2 (bad input) or 1 (the
work failed); no traceback reaches the user and nothing is half-written.

One small rendered dataset (drone-stereo-back, room scene, 12 frames) is made once per
session and copied into each test's tmp_path before a fault is planted. Commands run
in-process through typer's CliRunner, except where the fault lives at the process
level (signals, libpng writing to the stderr file descriptor): those run `python -m
rigcal` in a subprocess."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.core import geometry as geo
from rigcal.results.outputs import warnings_for
from rigcal.cli import app
from rigcal.results.compare import compare_rigs
from rigcal.data.truth import load_truth
from rigcal.camcal.pipeline import calibrate_views
from rigcal.core.observations import BoardView
from rigcal.data.dataset import list_dataset
from rigcal.detect.detect import detect_dataset
from rigcal.errors import CalibrationError
from rigcal.core.io import atomic_dir, atomic_write_text
from rigcal.core.rig import load_rig
from rigcal.sim.simulate import simulate_dataset
from rigcal.core.target import load_target

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "rigs" / "drone-stereo-back.yaml"
CALIBRATED = ROOT / "tests" / "golden" / "drone-stereo-back-calibrated.yaml"
BUMBLEBEE = ROOT / "samples" / "real" / "bumblebee2"  # in the repository: needs nothing from ../shared
CAMERAS = ("front_left", "front_right", "back")
FRAMES = 12
JOBS = 2
RUNNER = CliRunner()
# stderr lines that are progress, not messages
PROGRESS = re.compile(r"^(detecting|rendering|calibrating \d+ cameras)\b")


# ----------------------------------------------------------------------------- helpers


def cli(*args):
    return RUNNER.invoke(app, [str(a) for a in args])


def no_traceback(stdout: str, stderr: str) -> None:
    assert "Traceback" not in stdout + stderr, stderr[-3000:]


def error_line(result, code: int, *needles: str) -> str:
    """The one error line of a failed command; checks the exit code and that nothing else
    but progress reached stderr."""
    no_traceback(result.stdout, result.stderr)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert result.exit_code == code, (result.exit_code, result.stdout[-2000:], result.stderr[-2000:])
    return one_error_line(result.stderr, *needles)


def one_error_line(stderr: str, *needles: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip() and not PROGRESS.match(ln)]
    assert len(lines) == 1, stderr
    line = lines[0]
    assert line.startswith("rigcal: "), line
    for n in needles:
        assert n in line, (n, line)
    return line


def copy_dataset(src: Path, dst: Path, frames=None) -> Path:
    """Copy a dataset (rig.yaml, target.yaml, truth.yaml, images/), optionally only some frame stems."""
    keep = None if frames is None else {f"{f}.png" for f in frames}

    def ignore(folder, names):
        if keep is None or Path(folder).parent.name != "images":
            return []
        return [n for n in names if n not in keep]

    shutil.copytree(src, dst, ignore=ignore)
    return dst


def frames_with_views(det, cam: str) -> list[str]:
    return sorted({v.frame for v in det.views if v.camera == cam})


def leftovers(folder: Path) -> list[str]:
    """Temporary files or folders an atomic writer left behind."""
    return sorted(p.name for p in Path(folder).iterdir() if p.name.endswith(".tmp"))


def corrupt_png(path: Path) -> None:
    """Flip bits in the middle of a PNG's image data (a CRC failure, not a truncation)."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


# ----------------------------------------------------------------------------- session data


@pytest.fixture(scope="session")
def sim(tmp_path_factory) -> Path:
    """The clean dataset: drone-stereo-back, room scene, 12 frames (read-only: copy it)."""
    out = tmp_path_factory.mktemp("faults") / "clean"
    simulate_dataset(load_rig(RIG), out, scene="room", frames=FRAMES, seed=1, jobs=JOBS)
    return out


@pytest.fixture(scope="session")
def clean_det(sim):
    rig = load_rig(sim / "rig.yaml")
    return detect_dataset(list_dataset(sim, rig), load_target(sim / "target.yaml"), rig=rig, jobs=JOBS,
                          progress=False)


TRUNCATED = "images/front_left/000003.png"
GARBAGE = "images/back/000005.png"
BAD_CRC = "images/front_right/000006.png"
BLACK = "images/front_right/000004.png"
WHITE = "images/back/000007.png"
MISSING = "images/front_right/000009.png"


@pytest.fixture(scope="session")
def faulted(sim, tmp_path_factory):
    """`rigcal calibrate` (a subprocess: libpng writes to the stderr descriptor itself) on the
    dataset with a truncated PNG, a file of random bytes, a PNG failing its CRC, an
    all-black and an all-white image and one frame missing for one camera."""
    ds = copy_dataset(sim, tmp_path_factory.mktemp("faulted") / "ds")
    p = ds / TRUNCATED
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    (ds / GARBAGE).write_bytes(np.random.default_rng(7).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    corrupt_png(ds / BAD_CRC)
    cv2.imwrite(str(ds / BLACK), np.zeros((480, 640), np.uint8))
    cv2.imwrite(str(ds / WHITE), np.full((480, 640), 255, np.uint8))
    (ds / MISSING).unlink()
    out = ds.parent / "out.yaml"
    proc = subprocess.run([sys.executable, "-m", "rigcal", "calibrate", str(ds), "--out", str(out), "--jobs",
                           str(JOBS)], capture_output=True, text=True, timeout=600)
    return ds, out, proc


def summary_line(stdout: str, cam: str) -> str:
    return next(ln for ln in stdout.splitlines() if ln.strip().startswith(f"{cam}: ") and "images" in ln)


# ----------------------------------------------------------------------------- images


@pytest.mark.slow
def test_truncated_or_corrupt_image_is_skipped_with_one_warning_and_counted(faulted):
    ds, out, proc = faulted
    no_traceback(proc.stdout, proc.stderr)
    assert proc.returncode == 0, proc.stderr
    assert "libpng" not in proc.stderr  # the decoder's own stderr line is not let through
    skipped = [ln for ln in proc.stderr.splitlines() if ln.startswith("warning: ") and "skipped" in ln]
    assert len(skipped) == 3, proc.stderr
    for rel, why in ((TRUNCATED, "truncated PNG"), (GARBAGE, "not a readable image"), (BAD_CRC, "CRC")):
        mine = [ln for ln in skipped if str(ds / rel) in ln]
        assert len(mine) == 1 and why in mine[0], (rel, skipped)
        assert f"skipped {ds / rel}" in proc.stdout  # and listed in the summary
    assert "1 unreadable" in summary_line(proc.stdout, "front_left")
    assert "1 unreadable" in summary_line(proc.stdout, "front_right")
    assert "1 unreadable" in summary_line(proc.stdout, "back")
    assert load_rig(out).names == CAMERAS


def test_black_and_white_images_give_no_detection_counted_without_warnings(faulted, clean_det, capfd):
    ds, out, proc = faulted
    assert proc.returncode == 0, proc.stderr
    for rel in (BLACK, WHITE):
        assert rel.split("/")[-1] not in proc.stderr.replace(Path(TRUNCATED).name, "").replace(
            Path(GARBAGE).name, "").replace(Path(BAD_CRC).name, ""), proc.stderr
    # counted among the images without a board: one more than the clean dataset has
    for cam, rel in (("front_right", BLACK), ("back", WHITE)):
        n = clean_det.no_board[cam] + 1
        assert f"{n} without a board" in summary_line(proc.stdout, cam), (cam, proc.stdout)
    # the library: no view, counted, nothing printed
    rig = load_rig(ds / "rig.yaml")
    sub = copy_dataset(ds, ds.parent / "flat", frames=["000004", "000007"])
    for cam in CAMERAS:
        for f in (sub / "images" / cam).iterdir():
            if f"images/{cam}/{f.name}" not in (BLACK, WHITE):
                f.unlink()
    (sub / "images" / "front_left" / "000004.png").write_bytes((ds / BLACK).read_bytes())
    capfd.readouterr()
    det = detect_dataset(list_dataset(sub, rig), load_target(sub / "target.yaml"), rig=rig, jobs=1, progress=False)
    assert capfd.readouterr() == ("", "")
    assert det.views == [] and det.unreadable == []
    assert det.no_board == {"front_left": 1, "front_right": 1, "back": 1}


def test_image_size_differs_from_rig_resolution(sim, tmp_path):
    ds = copy_dataset(sim, tmp_path / "ds", frames=["000000", "000001", "000002"])
    p = ds / "images" / "back" / "000001.png"
    cv2.imwrite(str(p), cv2.resize(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), (800, 600)))
    r = cli("calibrate", ds, "--out", tmp_path / "out.yaml", "--jobs", 1)
    error_line(r, 2, str(p), "camera back", "800x600", "640x480", "--allow-resize")
    # --allow-resize scales a camera whose images all have another size; one odd image is refused
    r = cli("calibrate", ds, "--out", tmp_path / "out.yaml", "--jobs", 1, "--allow-resize")
    error_line(r, 2, str(p), "camera back", "two sizes", "640x480", "800x600")
    assert not (tmp_path / "out.yaml").exists()


def test_image_turned_by_90_degrees_is_named_even_with_allow_resize(sim, tmp_path):
    """A portrait image of a landscape camera (e.g. a phone photo saved with an EXIF
    orientation tag applied) is not a resize: scaling fx and fy apart would be nonsense."""
    ds = copy_dataset(sim, tmp_path / "ds", frames=["000000", "000001", "000002"])
    p = ds / "images" / "back" / "000002.png"
    cv2.imwrite(str(p), cv2.rotate(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), cv2.ROTATE_90_CLOCKWISE))
    for extra in ([], ["--allow-resize"]):
        r = cli("calibrate", ds, "--out", tmp_path / "out.yaml", "--jobs", 1, *extra)
        error_line(r, 2, str(p), "camera back", "480x640", "turned by 90 degrees", "EXIF")
    assert not (tmp_path / "out.yaml").exists()


def test_allow_resize_calibrates_images_of_another_size(sim, clean_det, tmp_path):
    ds = copy_dataset(sim, tmp_path / "ds", frames=frames_with_views(clean_det, "back")[:7])
    for p in (ds / "images" / "back").iterdir():
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(p), cv2.resize(img, (800, 600), interpolation=cv2.INTER_CUBIC))
    out = tmp_path / "out.yaml"
    r = cli("calibrate", ds, "--out", out, "--jobs", JOBS, "--allow-resize")
    no_traceback(r.stdout, r.stderr)
    assert r.exit_code == 0, r.stderr[-3000:]
    cal = load_rig(out)
    true = load_truth(ds / "truth.yaml").rig.camera("back").intrinsics
    m = cal.camera("back").intrinsics
    assert (m.width, m.height) == (800, 600)
    s = 800 / 640
    assert m.fx == pytest.approx(s * true.fx, rel=0.01) and m.fy == pytest.approx(s * true.fy, rel=0.01)
    assert m.cx == pytest.approx((true.cx + 0.5) * s - 0.5, abs=3.0)
    assert m.cy == pytest.approx((true.cy + 0.5) * s - 0.5, abs=3.0)
    assert cal.camera("front_left").intrinsics.width == 640
    assert cal.camera("back").calibration["reprojection_rms_px"] < 0.1


# ----------------------------------------------------------------------------- layout


@pytest.mark.parametrize("change, needles", [
    ("rename", ["images/rear/", "camera back", "images/back/"]),
    ("extra", ["images/left_cam/", "not a camera of the rig"]),
    ("drop", ["camera back", "no folder images/back/"]),
])
def test_camera_folders_must_match_the_rig(sim, tmp_path, change, needles):
    ds = copy_dataset(sim, tmp_path / "ds", frames=["000000"])
    if change == "rename":
        (ds / "images" / "back").rename(ds / "images" / "rear")
    elif change == "extra":
        shutil.copytree(ds / "images" / "back", ds / "images" / "left_cam")
    else:
        shutil.rmtree(ds / "images" / "back")
    error_line(cli("calibrate", ds, "--out", tmp_path / "o.yaml"), 2, *needles)
    assert not (tmp_path / "o.yaml").exists()


def test_frame_missing_for_one_camera_is_fine(faulted):
    ds, out, proc = faulted
    assert proc.returncode == 0, proc.stderr
    assert not (ds / MISSING).exists()
    assert summary_line(proc.stdout, "front_right").split(":", 1)[1].strip().startswith(f"{FRAMES - 1} images")
    assert summary_line(proc.stdout, "front_left").split(":", 1)[1].strip().startswith(f"{FRAMES} images")
    assert str(ds / MISSING) not in proc.stdout + proc.stderr
    cal = load_rig(out)
    assert cal.camera("front_right").calibration["frames"] <= FRAMES - 1
    errors = compare_rigs(cal, load_truth(ds / "truth.yaml").rig)["pairs"][("front_left", "front_right")]
    assert errors["rot_deg"] < 0.05 and errors["trans_mm"] < 0.5, errors


# ----------------------------------------------------------------------------- target and coverage


def test_wrong_dictionary_exits_1_with_the_likely_cause(sim, tmp_path):
    ds = copy_dataset(sim, tmp_path / "ds", frames=["000000", "000001"])
    t = ds / "target.yaml"
    t.write_text(t.read_text().replace("DICT_5X5_1000", "DICT_4X4_1000"))
    r = cli("calibrate", ds, "--out", tmp_path / "o.yaml", "--jobs", 1)
    error_line(r, 1, "no board detected in any of 2 images of camera front_left; check target.yaml "
                     "(dictionary, squares, legacy_pattern)", "markers of DICT_5X5_1000 found",
               "target.yaml says DICT_4X4_1000")
    assert not (tmp_path / "o.yaml").exists()


def test_wrong_board_size_exits_1_with_the_likely_cause(sim, tmp_path):
    ds = copy_dataset(sim, tmp_path / "ds", frames=["000000", "000001", "000002"])
    t = ds / "target.yaml"
    t.write_text(t.read_text().replace("squares: [9, 6]", "squares: [6, 9]"))
    r = cli("calibrate", ds, "--out", tmp_path / "o.yaml", "--jobs", 1)
    error_line(r, 1, "no board detected in any of 3 images of camera front_left; check target.yaml",
               "corners appear with squares: [9, 6]")


def test_camera_with_boards_in_fewer_than_3_frames_exits_1(sim, clean_det, tmp_path):
    back = frames_with_views(clean_det, "back")[:2]
    front = [f for f in frames_with_views(clean_det, "front_left") if f in frames_with_views(clean_det, "front_right")
             and f not in back][:3]
    ds = copy_dataset(sim, tmp_path / "ds", frames=back + front)
    for p in (ds / "images" / "back").iterdir():
        if p.stem not in back:
            p.unlink()
    r = cli("calibrate", ds, "--out", tmp_path / "o.yaml", "--jobs", 1)
    error_line(r, 1, "back:", "only 2 frame(s)", "--fix-intrinsics")
    assert not (tmp_path / "o.yaml").exists()


# ----------------------------------------------------------------------------- the solve


def _stereo_views(poses, rig_true, corners, rng, noise_px=0.1) -> list[BoardView]:
    views = []
    for f, T_body_board in enumerate(poses):
        for cam in rig_true.cameras:
            p_cam = geo.transform(geo.inv_T(cam.T_body_cam) @ T_body_board, corners)
            uv, valid = cam.intrinsics.project(p_cam)
            ok = valid & cam.intrinsics.in_image(uv, margin=2)
            if ok.sum() >= 8:
                ids = np.nonzero(ok)[0]
                views.append(BoardView(cam.name, f"{f:06d}", "b", ids, uv[ok] + rng.normal(0, noise_px, (len(ids), 2))))
    return views


def _board_corners(nx: int = 8, ny: int = 5, s: float = 0.06) -> np.ndarray:
    """(nx * ny, 3) inner corners of a board of s m squares, row-major from (s, s)."""
    k = np.arange(nx * ny)
    return np.column_stack([(k % nx + 1) * s, (k // nx + 1) * s, np.zeros(nx * ny)])


def _board_pose(declared, corners):
    """pose(rotvec, dist, shift) -> T_body_board: the board's centre `dist` m before the first
    camera, `shift` (2,) m off its axis (plus 5 cm along x), turned by `rotvec`."""
    def pose(rotvec, dist, shift):
        R = geo.R_from_rotvec(rotvec)
        return declared.cameras[0].T_body_cam @ geo.make_T(R, np.array([shift[0] + 0.05, shift[1], dist])
                                                           - R @ corners.mean(0))
    return pose


@pytest.mark.slow
def test_degenerate_motion_calibrates_and_warns_what_is_poorly_constrained():
    """Eight frames of a board in nearly the same pose in front of a stereo pair: the focal
    length and the cameras' depth are not observable; calibrate must finish and say so.
    The same board moved properly gives no warning."""
    declared = load_rig(RIG)
    declared = declared.with_cameras([c for c in declared.cameras if c.name != "back"])
    rng = np.random.default_rng(3)
    cams = []
    for c in declared.cameras:  # the truth: other focal lengths, some distortion, mounting errors
        m = c.intrinsics.with_(fx=c.intrinsics.fx * 1.02, fy=c.intrinsics.fy * 1.021, dist=(-0.02, 0.01, 0, 0, 0))
        T = c.T_body_cam.copy()
        T[:3, 3] += rng.normal(0, 0.003, 3)
        cams.append(replace(c, intrinsics=m, T_body_cam=T))
    true = declared.with_cameras(cams)
    corners = _board_corners()
    pose = _board_pose(declared, corners)

    still = [pose(rng.normal(0, np.radians(0.3), 3), 1.0 + rng.normal(0, 0.003), rng.normal(0, 0.003, 2))
             for _ in range(8)]
    cal = calibrate_views(_stereo_views(still, true, corners, rng), declared, {"b": corners})
    assert np.isfinite(cal.rms_px) and cal.rms_px < 0.3
    warns = warnings_for(cal)
    for cam in ("front_left", "front_right"):
        assert any(w.startswith(f"{cam}: focal length fx is poorly constrained") for w in warns), warns
        assert any(w.startswith(f"{cam}: position along body F is poorly constrained") for w in warns), warns
    moving = [pose(rng.normal(0, np.radians(25), 3), rng.uniform(0.6, 1.5), rng.normal(0, 0.15, 2))
              for _ in range(8)]
    good = calibrate_views(_stereo_views(moving, true, corners, rng), declared, {"b": corners})
    assert warnings_for(good) == []


def test_a_rig_that_contradicts_its_declaration_is_named():
    """A camera mounted upside down but declared upright, and a target in millimetres:
    the aligned body frame hid both (exit 0, no word); the camera pairs show them."""
    from types import SimpleNamespace

    from rigcal.results.outputs import declared_disagreements

    declared = load_rig(RIG)
    assert declared_disagreements(SimpleNamespace(declared=declared, rig=declared)) == []
    cams = []
    for c in declared.cameras:
        T = c.T_body_cam.copy()
        if c.name == "front_right":
            T[:3, :3] = T[:3, :3] @ np.diag([-1.0, -1.0, 1.0])  # turned 180 deg about its optical axis
        cams.append(replace(c, T_body_cam=T))
    msgs = declared_disagreements(SimpleNamespace(declared=declared, rig=declared.with_cameras(cams)))
    assert len(msgs) == 2 and all("180 deg from the declared one (about the optical axis" in m for m in msgs), msgs
    assert {m.split(":")[0] for m in msgs} == {"front_left/front_right", "front_right/back"}
    fl, fr = declared.camera("front_left").T_body_cam, declared.camera("front_right").T_body_cam
    swapped = [replace(c, T_body_cam={"front_left": fr, "front_right": fl}.get(c.name, c.T_body_cam))
               for c in declared.cameras]  # images/front_left/ and images/front_right/ swapped
    msgs = declared_disagreements(SimpleNamespace(declared=declared, rig=declared.with_cameras(swapped)))
    assert len(msgs) == 1 and msgs[0].startswith("front_left/front_right: seen from front_left, front_right is "
                                                 "calibrated 180 deg away"), msgs
    big = [replace(c, T_body_cam=geo.make_T(c.T_body_cam[:3, :3], 1000 * c.T_body_cam[:3, 3]))
           for c in declared.cameras]
    msgs = declared_disagreements(SimpleNamespace(declared=declared, rig=declared.with_cameras(big)))
    assert len(msgs) == 1 and msgs[0].startswith("the calibrated rig is 1000x the size of the declared one"), msgs


@pytest.mark.slow
def test_a_camera_with_mirrored_images_fails_instead_of_writing_a_bad_rig():
    """A camera that flips its images (a mirror setting) sees a chessboard symmetric under
    that flip as a valid board from another pose: each camera calibrates alone, but no
    rigid rig fits both. That used to end with exit 0 and 30-60 px RMS."""
    declared = load_rig(RIG)
    declared = declared.with_cameras([c for c in declared.cameras if c.name != "back"])
    rng = np.random.default_rng(3)
    corners = _board_corners()
    pose = _board_pose(declared, corners)

    moving = [pose(rng.normal(0, np.radians(25), 3), rng.uniform(0.6, 1.5), rng.normal(0, 0.15, 2))
              for _ in range(8)]
    views = _stereo_views(moving, declared, corners, rng)
    width = declared.camera("front_right").intrinsics.width
    flipped = []
    for v in views:
        if v.camera == "front_right":  # u -> W-1-u, and the ids as the flipped board numbers them
            ids = (v.ids // 8) * 8 + (7 - v.ids % 8)  # the 8 x 5 board
            uv = np.column_stack([width - 1 - v.uv[:, 0], v.uv[:, 1]])
            order = np.argsort(ids)
            v = replace(v, ids=ids[order], uv=uv[order])
        flipped.append(v)
    assert calibrate_views(views, declared, {"b": corners}).rms_px < 0.3
    with pytest.raises(CalibrationError, match=r"the calibration failed: reprojection RMS .*front_right .*"
                                                r"its own views alone 0\.\d\d px.*mirrored"):
        calibrate_views(flipped, declared, {"b": corners})


def _waved_board(declared, rng, n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """An 8 x 5 board of 6 cm squares, (40, 3) corners, in n random T_body_board before the
    first camera: turned ~25 deg about each axis, 0.6-1.5 m away, +-0.15 m off its axis."""
    corners = _board_corners()
    poses = []
    for _ in range(n):
        R = geo.R_from_rotvec(rng.normal(0, np.radians(25), 3))
        shift = np.array([0.05, 0, 0]) + np.append(rng.normal(0, 0.15, 2), rng.uniform(0.6, 1.5))
        poses.append(declared.cameras[0].T_body_cam @ geo.make_T(R, shift - R @ corners.mean(0)))
    return corners, poses


def test_fixed_intrinsics_that_do_not_fit_the_images_are_named():
    """--fix-intrinsics with a declared focal length 3 % off and no distortion (k1 -0.2 in truth): the
    extrinsics absorb the misfit without a word unless the camera's own views say so."""
    declared = load_rig(RIG)
    declared = declared.with_cameras([c for c in declared.cameras if c.name != "back"])
    rng = np.random.default_rng(5)
    true = declared.with_cameras([replace(c, intrinsics=c.intrinsics.with_(
        fx=c.intrinsics.fx * 1.03, fy=c.intrinsics.fy * 1.03, dist=(-0.2, 0.05, 0, 0, 0))) for c in declared.cameras])
    corners, poses = _waved_board(declared, rng, 8)
    views = _stereo_views(poses, true, corners, rng)
    notes = calibrate_views(views, declared, {"b": corners}, fix_intrinsics=True).notes
    for cam in ("front_left", "front_right"):
        assert any(n.startswith(f"{cam}: the declared intrinsics (--fix-intrinsics) fit its own views to ")
                   for n in notes), notes
    assert not any("declared intrinsics" in n for n in calibrate_views(views, true, {"b": corners},
                                                                       fix_intrinsics=True).notes)


def test_repeated_images_count_once():
    """The same image pair saved under several frame names: eleven copies of one pose
    calibrated (exit 0) to a focal length 28 % off on the Bumblebee2 set."""
    declared = load_rig(RIG)
    declared = declared.with_cameras([c for c in declared.cameras if c.name != "back"])
    rng = np.random.default_rng(7)
    corners, poses = _waved_board(declared, rng, 6)
    views = _stereo_views(poses, declared, corners, rng)
    copies = [replace(v, frame=f"copy{j}_{v.frame}") for j in range(2) for v in views if v.frame == "000001"]
    cal = calibrate_views(views + copies, declared, {"b": corners})
    for cam in ("front_left", "front_right"):
        assert (f"{cam}: 2 view(s) repeat another frame's corners exactly (copy0_000001 = 000001, copy1_000001 = "
                f"000001) and were used once") in " | ".join(cal.notes), cal.notes
        assert cal.stats[cam].frames == 6
    two = [v for v in views if v.frame in ("000000", "000001")]
    again = [replace(v, frame=f"copy{j}_{v.frame}") for j in range(4) for v in two]
    with pytest.raises(CalibrationError, match=r"boards detected in only 2 frame\(s\) \(and 8 exact repeats of them\)"):
        calibrate_views(two + again, declared, {"b": corners})


def test_outlier_detections_are_rejected_and_counted(sim, clean_det):
    """Real detections with a planted wrong corner id (two corners swapped) and a mirrored
    board (every id reflected along the board's x): the solve rejects both and counts
    them, and the rig comes out as accurate as it is without them."""
    rig = load_rig(sim / "rig.yaml")
    target = load_target(sim / "target.yaml")
    views = [replace(v, sigma=None) for v in clean_det.views]
    ki = max((k for k, v in enumerate(views) if v.camera == "front_left"), key=lambda k: len(views[k].ids))
    v = views[ki]
    a, b = int(np.argmin(v.ids)), int(np.argmax(v.ids))  # two corners far apart on the board
    uv = v.uv.copy()
    uv[[a, b]] = uv[[b, a]]
    views[ki] = replace(v, uv=uv)
    swapped = uv[[a, b]]
    km = max((k for k, v in enumerate(views) if v.camera == "back"), key=lambda k: len(views[k].ids))
    v = views[km]
    nx = target.board(v.board).inner_corners[0]
    mirrored = (v.ids // nx) * nx + (nx - 1 - v.ids % nx)
    order = np.argsort(mirrored)
    views[km] = replace(v, ids=mirrored[order], uv=v.uv[order])
    planted_mirror = len(v.ids)

    cal = calibrate_views(views, rig, {bd.name: bd.corners for bd in target.boards})
    ci = cal.cam_names.index("front_left")
    rows = [np.nonzero((cal.obs.cam == ci) & np.all(cal.obs.uv == p, axis=1))[0] for p in swapped]
    assert all(len(r) == 1 and not cal.inliers[r[0]] for r in rows)
    assert cal.stats["front_left"].outliers >= 2
    assert cal.stats["back"].outliers >= planted_mirror
    bi = cal.cam_names.index("back")
    # none of the mirrored view's corners is used
    mirror_uv = views[km].uv
    used = cal.obs.uv[(cal.obs.cam == bi) & cal.inliers]
    assert not (used[:, None, :] == mirror_uv[None]).all(-1).any()
    errors = compare_rigs(cal.rig, load_truth(sim / "truth.yaml").rig)["pairs"]
    for pair, e in errors.items():
        assert e["rot_deg"] < 0.05 and e["trans_mm"] < 0.5, (pair, e)


def test_symmetric_chessboard_order_is_resolved(tmp_path):
    """BoofCV's Bumblebee2 set (samples/real/bumblebee2): a 5x7-square chessboard, the same
    turned by 180 degrees; OpenCV returns pair 11's right corners in reverse. Calibrate
    must put them back in order and use every frame: no outliers, the published 120.05 mm
    baseline."""
    ds = BUMBLEBEE
    out = tmp_path / "bb.yaml"
    r = cli("calibrate", ds, "--out", out, "--jobs", 1)
    no_traceback(r.stdout, r.stderr)
    assert r.exit_code == 0, r.stderr
    assert "11 with a 180-degree ambiguous order" in r.stdout
    assert "1 view(s) had their corner order reversed" in r.stderr
    cal = load_rig(out)
    for cam in ("left", "right"):
        assert cal.camera(cam).calibration["frames"] == 11
        assert cal.camera(cam).calibration["outliers"] == 0
    assert cal.stereo_pairs[0].baseline_m * 1000 == pytest.approx(120.05, abs=0.5)


def test_square_chessboard_is_refused_for_a_rig(tmp_path):
    """7x7 inner corners: a quarter turn maps the board onto itself, so two cameras may
    number it differently; refused with the reason before any image is read."""
    ds = tmp_path / "sq"
    for cam in ("left", "right"):
        (ds / "images" / cam).mkdir(parents=True)
        (ds / "images" / cam / "000001.png").write_bytes(b"not read")
    (ds / "rig.yaml").write_text("""rig: pair
cameras:
  left: {model: pinhole, resolution: [640, 480], intrinsics: {focal: 520.0}, position: [0, 0.06, 0], look: forward}
  right: {model: pinhole, resolution: [640, 480], intrinsics: {focal: 520.0}, position: [0, -0.06, 0], look: forward}
""")
    (ds / "target.yaml").write_text("boards:\n  - {type: chessboard, inner_corners: [7, 7], square_length: 0.03}\n")
    r = cli("calibrate", ds, "--out", tmp_path / "out.yaml", "--jobs", 1)
    no_traceback(r.stdout, r.stderr)
    assert r.exit_code == 2
    assert "target.yaml: boards[0].inner_corners: [7, 7] is square" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out.yaml").exists()


# ----------------------------------------------------------------------------- interrupts


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, IndexError, ValueError):
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(stat.parent.name))
    return out


def _descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        kids = _children(todo.pop())
        out += kids
        todo += kids
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _wait_for(cond, timeout: float = 120.0, what: str = "") -> None:
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, f"timed out waiting for {what}"
        time.sleep(0.05)


def _sigint_as_from_a_terminal() -> None:
    """A command started from a terminal has SIGINT at its default. Under a test runner run
    as a background job (`make test &`, nohup) it inherits SIGINT ignored, and Python then
    never raises KeyboardInterrupt, as nohup intends; the test is about Ctrl-C at a terminal."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("command, sig, to_group, when", [
    # Ctrl-C: the terminal signals the whole process group; as the worker pool starts
    ("calibrate", signal.SIGINT, True, "starting"),
    ("calibrate", signal.SIGTERM, False, "working"),  # kill PID, while the workers detect
    ("simulate", signal.SIGINT, True, "working"),
    ("simulate", signal.SIGTERM, False, "working"),
])
@pytest.mark.slow
def test_interrupt_leaves_no_output_and_no_temporary_files(sim, tmp_path, command, sig, to_group, when):
    if command == "calibrate":
        out = tmp_path / "out.yaml"
        args = ["calibrate", str(sim), "--out", str(out), "--report", str(tmp_path / "r.html"), "--jobs", str(JOBS)]
    else:  # one camera: the first image is soon there
        out = tmp_path / "sim"
        rig = _write(tmp_path / "tiny.yaml", "cameras:\n  cam: {model: pinhole, resolution: [640, 480], "
                                             "intrinsics: {focal: 400.0}, position: [0, 0, 0], look: forward}\n")
        args = ["simulate", str(rig), "--out", str(out), "--frames", "12", "--jobs", str(JOBS)]
    proc = subprocess.Popen([sys.executable, "-m", "rigcal", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, preexec_fn=_sigint_as_from_a_terminal)
    try:
        if command == "calibrate" and when == "starting":  # the first helper process appears
            _wait_for(lambda: _children(proc.pid) or proc.poll() is not None, what="the worker pool")
        elif command == "calibrate":  # workers (children of the forkserver) are detecting
            _wait_for(lambda: len(_descendants(proc.pid)) >= 3 or proc.poll() is not None, what="detection workers")
        else:  # rendering into the temporary dataset folder
            _wait_for(lambda: any(tmp_path.glob(".sim.*.tmp/images/*/*.png")) or proc.poll() is not None,
                      what="the first rendered image")
        assert proc.poll() is None, "finished before it could be interrupted"
        workers = _descendants(proc.pid)
        if to_group:
            os.killpg(proc.pid, sig)
        else:
            os.kill(proc.pid, sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    no_traceback(stdout, stderr)
    assert proc.returncode == 128 + sig, (proc.returncode, stderr)
    one_error_line(stderr, "no partial output was left behind")
    assert not out.exists() and not (tmp_path / "r.html").exists()
    assert leftovers(tmp_path) == []
    if command == "simulate":
        assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.yaml"]
    _wait_for(lambda: not any(_alive(w) for w in workers), timeout=30, what="worker processes to end")


def test_interrupt_while_writing_leaves_nothing(tmp_path, monkeypatch):
    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_text(tmp_path / "out.yaml", "x" * 100000)
    with pytest.raises(KeyboardInterrupt):
        with atomic_dir(tmp_path / "dataset") as d:
            (d / "rig.yaml").write_text("x")
            raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- outputs


def _commands(sim: Path, tmp: Path, out: Path) -> dict[str, list]:
    """Every command that writes, each writing to `out` (a file or folder path)."""
    camchain = tmp / "camchain.yaml"
    if not camchain.exists():
        assert cli("export", CALIBRATED, "--format", "kalibr", "--out", camchain).exit_code == 0
    return {
        "calibrate": ["calibrate", sim, "--out", out, "--jobs", 1],
        "simulate": ["simulate", RIG, "--out", out, "--frames", 2, "--jobs", 1],
        "export": ["export", CALIBRATED, "--format", "json", "--out", out],
        "export-ros": ["export", CALIBRATED, "--format", "ros", "--out", out],
        "board": ["board", sim / "target.yaml", "--out", out.with_suffix(".png"), "--dpi", 50],
        "view": ["view", RIG, "--out", out],
        "import": ["import", camchain, "--rig", RIG, "--out", out],
    }


@pytest.mark.parametrize("command", ["calibrate", "simulate", "export", "export-ros", "board", "view", "import"])
def test_unwritable_output_exits_2_before_any_work(sim, tmp_path, command):
    # tests run as root, where a 0500 folder does not stop a write: a regular file in the
    # path does, for everyone
    blocker = tmp_path / "a_file"
    blocker.write_text("keep me")
    args = _commands(sim, tmp_path, blocker / "out")[command]
    t0 = time.perf_counter()
    error_line(cli(*args), 2, str(blocker))
    assert blocker.read_text() == "keep me"
    if command == "calibrate":  # refused up front, not after minutes of detection
        assert time.perf_counter() - t0 < 5.0
    assert leftovers(tmp_path) == []


def test_output_under_proc_exits_2(sim, tmp_path):
    error_line(cli("export", CALIBRATED, "--format", "json", "--out", "/proc/rigcal-test.json"), 2,
               "/proc/rigcal-test.json")


@pytest.mark.parametrize("command", ["calibrate", "export", "view", "import"])
def test_output_onto_a_pipe_exits_2_and_keeps_it(sim, tmp_path, command):
    """A rename over a pipe or device replaced it with a regular file (as root, --out
    /dev/full or /dev/stdout itself); such an output is now refused."""
    fifo = tmp_path / "out.yaml"
    os.mkfifo(fifo)
    error_line(cli(*_commands(sim, tmp_path, fifo)[command]), 2, f"{fifo}: is a pipe")
    assert fifo.is_fifo()


def test_calibrate_refuses_outputs_that_collide(sim, tmp_path):
    """--report onto --out wrote the HTML over the calibrated rig (exit 0); --out onto the
    target file replaced the board description."""
    out = tmp_path / "cal.yaml"
    error_line(cli("calibrate", sim, "--out", out, "--report", out, "--jobs", 1), 2, "--report and --out name the same file")
    target = tmp_path / "t.yaml"
    shutil.copy(sim / "target.yaml", target)
    error_line(cli("calibrate", sim, "--out", target, "--target", target, "--jobs", 1), 2,
               f"{target}: is the target file this calibration reads")
    assert not out.exists() and target.read_text() == (sim / "target.yaml").read_text()


def test_output_through_a_symlink_writes_the_file_it_names(tmp_path):
    real = tmp_path / "store" / "rig.yaml"
    real.parent.mkdir()
    real.write_text("old")
    link = tmp_path / "rig.yaml"
    link.symlink_to(real)
    r = cli("export", CALIBRATED, "--format", "json", "--out", link)
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and real.read_text().startswith("{")


@pytest.fixture
def full_disk(tmp_path, monkeypatch):
    """A folder on a full file system: a 64 KiB tmpfs filled up when this process may
    mount one, else a folder where every rename fails with ENOSPC."""
    mnt = tmp_path / "full"
    mnt.mkdir()
    mounted = os.geteuid() == 0 and shutil.which("mount") and subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True).returncode == 0
    if mounted:
        with contextlib.suppress(OSError), open(mnt / "filler", "wb") as f:
            while True:
                f.write(b"\0" * 4096)
                f.flush()
    else:
        real_replace = os.replace

        def no_space(src, dst, *a, **k):
            if str(mnt) in str(dst):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return real_replace(src, dst, *a, **k)

        monkeypatch.setattr(os, "replace", no_space)
    try:
        yield mnt
    finally:
        if mounted:
            subprocess.run(["umount", str(mnt)], check=False)


@pytest.mark.parametrize("command", ["calibrate", "simulate", "export", "board"])
def test_disk_full_exits_2_and_leaves_nothing(sim, clean_det, tmp_path, full_disk, command):
    before = sorted(p.name for p in full_disk.iterdir())
    src = sim
    if command == "calibrate":  # a short dataset: the write comes after the whole calibration
        frames = [f for f in frames_with_views(clean_det, "back")
                  if all(f in frames_with_views(clean_det, c) for c in CAMERAS)][:6]
        src = copy_dataset(sim, tmp_path / "ds", frames=frames)
    out = full_disk / ("sim" if command == "simulate" else "out.yaml")
    # simulate's images are written by cv2.imwrite, which gives no reason
    why = "cannot write" if command == "simulate" else os.strerror(errno.ENOSPC)
    error_line(cli(*_commands(src, tmp_path, out)[command]), 2, str(full_disk), why)
    assert sorted(p.name for p in full_disk.iterdir()) == before


# ----------------------------------------------------------------------------- input files


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _sub(path: Path, old: str, new: str) -> str:
    """The file's text with the first `old` (a regular expression after "re:") replaced."""
    text = path.read_text()
    pattern = old[3:] if old.startswith("re:") else re.escape(old)
    assert re.search(pattern, text), (old, path)
    return re.sub(pattern, lambda m: new, text, count=1)


MALFORMED = {
    # name: (file to break, old, new, command, needles)
    "rig": ("rig", "fx: 300.0", "fx: three hundred", "calibrate",
            ["rig.yaml", "cameras.front_left.intrinsics.fx", "expected a number", "got text 'three hundred'"]),
    "rig-syntax": ("rig", "resolution: [640, 480]", "resolution: [640, 480", "calibrate",
                   ["rig.yaml", "not valid YAML at line"]),
    "target": ("target", "squares: [9, 6]", "squares: [9]", "calibrate",
               ["target.yaml", "boards[0].squares", "expected two integers", "got"]),
    "target-key": ("target", "marker_length:", "marker_size:", "calibrate",
                   ["target.yaml", "boards[0].marker_size", "unknown key"]),
    "calibrated-export": ("calibrated", "position: [0.1012, 0.0497, 0.0103]", "position: [0.1012, 0.0497]", "export",
                          ["cal.yaml", "cameras.front_left.position", "expected 3 numbers", "got [0.1012, 0.0497]"]),
    "calibrated-project": ("calibrated", "quaternion: [", "quaternion: [2, ", "project",
                           ["cal.yaml", "cameras.front_left", "quaternion"]),
    "calibrated-view": ("calibrated", "model: pinhole", "model: pinhole2", "view",
                        ["cal.yaml", "cameras.front_left.model", "pinhole2"]),
    "truth-compare": ("truth", "boards:", "boards: 1\nold_boards:", "compare", ["truth.yaml", "boards", "expected"]),
    "camchain-import": ("camchain", "camera_model: pinhole", "camera_model: [pinhole]", "import",
                        ["camchain.yaml", "cam0.camera_model"]),
    "target-board": ("target", "square_length: 0.144", "square_length: '0.144'", "board",
                     ["target.yaml", "boards[0].square_length", "expected a number", "got text '0.144'"]),
    "rig-simulate": ("rig", "resolution: [640, 480]", "resolution: [640, -480]", "simulate",
                     ["rig.yaml", "cameras.front_left.resolution", "-480"]),
}
NONFINITE = {
    "rig": ("rig", "fx: 300.0", "fx: .nan", "calibrate", ["rig.yaml", "cameras.front_left.intrinsics.fx", "finite"]),
    "target": ("target", "square_length: 0.144", "square_length: .inf", "calibrate",
               ["target.yaml", "boards[0].square_length", "finite"]),
    "calibrated-export": ("calibrated", "position: [0.1012", "position: [.nan", "export",
                          ["cal.yaml", "cameras.front_left.position[0]", "finite"]),
    "calibrated-stats": ("calibrated", "reprojection_rms_px:", "reprojection_rms_px: -.inf\n      old_rms:", "project",
                         ["cal.yaml", "reprojection_rms_px", "finite"]),
    "truth-compare": ("truth", r"re:position: \[[^,]+,", "position: [.inf,", "compare",
                      ["truth.yaml", "cameras.front_left.position[0]", "finite"]),
    "camchain-import": ("camchain", "intrinsics: [", "intrinsics: [.nan, ", "import",
                        ["camchain.yaml", "cam0.intrinsics", "finite"]),
    "rig-view": ("rig", "position: [0.1, 0.05, 0.01]", "position: [0.1, .inf, 0.01]", "view",
                 ["rig.yaml", "cameras.front_left.position[1]", "finite"]),
}


def _broken_inputs(sim: Path, tmp: Path, which: str, old: str, new: str) -> dict[str, Path]:
    """Input files (the dataset's rig and target, a calibrated rig, a truth.yaml, a Kalibr
    camchain) in tmp, with one of them edited."""
    ds = copy_dataset(sim, tmp / "ds", frames=["000000"])
    files = {"rig": ds / "rig.yaml", "target": ds / "target.yaml", "truth": ds / "truth.yaml",
             "calibrated": _write(tmp / "cal.yaml", CALIBRATED.read_text()), "camchain": tmp / "camchain.yaml"}
    assert cli("export", CALIBRATED, "--format", "kalibr", "--out", files["camchain"]).exit_code == 0
    _write(files[which], _sub(files[which], old, new))
    files["dataset"] = ds
    return files


def _command(command: str, which: str, f: dict[str, Path], tmp: Path) -> list:
    return {
        "calibrate": ["calibrate", f["dataset"], "--out", tmp / "o.yaml", "--jobs", 1],
        "export": ["export", f["calibrated"], "--format", "json", "--out", tmp / "o.json"],
        "project": ["project", f["calibrated"], "--position", 0, 0, 10, "--heading", 0, "--point", 3, 10, 12],
        "view": ["view", f["calibrated"] if which == "calibrated" else f["rig"], "--out", tmp / "o.html"],
        "compare": ["compare", f["calibrated"], f["truth"]],
        "import": ["import", f["camchain"], "--rig", RIG, "--out", tmp / "o.yaml"],
        "board": ["board", f["target"], "--out", tmp / "o.png", "--dpi", 50],
        "simulate": ["simulate", f["rig"], "--out", tmp / "o", "--frames", 2, "--jobs", 1],
    }[command]


def _check_input_case(sim, tmp_path, case):
    which, old, new, command, needles = case
    f = _broken_inputs(sim, tmp_path, which, old, new)
    error_line(cli(*_command(command, which, f, tmp_path)), 2, *needles)
    assert not any(p.name.startswith("o.") or p.name == "o" for p in tmp_path.iterdir())
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("case", [MALFORMED[k] for k in sorted(MALFORMED)], ids=sorted(MALFORMED))
def test_malformed_yaml_is_one_line_with_file_key_and_expected(sim, tmp_path, case):
    _check_input_case(sim, tmp_path, case)


@pytest.mark.parametrize("name", sorted(NONFINITE))
def test_nan_and_inf_are_refused_at_load(sim, tmp_path, name):
    _check_input_case(sim, tmp_path, NONFINITE[name])


@pytest.mark.parametrize("args, needles", [
    (["project", RIG, "--position", "nan", 0, 0, "--heading", 0, "--point", 1, 2, 3], ["--position", "finite"]),
    (["project", RIG, "--position", 0, 0, 0, "--heading", "inf", "--point", 1, 2, 3], ["--heading", "finite"]),
    (["simulate", RIG, "--out", "never", "--noise", "nan"], ["--noise", "nan"]),
    (["simulate", RIG, "--out", "never", "--blur", "inf"], ["--blur", "inf"]),
])
def test_nan_and_inf_options_are_refused(tmp_path, args, needles):
    error_line(cli(*args), 2, *needles)
    assert not Path("never").exists()


@pytest.mark.parametrize("args, says", [
    (["calibrate", "DATASET", "--out", "o.yaml", "--distortion", "bogus"], "'--distortion'"),
    (["calibrate", "DATASET", "--out", "o.yaml", "--jobs", "0"], "--jobs"),
    (["calibrate", "DATASET", "--out", "o.yaml", "--bogus"], "--bogus"),
    (["calibrate"], "Missing argument"),
    (["project", "RIG", "--position", "1", "2", "--point", "1", "2", "3"], "'--position'"),
])
def test_a_bad_option_is_one_line_and_exit_2(tmp_path, args, says):
    """A bad option value, an unknown option or a missing argument is bad input (cli.md):
    one stderr line naming the option, exit 2, nothing written; not typer's usage box."""
    proc = subprocess.run([sys.executable, "-m", "rigcal", *args], cwd=tmp_path, capture_output=True, text=True,
                          timeout=60)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and says in lines[0], proc.stderr
    # typer's own usage errors point at the help page; rigcal's checks name the option
    assert "--help" in lines[0] or lines[0].startswith("rigcal: --jobs: expected a positive number"), proc.stderr
    assert proc.stdout == "" and not list(tmp_path.iterdir())


def test_help_still_works(tmp_path):
    """--help exits 0 with the page on stdout; `rigcal` alone shows the help (exit 2, as typer does)."""
    h = subprocess.run([sys.executable, "-m", "rigcal", "calibrate", "--help"], capture_output=True, text=True,
                       timeout=60)
    assert h.returncode == 0 and "--distortion" in h.stdout and h.stderr == ""
    bare = subprocess.run([sys.executable, "-m", "rigcal"], capture_output=True, text=True, timeout=60)
    assert bare.returncode == 2 and "calibrate" in bare.stdout


@pytest.mark.slow
def test_a_declared_board_never_seen_is_named(sim, tmp_path):
    """A room's target.yaml with a board whose ids appear in no image (a misdeclared
    first_marker_id looks the same): calibrate works from the others and names it."""
    ds = copy_dataset(sim, tmp_path / "ds")
    doc = yaml.safe_load((ds / "target.yaml").read_text())
    extra = dict(doc["boards"][0], name="spare", first_marker_id=900)
    doc["boards"].append(extra)
    (ds / "target.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    r = RUNNER.invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml"), "--jobs", str(JOBS)])
    assert r.exit_code == 0, r.output
    assert "warning: board spare: never detected in" in r.output and "first_marker_id" in r.output
    assert "never detected" not in RUNNER.invoke(
        app, ["calibrate", str(sim), "--out", str(tmp_path / "cal2.yaml"), "--jobs", str(JOBS)]).output
