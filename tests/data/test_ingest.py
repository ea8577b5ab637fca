"""`rigcal ingest`: EuRoC folders, ROS 1 / ROS 2 bags and videos built here from a
small simulated recording; the dataset they give must hold the same frames (pixels, stems =
capture times), the same IMU samples, and calibrate to the same rig as the simulated folder."""

from __future__ import annotations

import os
import shutil
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from tests.support import recordings as R
from rigcal.core import geometry as geo
from rigcal.cli import app
from rigcal.errors import InputError
from rigcal.data.ingest import images as ims
from rigcal.data.ingest.video import frame_time_ns
from rigcal.data.ingest.writer import first_of_monotonic, thin_by_rate
from rigcal.core.rig import load_rig, rig_from_dict
from rigcal.sim.simulate import simulate_dataset

RIG = R.SMALL_STEREO
IMUS = "\n" + R.IMU_BLOCK
CAMS = ("left", "right")
runner = CliRunner()


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    root = tmp_path_factory.mktemp("ingest")
    (root / "rig.yaml").write_text(RIG)
    simulate_dataset(load_rig(root / "rig.yaml"), root / "sim", scene="board", frames=10, noise=1.0, jobs=2, seed=5)
    return root


def _stamped(sim_dir: Path, out: Path, drop: dict[str, int] | None = None) -> Path:
    """The simulated dataset with frame i renamed to its capture time T0 + i * DT (the
    reference every ingested dataset is compared with); `drop` removes a camera's first frames."""
    for cam in CAMS:
        (out / "images" / cam).mkdir(parents=True)
        frames = R.sim_frames(sim_dir, cam)
        for i, (t, f) in enumerate(zip(R.stamps(len(frames)), frames)):
            if i >= (drop or {}).get(cam, 0):
                shutil.copyfile(f, out / "images" / cam / f"{t}.png")
    shutil.copyfile(sim_dir / "rig.yaml", out / "rig.yaml")
    shutil.copyfile(sim_dir / "target.yaml", out / "target.yaml")
    return out


def _calibrate(dataset: Path, out: Path, rig: Path | None = None):
    # camera-only: the recordings are 1 s long, too short for the camera-IMU step, and the
    # comparison is with the simulated folder's camera calibration
    args = (["calibrate", str(dataset), "--out", str(out), "--jobs", "1", "--camera-only"]
            + (["--rig", str(rig)] if rig else []))
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    return load_rig(out)


@pytest.fixture(scope="module")
def reference(sim):
    ds = _stamped(sim / "sim", sim / "stamped")
    return _calibrate(ds, sim / "stamped.yaml")


def _assert_same_calibration(a, b, px=1e-6, m=1e-9, deg=1e-7):
    for ca in a.cameras:
        cb = b.camera(ca.name)
        ia, ib = ca.intrinsics, cb.intrinsics
        assert ia.model == ib.model
        np.testing.assert_allclose([ia.fx, ia.fy, ia.cx, ia.cy], [ib.fx, ib.fy, ib.cx, ib.cy], rtol=0, atol=px)
        np.testing.assert_allclose(ia.dist, ib.dist, rtol=0, atol=px * 1e-2)
        np.testing.assert_allclose(ca.T_body_cam[:3, 3], cb.T_body_cam[:3, 3], rtol=0, atol=m)
        assert geo.rotation_angle_deg(ca.T_body_cam[:3, :3].T @ cb.T_body_cam[:3, :3]) <= deg


def _ingest(*args) -> object:
    return runner.invoke(app, ["ingest", *map(str, args)])


def _images(ds: Path, cam: str) -> dict[int, np.ndarray]:
    return {int(p.stem): cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((ds / "images" / cam).iterdir())}


def _assert_same_frames(ds: Path, sim_dir: Path, stamp_of: dict[str, list[int]] | None = None):
    for cam in CAMS:
        got = _images(ds, cam)
        frames = R.sim_frames(sim_dir, cam)
        want_t = stamp_of[cam] if stamp_of else R.stamps(len(frames)).tolist()
        assert sorted(got) == sorted(want_t)
        for t, f in zip(R.stamps(len(frames)).tolist(), frames):
            if t in got:
                assert np.array_equal(got[t], cv2.imread(str(f), cv2.IMREAD_UNCHANGED)), (cam, t)


def _read_imu(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = path.read_text().splitlines()
    assert lines[0] == R.IMU_HEADER
    t = np.array([int(ln.split(",")[0]) for ln in lines[1:]], np.int64)
    v = np.array([[float(x) for x in ln.split(",")[1:]] for ln in lines[1:]])
    return t, v


# ----------------------------------------------------------------------------- EuRoC


@pytest.fixture(scope="module")
def euroc(sim):
    src = sim / "euroc"
    R.write_euroc(src, sim / "sim", load_rig(sim / "rig.yaml"), {"cam0": "left", "cam1": "right"})
    return src


def test_euroc_folder_gives_the_same_frames_imu_rig_and_calibration(sim, euroc, reference, tmp_path):
    ds = tmp_path / "ds"
    before = sorted(p.relative_to(euroc) for p in euroc.rglob("*"))
    res = _ingest(euroc, "--out", ds, "--camera", "left=cam0", "--camera", "right=cam1", "--imu", "imu0=imu0",
                  "--target", sim / "sim" / "target.yaml")
    assert res.exit_code == 0, res.output
    assert "images/left/: 10 of 10 frames" in res.output and "imu/imu0.csv: " in res.output
    assert sorted(p.relative_to(euroc) for p in euroc.rglob("*")) == before  # the source is untouched
    _assert_same_frames(ds, sim / "sim")
    assert all(p.is_symlink() for p in (ds / "images" / "left").iterdir())
    t, v = _read_imu(ds / "imu" / "imu0.csv")
    t_src, v_src = _read_imu(euroc / "mav0" / "imu0" / "data.csv")
    assert np.array_equal(t, t_src) and np.array_equal(v, v_src)  # full precision: every double survives

    doc = yaml.safe_load((ds / "rig.yaml").read_text())
    declared = load_rig(sim / "rig.yaml")
    got = rig_from_dict(doc)  # the whole rig, imus included, loads
    for c in declared.cameras:
        g = got.camera(c.name)
        np.testing.assert_allclose(g.T_body_cam, c.T_body_cam, atol=1e-12)
        assert g.intrinsics.fx == c.intrinsics.fx and g.intrinsics.dist[:4] == c.intrinsics.dist[:4]
    assert doc["stereo_pairs"] == [["left", "right"]]
    imu = doc["imus"]["imu0"]  # imu.md: pose in FLU, rate and Kalibr's noise figures from sensor.yaml
    np.testing.assert_allclose(imu["rotation"], [[0, 0, 1], [0, -1, 0], [1, 0, 0]], atol=0)
    assert imu["position"] == [0.0, 0.0, 0.0] and imu["update_rate"] == 200.0
    assert {k: imu[k] for k in R.NOISE} == R.NOISE
    np.testing.assert_allclose(got.imu("imu0").T_body_imu[:3, :3], imu["rotation"], atol=0)

    cal = _calibrate(ds, tmp_path / "cal.yaml")  # the written rig, imus and all
    _assert_same_calibration(cal, reference)


def test_euroc_default_names_copy_and_body_axes(sim, euroc, tmp_path):
    ds = tmp_path / "ds"
    res = _ingest(euroc / "mav0", "--out", ds, "--copy", "--body-axes", "F", "L", "U")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (ds / "images").iterdir()) == ["cam0", "cam1"]
    assert (ds / "imu" / "imu0.csv").is_file()  # neither --camera nor --imu: every sensor
    assert not any(p.is_symlink() for p in (ds / "images" / "cam0").iterdir())
    doc = yaml.safe_load((ds / "rig.yaml").read_text())
    # B taken as FLU: the declared poses are T_BS itself, which write_euroc made with U -L F
    R_BS = np.array(doc["cameras"]["cam0"]["rotation"])
    R_flu_B = geo.R_from_axes(["U", "-L", "F"])
    np.testing.assert_allclose(R_flu_B @ R_BS, geo.R_from_look("forward"), atol=1e-12)
    assert "gravity" in res.output and "check --body-axes" in res.output  # gravity reads +x = F here, not U
    res = _ingest(euroc, "--out", tmp_path / "ds2")
    assert res.exit_code == 0 and "gravity" not in res.output
    res = _ingest(euroc, "--out", tmp_path / "ds3", "--camera", "cam0=cam0")  # cameras chosen, no --imu: no IMU
    assert res.exit_code == 0 and not (tmp_path / "ds3" / "imu").exists()
    assert "imus" not in yaml.safe_load((tmp_path / "ds3" / "rig.yaml").read_text())


def test_start_end_window_and_rate_keeps_the_sharpest_shared_instant(sim, tmp_path):
    src = tmp_path / "euroc"
    R.write_euroc(src, sim / "sim", load_rig(sim / "rig.yaml"), {"cam0": "left", "cam1": "right"})
    for cam in ("cam0", "cam1"):  # blur every frame but the odd ones: at 10 Hz each slot holds one sharp frame
        for i, p in enumerate(sorted((src / "mav0" / cam / "data").iterdir())):
            if i % 2 == 0:
                cv2.imwrite(str(p), cv2.GaussianBlur(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), (0, 0), 3.0))
    t = R.stamps(10)
    res = _ingest(src, "--out", tmp_path / "thin", "--rate", "10")
    assert res.exit_code == 0, res.output
    for cam in ("cam0", "cam1"):
        assert sorted(int(p.stem) for p in (tmp_path / "thin" / "images" / cam).iterdir()) == t[1::2].tolist()
    res = _ingest(src, "--out", tmp_path / "win", "--start", "0.1", "--end", "0.3")
    assert res.exit_code == 0, res.output
    assert sorted(int(p.stem) for p in (tmp_path / "win" / "images" / "cam0").iterdir()) == t[2:7].tolist()
    res = _ingest(src, "--out", tmp_path / "late", "--start", "0.35")
    assert res.exit_code == 0, res.output
    assert sorted(int(p.stem) for p in (tmp_path / "late" / "images" / "cam1").iterdir()) == t[7:].tolist()
    t_imu, _ = _read_imu(tmp_path / "late" / "imu" / "imu0.csv")  # the window widened by 0.5 s
    t_src, _ = _read_imu(src / "mav0" / "imu0" / "data.csv")
    inside = t_src[t_src >= t[0] + 350_000_000 - 500_000_000]
    assert np.array_equal(t_imu, inside) and len(inside) < len(t_src)


def test_thin_by_rate_unsynchronised_cameras_keep_their_own_sharpest():
    t0 = 0
    focus = {"a": {0: 1.0, 30: 5.0, 100: 2.0}, "b": {10: 3.0, 40: 1.0, 110: 1.0, 120: 4.0}}
    kept = thin_by_rate(focus, t0, rate_hz=1e9 / 100)  # slots of 100 ns
    assert kept == {"a": [30, 100], "b": [10, 120]}
    shared = thin_by_rate({"a": {0: 1.0, 50: 2.0}, "b": {0: 9.0, 50: 1.5}}, 0, 1e9 / 100)
    assert shared == {"a": [50], "b": [50]}  # the instant whose blurrier camera is sharpest


# ----------------------------------------------------------------------------- bags


def _bag_images(sim_dir: Path, colour: bool = False) -> dict[str, list[tuple[int, np.ndarray]]]:
    out = {}
    for cam in CAMS:
        frames = R.sim_frames(sim_dir, cam)
        imgs = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in frames]
        if colour:
            imgs = [cv2.cvtColor(i, cv2.COLOR_GRAY2BGR) for i in imgs]
        out[cam] = list(zip(R.stamps(len(frames)).tolist(), imgs))
    return out


def _imu(n: int = 10):
    t = R.stamps(n)
    return R.synthetic_imu(int(t[0]), int(t[-1]))


@pytest.mark.parametrize("kind,compressed,encoding", [("ros1", False, "mono8"), ("sqlite3", True, None),
                                                      ("mcap", False, "rgb8"), ("ros1", True, None)])
def test_bag_gives_the_same_frames_imu_and_calibration(sim, reference, tmp_path, kind, compressed, encoding):
    colour = encoding == "rgb8"
    bag = R.write_bag(tmp_path / ("rec.bag" if kind == "ros1" else "rec"), kind, _bag_images(sim / "sim", colour),
                      _imu(), compressed=compressed, encoding=encoding)
    suffix = "/compressed" if compressed else ""
    ds = tmp_path / "ds"
    (tmp_path / "rig_imu.yaml").write_text(RIG + IMUS)
    res = _ingest(bag, "--out", ds, "--camera", f"left=/left/image_raw{suffix}", "--camera",
                  f"right=/right/image_raw{suffix}", "--imu", "imu0=/imu0", "--rig", tmp_path / "rig_imu.yaml",
                  "--target", sim / "sim" / "target.yaml")
    assert res.exit_code == 0, res.output
    if colour:
        for cam in CAMS:
            for t, img in _images(ds, cam).items():
                assert img.ndim == 3 and np.array_equal(img[:, :, 0], img[:, :, 2])
                (ds / "images" / cam / f"{t}.png").unlink()
                cv2.imwrite(str(ds / "images" / cam / f"{t}.png"), cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    _assert_same_frames(ds, sim / "sim")  # stems are header stamps, not the later record times
    t, v = _read_imu(ds / "imu" / "imu0.csv")
    t_src, g, a = _imu()
    assert np.array_equal(t, t_src) and np.array_equal(v, np.column_stack([g, a]))
    assert (ds / "rig.yaml").read_text() == RIG + IMUS  # --rig is copied as written
    cal = _calibrate(ds, tmp_path / "cal.yaml")  # the rig given with --rig, imus and all
    _assert_same_calibration(cal, reference)


def test_rig_must_declare_the_ingested_sensors(sim, tmp_path):
    bag = R.write_bag(tmp_path / "rec.bag", "ros1", _bag_images(sim / "sim"), _imu())
    res = _ingest(bag, "--out", tmp_path / "ds", "--camera", "left=/left/image_raw", "--camera",
                  "right=/right/image_raw", "--imu", "imu0=/imu0", "--rig", sim / "rig.yaml")
    assert res.exit_code == 2 and "imus: declares none but the recording gives imu0" in res.output
    res = _ingest(bag, "--out", tmp_path / "ds", "--camera", "left=/left/image_raw", "--rig", sim / "rig.yaml")
    assert res.exit_code == 2 and "declares left, right but the recording gives left" in res.output
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_bag_camera_info_gives_a_rig_of_intrinsics(sim, tmp_path, kind):
    declared = load_rig(sim / "rig.yaml")
    info = {c.name: c.intrinsics for c in declared.cameras}
    bag = R.write_bag(tmp_path / ("rec.bag" if kind == "ros1" else "rec"), kind, _bag_images(sim / "sim"), None,
                      camera_info=info)
    res = _ingest(bag, "--out", tmp_path / "ds", "--camera", "left=/left/image_raw", "--camera",
                  "right=/right/image_raw", "--target", sim / "sim" / "target.yaml")
    assert res.exit_code == 0, res.output
    assert "rig.yaml: from CameraInfo topics" in res.output
    rig = load_rig(tmp_path / "ds" / "rig.yaml")
    for c in rig.cameras:
        m = declared.camera(c.name).intrinsics
        assert c.T_body_cam is None  # a CameraInfo does not say where the camera is
        assert (c.intrinsics.fx, c.intrinsics.cy, c.intrinsics.width) == (m.fx, m.cy, m.width)
        assert c.intrinsics.dist == tuple(m.dist[:4])
    res = runner.invoke(app, ["calibrate", str(tmp_path / "ds"), "--out", str(tmp_path / "cal.yaml"), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    res = _ingest(bag, "--out", tmp_path / "ds2", "--camera", "left=/left/image_raw", "--camera",
                  "right=/nope/image_raw")
    assert res.exit_code == 2 and "/nope/image_raw" in res.output


def test_bag_without_camera_lists_topics_and_writes_nothing(sim, tmp_path):
    bag = R.write_bag(tmp_path / "rec.bag", "ros1", _bag_images(sim / "sim"), _imu())
    res = _ingest(bag, "--out", tmp_path / "ds")
    assert res.exit_code == 2
    assert "/left/image_raw" in res.output and "/imu0" in res.output and "20.0 Hz" in res.output
    assert "200" in res.output and not (tmp_path / "ds").exists()
    res = _ingest(bag, "--out", tmp_path / "ds", "--camera", "left=/nope")
    assert res.exit_code == 2 and "/nope" in res.output and "/right/image_raw" in res.output
    assert not (tmp_path / "ds").exists()


def test_bad_bags_are_one_line_and_write_nothing(sim, tmp_path):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"this is not a bag\n" * 50)
    bag = R.write_bag(tmp_path / "rec.bag", "ros1", _bag_images(sim / "sim"), None)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    cut2 = []
    for kind in ("sqlite3", "mcap"):  # ROS 2 bag folders whose storage file was cut short
        d = R.write_bag(tmp_path / kind, kind, _bag_images(sim / "sim"), None)
        f = next(p for p in d.iterdir() if p.suffix in (".db3", ".mcap"))
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
        cut2.append(d)
    for src in (junk, cut, *cut2):
        res = _ingest(src, "--out", tmp_path / "ds", "--camera", "left=/left/image_raw")
        assert res.exit_code == 2, res.output
        assert str(src) in res.output and len(res.output.strip().splitlines()) == 1
        assert not (tmp_path / "ds").exists() and not list(tmp_path.glob(".ds*"))


def test_unsupported_encoding_is_named(sim, tmp_path):
    img = np.zeros((8, 8), np.float32)
    imgs = {"left": [(R.T0_NS, img)]}
    bag = R.write_bag(tmp_path / "rec.bag", "ros1", imgs, None, encoding="32FC1")
    res = _ingest(bag, "--out", tmp_path / "ds", "--camera", "left=/left/image_raw")
    assert res.exit_code == 2 and "'32FC1'" in res.output and "/left/image_raw, message 1" in res.output
    assert not (tmp_path / "ds").exists()


def test_duplicated_and_backwards_stamps_keep_the_first(sim, tmp_path):
    imgs = _bag_images(sim / "sim")["left"]
    t = [s for s, _ in imgs]
    # message 4 repeats message 3's stamp; message 6 goes back before message 5
    order = [(t[0], imgs[0][1]), (t[1], imgs[1][1]), (t[2], imgs[2][1]), (t[2], imgs[3][1]), (t[4], imgs[4][1]),
             (t[3], imgs[5][1]), (t[5], imgs[6][1])]
    bag = tmp_path / "rec.bag"
    _write_in_order(bag, order)  # record times increase in message order, whatever the header stamps say
    res = _ingest(bag, "--out", tmp_path / "ds", "--camera", "left=/left/image_raw")
    assert res.exit_code == 0, res.output
    assert "1 duplicated and 1 backwards" in res.output
    got = _images(tmp_path / "ds", "left")
    assert sorted(got) == [t[0], t[1], t[2], t[4], t[5]]
    assert np.array_equal(got[t[2]], imgs[2][1])  # the first of the two frames stamped t[2]


def _write_in_order(path: Path, frames):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as w:
        c = w.add_connection("/left/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        for i, (t, img) in enumerate(frames):
            w.write(c, R.T0_NS + i * 1000, ts.serialize_ros1(R.image_msg(ts, img, t, True), "sensor_msgs/msg/Image"))


def test_out_needs_force(sim, euroc, tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "keep.txt").write_text("mine")
    res = _ingest(euroc, "--out", ds)
    assert res.exit_code == 2 and "--force" in res.output
    assert [p.name for p in ds.iterdir()] == ["keep.txt"]
    res = _ingest(euroc, "--out", ds, "--force")
    assert res.exit_code == 0 and not (ds / "keep.txt").exists() and (ds / "images" / "cam0").is_dir()


# ----------------------------------------------------------------------------- video


def test_videos_with_a_start_offset_give_the_same_frames_and_calibration(sim, tmp_path):
    drop = 3  # the right camera started 3 frames (0.15 s) after the left one
    frames = {c: [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in R.sim_frames(sim / "sim", c)] for c in CAMS}
    (tmp_path / "videos").mkdir()
    R.write_video(tmp_path / "videos" / "left.mkv", frames["left"])
    R.write_video(tmp_path / "videos" / "right.mkv", frames["right"][drop:])
    ds = tmp_path / "ds"
    res = _ingest(tmp_path / "videos", "--out", ds, "--camera", "left=left.mkv", "--camera", "right=right.mkv", "--offset",
                  "right=0.15", "--rig", sim / "rig.yaml", "--target", sim / "sim" / "target.yaml")
    assert res.exit_code == 0, res.output
    t = (R.stamps(10) - R.T0_NS).tolist()  # container clocks start at 0
    for cam, first in (("left", 0), ("right", drop)):
        got = _images(ds, cam)
        assert sorted(got) == t[first:]
        for i in range(first, 10):
            assert np.array_equal(got[t[i]], frames[cam][i])  # ffv1 is lossless
    ref = _stamped(sim / "sim", tmp_path / "ref", drop={"right": drop})
    for cam in CAMS:  # the same stems as the video dataset, so both calibrate the same frames
        for p in (ref / "images" / cam).iterdir():
            p.rename(p.with_name(f"{int(p.stem) - R.T0_NS}.png"))
    _assert_same_calibration(_calibrate(ds, tmp_path / "cal.yaml"), _calibrate(ref, tmp_path / "ref.yaml"))


def test_video_without_timestamps_and_listing(sim, tmp_path):
    import av

    raw = tmp_path / "cam.h264"  # a raw H.264 stream: no container, no timestamps
    with av.open(str(raw), "w", format="h264") as c:
        s = c.add_stream("libx264", rate=20)
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        for i in range(3):
            for p in s.encode(av.VideoFrame.from_ndarray(np.full((48, 64, 3), 40 * i, np.uint8), format="bgr24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    res = _ingest(raw, "--out", tmp_path / "ds")
    assert res.exit_code == 2 and "no timestamp" in res.output and str(raw) in res.output
    assert not (tmp_path / "ds").exists()
    res = _ingest(tmp_path, "--out", tmp_path / "ds")
    assert res.exit_code == 2 and "overlaps the source" in res.output  # --force would delete the source
    res = _ingest(tmp_path, "--out", tmp_path.parent / f"{tmp_path.name}_ds")
    assert res.exit_code == 2 and "cam.h264" in res.output and "--camera" in res.output


def test_frame_time_is_exact_rational():
    assert frame_time_ns(3, Fraction(1, 30), Fraction("0.1"), "x") == 200_000_000
    assert frame_time_ns(1001, Fraction(1, 30000), Fraction(0), "x") == 33_366_667  # rounded to the nearest ns
    with pytest.raises(InputError, match="no timestamp"):
        frame_time_ns(None, Fraction(1, 30), Fraction(0), "x")


# ----------------------------------------------------------------------------- pixels


def test_bayer_rggb_demosaics_to_the_right_colours():
    h, w = 32, 32
    bgr = np.zeros((h, w, 3), np.uint8)
    bgr[:] = (30, 120, 220)  # flat colour: B 30, G 120, R 220
    mosaic = np.empty((h, w), np.uint8)  # rggb: R at (even, even), B at (odd, odd)
    mosaic[0::2, 0::2] = 220
    mosaic[0::2, 1::2] = 120
    mosaic[1::2, 0::2] = 120
    mosaic[1::2, 1::2] = 30
    out = ims.raw_pixels("bayer_rggb8", h, w, w, False, mosaic.ravel())
    np.testing.assert_allclose(out[4:-4, 4:-4].reshape(-1, 3).mean(axis=0), (30, 120, 220), atol=1.0)
    swapped = ims.raw_pixels("bayer_bggr8", h, w, w, False, mosaic.ravel())
    assert abs(float(swapped[8:-8, 8:-8, 2].mean()) - 30) < 1.0  # read as bggr, red and blue swap


def test_mono16_keeps_the_significant_bits_and_padding_is_skipped():
    img = np.array([[0, 4095], [2048, 1024]], np.uint16)  # a 12-bit sensor
    data = np.zeros((2, 6), np.uint8)  # step 6: 2 bytes of row padding
    data[:, :4] = img.astype("<u2").view(np.uint8).reshape(2, 4)
    out = ims.raw_pixels("mono16", 2, 2, 6, False, data.ravel())
    assert out.tolist() == [[0, 255], [128, 64]]
    big = ims.raw_pixels("mono16", 2, 2, 4, True, img.astype(">u2").view(np.uint8).ravel())
    assert big.tolist() == out.tolist()
    with pytest.raises(ims.EncodingError, match="holds 3 bytes"):
        ims.raw_pixels("mono8", 2, 2, 2, False, np.zeros(3, np.uint8))


def test_focus_measure_prefers_the_sharp_frame():
    rng = np.random.default_rng(0)
    img = (rng.random((64, 64)) > 0.5).astype(np.uint8) * 255
    assert ims.focus_measure(img) > 10 * ims.focus_measure(cv2.GaussianBlur(img, (0, 0), 2.0))


def test_first_of_monotonic_counts():
    keep, dup, back = first_of_monotonic(np.array([1, 2, 2, 5, 3, 4, 6, 6]))
    assert keep.tolist() == [True, True, False, True, False, False, True, False]
    assert (dup, back) == (2, 2)


# ----------------------------------------------------------------------------- EuRoC's own files

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real" / "euroc_imu_april"
CAM0_YAML = """%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""
CAM1_T_BS = """  data: [0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556,
         0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024,
        -0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038,
         0.0, 0.0, 0.0, 1.0]
"""
IMU0_YAML = """#Default imu sensor yaml file
sensor_type: imu
comment: VI-Sensor IMU (ADIS16448)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0,
         0.0, 1.0, 0.0, 0.0,
         0.0, 0.0, 1.0, 0.0,
         0.0, 0.0, 0.0, 1.0]
rate_hz: 200

# inertial sensor noise model parameters (static)
gyroscope_noise_density: 1.6968e-04     # [ rad / s / sqrt(Hz) ]   ( gyro "white noise" )
gyroscope_random_walk: 1.9393e-05       # [ rad / s^2 / sqrt(Hz) ] ( gyro bias diffusion )
accelerometer_noise_density: 2.0000e-3  # [ m / s^2 / sqrt(Hz) ]  ( accel "white noise" )
accelerometer_random_walk: 3.0000e-3    # [ m / s^3 / sqrt(Hz) ].  ( accel bias diffusion )
"""


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/real is not beside this checkout")
def test_euroc_sensor_yaml_as_shipped_gives_a_forward_stereo_rig_with_the_imu_up(tmp_path):
    """EuRoC's published sensor.yaml files and its real imu0 stream: with the default body
    axes (U -L F) both cameras look forward, cam0 is the left one 110.07 mm from cam1, and
    gravity at the start of the recording reads up; taking B as FLU is flagged."""
    mav0 = tmp_path / "src" / "mav0"
    lines = CAM0_YAML.splitlines(keepends=True)
    cam1 = "".join(lines[:9]) + CAM1_T_BS + "".join(lines[13:])
    t_imu = np.array([int(ln.split(",")[0]) for ln in (REAL / "imu0.csv").read_text().splitlines()[1:200]])
    for cam, text in (("cam0", CAM0_YAML), ("cam1", cam1.replace("cam0", "cam1"))):
        (mav0 / cam / "data").mkdir(parents=True)
        (mav0 / cam / "sensor.yaml").write_text(text)
        rows = [int(t) for t in t_imu[40:120:4]]
        for t in rows:
            cv2.imwrite(str(mav0 / cam / "data" / f"{t}.png"), np.zeros((480, 752), np.uint8))
        (mav0 / cam / "data.csv").write_text(R.EUROC_HEADER + "\n" + "".join(f"{t},{t}.png\n" for t in rows))
    (mav0 / "imu0").mkdir()
    shutil.copyfile(REAL / "imu0.csv", mav0 / "imu0" / "data.csv")
    (mav0 / "imu0" / "sensor.yaml").write_text(IMU0_YAML)
    res = _ingest(tmp_path / "src", "--out", tmp_path / "ds")
    assert res.exit_code == 0, res.output
    assert "gravity" not in res.output
    doc = yaml.safe_load((tmp_path / "ds" / "rig.yaml").read_text())
    rig = rig_from_dict(doc)
    for cam in rig.cameras:
        z_body = cam.T_body_cam[:3, 2]  # the optical axis in FLU
        assert np.degrees(np.arccos(z_body[0])) < 3.0, (cam.name, z_body)
    left, right = rig.camera("cam0").T_body_cam[:3, 3], rig.camera("cam1").T_body_cam[:3, 3]
    assert left[1] > right[1]  # cam0 sits to the left
    assert abs(np.linalg.norm(left - right) * 1000 - 110.07) < 0.01
    assert doc["stereo_pairs"] == [["cam0", "cam1"]]
    assert doc["imus"]["imu0"]["gyroscope_noise_density"] == pytest.approx(1.6968e-04, rel=1e-12)
    t, v = _read_imu(tmp_path / "ds" / "imu" / "imu0.csv")
    assert len(t) > 100 and np.all(np.diff(t) > 0)
    res = _ingest(tmp_path / "src", "--out", tmp_path / "ds2", "--body-axes", "F", "L", "U")
    assert res.exit_code == 0 and "check --body-axes" in res.output


@pytest.mark.parametrize("fault,expect", [
    ("missing_image", "cam0/data.csv: row 3: image"),
    ("imu_cell", "imu0/data.csv: row 5: expected numbers"),
    ("imu_columns", "imu0/data.csv: row 2: expected 7 columns"),
    ("camera_stamp", "cam1/data.csv: row 2: expected an integer timestamp in ns, got '14037x'"),
    ("t_bs", "cam0/sensor.yaml: T_BS: expected a rigid 4x4 transform"),
])
def test_bad_euroc_folders_name_file_and_row(sim, tmp_path, fault, expect):
    src = tmp_path / "src"
    R.write_euroc(src, sim / "sim", load_rig(sim / "rig.yaml"), {"cam0": "left", "cam1": "right"})
    mav0 = src / "mav0"
    if fault == "missing_image":
        sorted((mav0 / "cam0" / "data").iterdir())[1].unlink()
    elif fault in ("imu_cell", "imu_columns"):
        lines = (mav0 / "imu0" / "data.csv").read_text().splitlines()
        i = 4 if fault == "imu_cell" else 1
        lines[i] = lines[i].replace(",", ",x", 1) if fault == "imu_cell" else lines[i].rsplit(",", 1)[0]
        (mav0 / "imu0" / "data.csv").write_text("\n".join(lines) + "\n")
    elif fault == "camera_stamp":
        lines = (mav0 / "cam1" / "data.csv").read_text().splitlines()
        lines[1] = "14037x," + lines[1].split(",")[1]
        (mav0 / "cam1" / "data.csv").write_text("\n".join(lines) + "\n")
    else:
        text = (mav0 / "cam0" / "sensor.yaml").read_text()
        (mav0 / "cam0" / "sensor.yaml").write_text(text.replace("data: [0.0, -1.0,", "data: [2.0, -1.0,"))
    res = _ingest(src, "--out", tmp_path / "ds")
    assert res.exit_code == 2, res.output
    assert expect in res.output and len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "ds").exists() and not list(tmp_path.glob(".ds*"))


def test_compressed_jpeg_is_written_as_recorded(sim, tmp_path):
    """A CompressedImage's JPEG bytes become the .jpg file unchanged (no second lossy encode)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    imgs = _bag_images(sim / "sim")["left"][:3]
    msgs = [R.compressed_msg(ts, img, t, False, fmt="jpg") for t, img in imgs]
    with Writer(tmp_path / "rec", version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        c = w.add_connection("/left/image_raw/compressed", "sensor_msgs/msg/CompressedImage", typestore=ts)
        for (t, _), m in zip(imgs, msgs):
            w.write(c, t, ts.serialize_cdr(m, "sensor_msgs/msg/CompressedImage"))
    res = _ingest(tmp_path / "rec", "--out", tmp_path / "ds", "--camera", "left=/left/image_raw/compressed")
    assert res.exit_code == 0, res.output
    for (t, _), m in zip(imgs, msgs):
        assert (tmp_path / "ds" / "images" / "left" / f"{t}.jpg").read_bytes() == bytes(m.data)


def test_unwritable_output_and_a_full_disk_mid_way_leave_nothing(sim, euroc, tmp_path, monkeypatch):
    import errno

    from rigcal.data.ingest import writer

    blocker = tmp_path / "a_file"
    blocker.write_text("keep me")
    res = _ingest(euroc, "--out", blocker / "ds")
    assert res.exit_code == 2 and str(blocker) in res.output and blocker.read_text() == "keep me"
    calls = []
    real = writer.os.symlink

    def fills_up(src, dst, *a, **k):
        calls.append(dst)
        if len(calls) > 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(src, dst, *a, **k)

    monkeypatch.setattr(writer.os, "symlink", fills_up)
    res = _ingest(euroc, "--out", tmp_path / "ds")
    assert res.exit_code == 2 and "No space left on device" in res.output and str(tmp_path / "ds") in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_a_file_that_is_not_a_video_is_named(tmp_path):
    bad = tmp_path / "src" / "cam.mp4"
    bad.parent.mkdir()
    bad.write_bytes(b"\x00not a video" * 100)
    res = _ingest(bad, "--out", tmp_path / "ds")
    assert res.exit_code == 2 and f"{bad}: not a readable video" in res.output
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "ds").exists()


def _readme_commands() -> list[list[str]]:
    """The shell block of README's "From your recording", one argv per command."""
    import shlex

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    section = text[text.index("## From your recording"):]
    block = section[section.index("```sh") + 5: section.index("```", section.index("```sh") + 5)]
    lines = block.replace("\\\n", " ").splitlines()
    return [shlex.split(ln, comments=True)[1:] for ln in lines if ln.strip().startswith("rigcal ")]


def test_readme_commands_run_on_the_example_recordings(tmp_path, monkeypatch):
    R.build_examples(tmp_path / "recs")
    monkeypatch.chdir(tmp_path / "recs")
    cmds = _readme_commands()
    assert len(cmds) >= 7 and {c[1] for c in cmds if c[0] == "ingest"} >= {"euroc_seq", "rec.bag", "rec_mcap", "videos"}
    for argv in cmds:
        lists_topics = argv[0] == "ingest" and argv[1] == "rec.bag" and "--camera" not in argv
        res = runner.invoke(app, argv)
        assert res.exit_code == (2 if lists_topics else 0), (argv, res.output)
    assert (tmp_path / "recs" / "calibrated.yaml").is_file()


def test_offsets_are_checked(tmp_path):
    src = tmp_path / "videos"
    src.mkdir()
    frames = [np.full((16, 16), 10 * i, np.uint8) for i in range(4)]
    R.write_video(src / "a.mkv", frames)
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "a=-1")
    assert res.exit_code == 2 and "before 0" in res.output and "--offset" in res.output
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "b=0.5")
    assert res.exit_code == 2 and "--offset b: not a camera given with --camera" in res.output
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "a=soon")
    assert res.exit_code == 2 and "expected a number of seconds" in res.output
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "a=0.5")
    assert res.exit_code == 0, res.output
    assert sorted(int(p.stem) for p in (tmp_path / "ds" / "images" / "a").iterdir()) == [
        500_000_000, 550_000_000, 600_000_000, 650_000_000]
