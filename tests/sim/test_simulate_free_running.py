"""`rigcal simulate --scene imu` with free-running cameras, per-camera rates and dropped
frames: each camera's schedule (own phase, period error, jitter, late start, early stop),
truth.yaml's per-camera record, corners of a free-running image at the truth pose of its
own stem plus offset, the options' bad values (one line, exit 2), and a shipped rig by
name. Renders are small (seconds)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core import geometry as geo
from rigcal.core.rig import load_rig, parse_rig, rig_from_dict
from rigcal.detect.detect import detect_image
from rigcal.sim.imu_scene import (EPOCH_NS, JITTER_S, MARGIN_S, RATE_ERROR, STAGGER_S, frame_timing,
                                  parse_camera_rates, simulate_motion_dataset)
from tests.support.rig_blocks import IMU_BLOCK

RIG = parse_rig("""\
rig: fr
""" + IMU_BLOCK + """\
cameras:
  front:
    model: pinhole
    resolution: [320, 240]
    intrinsics: {focal: 160.0}
    position: [0.1, 0.0, 0.0]
    axes: [-L, -U, F]
  back:
    model: pinhole
    resolution: [320, 240]
    intrinsics: {focal: 160.0}
    position: [-0.1, 0.0, 0.0]
    axes: [L, -U, -F]
""")
runner = CliRunner()


def test_synchronised_timing_is_the_shared_grid():
    t = frame_timing(RIG, 2.0, 10.0)
    assert np.array_equal(t.stems_ns[0], t.stems_ns[1]) and len(t.stems_ns[0]) == 20
    assert t.stems_ns[0][0] == EPOCH_NS + round(MARGIN_S * 1e9)
    assert np.all(np.diff(t.stems_ns[0]) == 100_000_000)


def test_per_camera_rates_keep_each_grid():
    t = frame_timing(RIG, 3.0, {"front": 20.0, "back": 30.0})
    assert [len(s) for s in t.stems_ns] == [60, 90] and t.rates_hz == (20.0, 30.0)
    # both grids start at MARGIN_S: they coincide every 0.1 s
    assert len(np.intersect1d(*t.stems_ns)) == 30


def test_free_running_schedules_are_their_own():
    duration, rate = 20.0, 20.0
    t = frame_timing(RIG, duration, rate, free_running=True, seed=4)
    a, b = t.stems_ns
    assert len(np.intersect1d(a, b)) == 0  # no shared stem
    for s in (a, b):
        d = np.diff(s) * 1e-9
        assert np.all(d > 0)
        # the period: off the nominal by at most RATE_ERROR, plus jitter (a few JITTER_S)
        period = np.median(d)
        assert abs(period * rate - 1.0) <= RATE_ERROR + 1e-6
        assert 0.3 * JITTER_S < np.std(d - period) / np.sqrt(2) < 3 * JITTER_S
        # starts up to STAGGER_S (+ a period) late, stops up to STAGGER_S early
        first, last = (s[0] - EPOCH_NS) * 1e-9 - MARGIN_S, (s[-1] - EPOCH_NS) * 1e-9 - MARGIN_S
        assert 0 <= first <= STAGGER_S + 1 / rate and duration - STAGGER_S - 1 / rate <= last <= duration
    # the IMU-clock times are the stems plus the camera's offset
    rig = RIG.with_cameras([RIG.cameras[0].__class__(**{**RIG.cameras[0].__dict__, "time_offset_s": 0.004}),
                            RIG.cameras[1]])
    t2 = frame_timing(rig, duration, rate, free_running=True, seed=4)
    assert np.allclose(t2.t_imu_s[0], (t2.stems_ns[0] - EPOCH_NS) * 1e-9 + 0.004, atol=1e-12)
    # seeded: the same schedule again, another seed another one
    assert np.array_equal(frame_timing(RIG, duration, rate, free_running=True, seed=4).stems_ns[1], b)
    assert not np.array_equal(frame_timing(RIG, duration, rate, free_running=True, seed=5).stems_ns[1][:5], b[:5])


def test_dropped_frames_keep_the_span():
    full = frame_timing(RIG, 10.0, 20.0)
    t = frame_timing(RIG, 10.0, 20.0, drop=0.2, seed=1)
    for s, f in zip(t.stems_ns, full.stems_ns):
        assert s[0] == f[0] and s[-1] == f[-1] and set(s) <= set(f)
        assert 0.1 * len(f) < len(f) - len(s) < 0.3 * len(f)
    assert not np.array_equal(*t.stems_ns)  # each camera drops its own


def test_camera_rate_texts():
    assert parse_camera_rates(None) is None
    assert parse_camera_rates(["25"]) == 25.0
    assert parse_camera_rates(["front=20", "back=30"]) == {"front": 20.0, "back": 30.0}


@pytest.fixture(scope="module")
def free(tmp_path_factory):
    out = tmp_path_factory.mktemp("free") / "ds"
    return simulate_motion_dataset(RIG, out, duration=1.6, camera_rate={"front": 5.0, "back": 7.0}, seed=3, jobs=1,
                                   free_running=True)


def test_free_running_files_and_truth(free):
    doc = yaml.safe_load((free.out_dir / "truth.yaml").read_text())
    stems = {c: sorted(int(p.stem) for p in (free.out_dir / "images" / c).glob("*.png")) for c in ("front", "back")}
    assert not set(stems["front"]) & set(stems["back"])
    assert doc["render"]["frames"] == {c: len(s) for c, s in stems.items()}
    assert doc["render"]["camera_rate_hz"] == {"front": 5.0, "back": 7.0}
    assert doc["render"]["shared_stems"] is False


def test_a_free_running_image_shows_the_truth_at_its_own_time(free):
    truth = rig_from_dict(yaml.safe_load((free.out_dir / "truth.yaml").read_text())["rig"], "truth.yaml")
    cam = truth.camera("front")
    errs, wrong = [], []
    for path in free.image_paths["front"]:
        t_img = (int(path.stem) - EPOCH_NS) * 1e-9 + cam.time_offset_s
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        for board, ids, uv, _ in detect_image(gray, free.target):
            bi = [b.name for b in free.target.boards].index(board)
            p_board = free.target.boards[bi].corners[ids]
            for t, sink in ((t_img, errs), (t_img + 0.03, wrong)):  # its own time; 30 ms off
                T_world_cam = free.trajectory.at(np.array([t])).T_world_body[0] @ cam.T_body_cam
                T = geo.inv_T(T_world_cam) @ free.T_world_board[bi]
                sink.append(cam.intrinsics.project(geo.transform(T, p_board))[0] - uv)
    assert errs, "no board detected"
    rms = lambda e: float(np.sqrt(np.mean(np.square(np.concatenate(e)))))  # noqa: E731
    assert rms(errs) <= 0.1 and rms(wrong) > 5 * rms(errs), (rms(errs), rms(wrong))


@pytest.mark.parametrize("args, needle", [
    (["--camera-rate", "front=20"], "no rate for camera back"),
    (["--camera-rate", "front=20", "--camera-rate", "side=30", "--camera-rate", "back=20"], "side is not a camera"),
    (["--camera-rate", "20", "--camera-rate", "back=30"], "not both"),
    (["--camera-rate", "front=fast", "--camera-rate", "back=30"], "'front=fast'"),
    (["--drop-frames", "1.5"], "--drop-frames"),
])
def test_bad_rates_are_one_line_and_nothing_written(tmp_path, args, needle):
    rig = tmp_path / "rig.yaml"
    rig.write_text("rig: fr\n" + IMU_BLOCK + """cameras:
  front: {model: pinhole, resolution: [64, 48], intrinsics: {focal: 40.0}, position: [0.1, 0, 0], axes: [-L, -U, F]}
  back: {model: pinhole, resolution: [64, 48], intrinsics: {focal: 40.0}, position: [-0.1, 0, 0], axes: [L, -U, -F]}
""")
    out = tmp_path / "out"
    r = runner.invoke(app, ["simulate", str(rig), "--scene", "imu", "--out", str(out), "--duration", "1", *args])
    assert r.exit_code == 2, r.output
    assert needle in r.output and len(r.output.strip().splitlines()) == 1, r.output
    assert not out.exists()


def test_free_running_is_only_for_the_imu_scene(tmp_path):
    r = runner.invoke(app, ["simulate", "drone-stereo-back", "--out", str(tmp_path / "o"), "--free-running"])
    assert r.exit_code == 2 and "--free-running: only used with --scene imu" in r.output, r.output


def test_a_shipped_rig_by_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no rig file of that name here: the shipped one is meant
    out = tmp_path / "d"
    r = runner.invoke(app, ["simulate", "drone-stereo-back-imu", "--scene", "imu", "--out", str(out),
                            "--duration", "0.25", "--camera-rate", "4", "--jobs", "1"])
    assert r.exit_code == 0, r.output
    shipped = Path(__file__).resolve().parents[2] / "rigs" / "drone-stereo-back-imu.yaml"
    assert (out / "rig.yaml").read_text() == shipped.read_text()
    assert load_rig("drone-stereo-back-imu").names == load_rig(out / "rig.yaml").names
