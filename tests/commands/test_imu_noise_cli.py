"""`rigcal imu-noise` through typer's CliRunner: the figures of known synthetic recordings in
every output format, and every bad input as one stderr line, exit 2, nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.cli import app
from tests.support.imu_static import static_imu, write_csv

RATE = 100.0
# large random walks, so that they dominate from tau ~1 s and 20 min is enough
ND = np.array([1e-3, 1e-3, 1e-3, 2e-3, 2e-3, 2e-3])
KW = np.array([1e-3, 1e-3, 1e-3, 2e-3, 2e-3, 2e-3])


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def refused(result, *needles):
    assert result.exit_code == 2, (result.exit_code, result.stdout[-2000:], result.stderr[-2000:])
    assert "Traceback" not in result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("imu")
    t, g, a = static_imu(1200, RATE, ND, KW, seed=7)
    return write_csv(d / "imu0.csv", t, g, a), (t, g, a)


def test_kalibr_yaml_and_report(recording, tmp_path):
    path, _ = recording
    out, rep = tmp_path / "imu.yaml", tmp_path / "r.html"
    r = run("imu-noise", path, "--out", out, "--report", rep)
    assert r.exit_code == 0, r.stderr
    doc = yaml.safe_load(out.read_text())
    assert set(doc) == {"accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                        "gyroscope_random_walk", "update_rate", "rostopic"}
    assert doc["gyroscope_noise_density"] == pytest.approx(1e-3, rel=0.03)
    assert doc["accelerometer_noise_density"] == pytest.approx(2e-3, rel=0.03)
    assert doc["gyroscope_random_walk"] == pytest.approx(1e-3, rel=0.35)
    assert doc["accelerometer_random_walk"] == pytest.approx(2e-3, rel=0.35)
    assert doc["update_rate"] == pytest.approx(RATE)
    assert doc["rostopic"] == "/imu0"
    page = rep.read_text()
    assert "plotly" in page and "allan-imu0" in page and "<script src=" not in page  # JS embedded: offline
    assert "imu0" in r.stdout and "white noise density" in r.stdout


def test_inflate_multiplies_and_says_so(recording, tmp_path):
    path, _ = recording
    plain, inflated = tmp_path / "a.yaml", tmp_path / "b.yaml"
    assert run("imu-noise", path, "--out", plain).exit_code == 0
    r = run("imu-noise", path, "--out", inflated, "--inflate", 3)
    assert r.exit_code == 0 and "--inflate" in r.stdout
    a, b = yaml.safe_load(plain.read_text()), yaml.safe_load(inflated.read_text())
    for k in ("gyroscope_noise_density", "accelerometer_random_walk"):
        assert b[k] == pytest.approx(3 * a[k], rel=1e-12)
    assert "--inflate 3" in inflated.read_text()


def _opencv_yaml(text: str) -> dict:
    return yaml.safe_load("\n".join(ln for ln in text.splitlines() if not ln.startswith("%YAML")))


def test_other_formats_use_their_own_keys(recording, tmp_path):
    path, _ = recording
    k = {}
    assert run("imu-noise", path, "--out", tmp_path / "k.yaml").exit_code == 0
    k = yaml.safe_load((tmp_path / "k.yaml").read_text())
    for fmt in ("vins", "orbslam3", "openvins", "basalt"):
        out = tmp_path / f"{fmt}.out"
        r = run("imu-noise", path, "--out", out, "--format", fmt)
        assert r.exit_code == 0, r.stderr
        text = out.read_text()
        if fmt == "vins":
            d = _opencv_yaml(text)
            assert d["acc_n"] == k["accelerometer_noise_density"] and d["gyr_w"] == k["gyroscope_random_walk"]
        elif fmt == "orbslam3":
            d = _opencv_yaml(text)
            assert d["IMU.NoiseGyro"] == k["gyroscope_noise_density"] and d["IMU.AccWalk"] == \
                k["accelerometer_random_walk"]
            assert isinstance(d["IMU.Frequency"], float)  # ORB-SLAM3 reads it as a real
        elif fmt == "openvins":
            d = _opencv_yaml(text)["imu0"]
            assert d["gyroscope_random_walk"] == k["gyroscope_random_walk"] and np.allclose(d["T_i_b"], np.eye(4))
        else:
            d = json.loads(text)["value0"]
            assert max(d["gyro_noise_std"]) == pytest.approx(k["gyroscope_noise_density"], rel=1e-12)
            assert len(d["accel_bias_std"]) == 3


RIG = """\
# a rig with one IMU
rig: test
body_frame: FLU
imus:
  imu0:
    position: [0.0, 0.0, 0.0]
    axes: [F, L, U]
    update_rate: 100.0
    gyroscope_noise_density: 1.0e-1   # datasheet
    gyroscope_random_walk: 1.0e-1
    accelerometer_noise_density: 1.0e-1
    accelerometer_random_walk: 1.0e-1
cameras:
  cam0:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0}
    distortion: [0.0, 0.0, 0.0, 0.0]
    position: [0.1, 0.0, 0.0]
    axes: [-L, -U, F]
"""


def test_rig_gets_the_figures_and_keeps_the_rest(recording, tmp_path):
    from rigcal.core.rig import parse_rig

    path, _ = recording
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG)
    out = tmp_path / "rig_out.yaml"
    r = run("imu-noise", path, "--out", out, "--rig", rig)
    assert r.exit_code == 0, r.stderr
    k_out = tmp_path / "k.yaml"
    assert run("imu-noise", path, "--out", k_out).exit_code == 0
    k = yaml.safe_load(k_out.read_text())
    text = out.read_text()
    assert "# a rig with one IMU" in text and "# datasheet" in text
    new, old = parse_rig(text), parse_rig(RIG)
    imu = new.imu("imu0")
    assert imu.gyroscope_noise_density == k["gyroscope_noise_density"]
    assert imu.accelerometer_random_walk == k["accelerometer_random_walk"]
    assert new.cameras == old.cameras and imu.update_rate == 100.0


def test_gap_pools_the_stretches_between_and_says_so(tmp_path):
    t, g, a = static_imu(1300, RATE, ND, KW, seed=8)
    keep = np.ones(len(t), bool)
    keep[5000:5100] = False  # a 1 s gap 50 s in
    path = write_csv(tmp_path / "imu0.csv", t[keep], g[keep], a[keep])
    whole = write_csv(tmp_path / "whole.csv", t, g, a)
    r = run("imu-noise", path, "--out", tmp_path / "o.yaml")
    assert r.exit_code == 0, r.stderr
    assert "1 gap(s)" in r.stdout and "pools the 2 stretches" in r.stdout and "samples 5001-" in r.stdout
    assert run("imu-noise", whole, "--out", tmp_path / "w.yaml").exit_code == 0
    gap, ref = yaml.safe_load((tmp_path / "o.yaml").read_text()), yaml.safe_load((tmp_path / "w.yaml").read_text())
    # 1 s of 1300 missing and the first 50 s a stretch of their own: the same figures within their precision
    assert gap["gyroscope_noise_density"] == pytest.approx(ref["gyroscope_noise_density"], rel=0.005)
    assert gap["accelerometer_random_walk"] == pytest.approx(ref["accelerometer_random_walk"], rel=0.1)


def test_temperature_trend_is_reported(tmp_path):
    t, g, a = static_imu(1200, RATE, ND, KW, seed=9)
    temp = 30 + 5 * np.arange(len(t)) / len(t)
    r = run("imu-noise", write_csv(tmp_path / "imu0.csv", t, g, a, temp), "--out", tmp_path / "o.yaml")
    assert r.exit_code == 0, r.stderr
    assert "temperature trend changes by +5.0 deg C" in r.stdout


def test_bag_gives_the_same_figures_as_its_csv(tmp_path):
    from tests.support.recordings import write_bag

    t, g, a = static_imu(240, 50.0, [1e-3] * 6, [5e-3] * 6, seed=10)
    bag = write_bag(tmp_path / "s.bag", "ros1", {}, (t, g, a))
    csv = write_csv(tmp_path / "imu0.csv", t, g, a)
    r = run("imu-noise", bag, "--out", tmp_path / "b.yaml", "--imu", "imu0=/imu0")
    assert r.exit_code == 0, r.stderr
    assert run("imu-noise", csv, "--out", tmp_path / "c.yaml").exit_code == 0
    b, c = yaml.safe_load((tmp_path / "b.yaml").read_text()), yaml.safe_load((tmp_path / "c.yaml").read_text())
    assert b["rostopic"] == "/imu0"
    for key in ("gyroscope_noise_density", "accelerometer_random_walk"):
        assert b[key] == pytest.approx(c[key], rel=1e-6)
    out = tmp_path / "x.yaml"
    refused(run("imu-noise", bag, "--out", out), "/imu0", "--imu NAME=TOPIC")
    refused(run("imu-noise", bag, "--out", out, "--imu", "imu0=/nope"), "no topic '/nope'", "/imu0")
    assert not out.exists()


# ----------------------------------------------------------------------------- bad input


def _lines(recording) -> list[str]:
    return recording[0].read_text().splitlines()


def test_non_numeric_cell_names_file_and_row(recording, tmp_path):
    ls = _lines(recording)
    cells = ls[40].split(",")
    cells[3] = "abc"
    ls[40] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(ls) + "\n")
    out = tmp_path / "o.yaml"
    refused(run("imu-noise", bad, "--out", out, "--report", tmp_path / "r.html"), str(bad), "row 41", "column 4",
            "'abc'")
    assert not out.exists() and not (tmp_path / "r.html").exists()


@pytest.mark.parametrize("what, needle", [("repeat", "repeats"), ("back", "is before")])
def test_duplicated_or_backward_timestamp(recording, tmp_path, what, needle):
    ls = _lines(recording)
    prev = ls[99].split(",")[0]
    cells = ls[100].split(",")
    cells[0] = prev if what == "repeat" else str(int(prev) - 1)
    ls[100] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(ls) + "\n")
    out = tmp_path / "o.yaml"
    refused(run("imu-noise", bad, "--out", out), str(bad), "row 101", needle)
    assert not out.exists()


def test_moving_recording_is_refused_with_the_figure(tmp_path):
    t, g, a = static_imu(1200, RATE, ND, KW, seed=11)
    a[60000:60300, 0] += 1.5  # picked up for 3 s
    out = tmp_path / "o.yaml"
    line = refused(run("imu-noise", write_csv(tmp_path / "imu0.csv", t, g, a), "--out", out),
                   "not a static recording", "m/s^2")
    assert "1.5" in line and "600 s" in line
    assert not out.exists()


def test_too_short_says_how_long_is_needed(tmp_path):
    t, g, a = static_imu(60, RATE, ND, np.array(KW) * 1e-3, seed=12)
    out = tmp_path / "o.yaml"
    refused(run("imu-noise", write_csv(tmp_path / "imu0.csv", t, g, a), "--out", out), "too short for the",
            "random walk", "record at least")
    assert not out.exists()


def test_option_errors(recording, tmp_path):
    path, _ = recording
    out = tmp_path / "o.yaml"
    refused(run("imu-noise", path, "--out", out, "--format", "rig"), "--format rig", "--rig")
    refused(run("imu-noise", path, "--out", out, "--inflate", 0.5), "--inflate", ">= 1")
    refused(run("imu-noise", tmp_path / "nope.csv", "--out", out), "does not exist")
    (tmp_path / "x.txt").write_text("hello")
    refused(run("imu-noise", tmp_path / "x.txt", "--out", out), "x.txt", "expected an IMU .csv")
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG)
    refused(run("imu-noise", path, "--out", out, "--rig", rig, "--imu", "other=imu0.csv"), "no IMU 'other'",
            "imu0")
    assert not out.exists()


def test_dataset_with_two_imus_needs_a_choice_for_kalibr(recording, tmp_path):
    path, _ = recording
    ds = tmp_path / "ds"
    (ds / "imu").mkdir(parents=True)
    for n in ("imu0", "imu1"):
        (ds / "imu" / f"{n}.csv").write_text(path.read_text())
    out = tmp_path / "o.yaml"
    refused(run("imu-noise", ds, "--out", out), "imu0, imu1", "--imu NAME=")
    assert not out.exists()
    r = run("imu-noise", ds, "--out", out, "--imu", "imu1=imu1.csv")
    assert r.exit_code == 0, r.stderr
    assert yaml.safe_load(out.read_text())["rostopic"] == "/imu1"


def test_euroc_folder(recording, tmp_path):
    path, _ = recording
    imu_dir = tmp_path / "MH" / "mav0" / "imu0"
    imu_dir.mkdir(parents=True)
    (imu_dir / "data.csv").write_text(path.read_text())
    (imu_dir / "sensor.yaml").write_text("%YAML:1.0\nsensor_type: imu\nrate_hz: 100\n")
    out = tmp_path / "o.yaml"
    r = run("imu-noise", tmp_path / "MH", "--out", out)
    assert r.exit_code == 0, r.stderr
    direct = tmp_path / "d.yaml"
    assert run("imu-noise", path, "--out", direct).exit_code == 0
    a, b = yaml.safe_load(out.read_text()), yaml.safe_load(direct.read_text())
    assert a["gyroscope_noise_density"] == b["gyroscope_noise_density"] and a["rostopic"] == "/imu0"
    refused(run("imu-noise", tmp_path / "MH", "--out", out, "--imu", "imu0=imu9"), "no such IMU", "imu0")


def test_rig_in_flow_style_is_rewritten_whole(recording, tmp_path):
    from rigcal.core.rig import parse_rig

    path, _ = recording
    doc = yaml.safe_load(RIG)
    rig = tmp_path / "flow.yaml"
    rig.write_text(yaml.safe_dump(doc, default_flow_style=True))
    out = tmp_path / "rig_out.yaml"
    r = run("imu-noise", path, "--out", out, "--format", "rig", "--rig", rig, "--inflate", 2)
    assert r.exit_code == 0, r.stderr
    k = tmp_path / "k.yaml"
    assert run("imu-noise", path, "--out", k).exit_code == 0
    want = yaml.safe_load(k.read_text())["gyroscope_random_walk"] * 2
    new = parse_rig(out.read_text())
    assert new.imu("imu0").gyroscope_random_walk == pytest.approx(want, rel=1e-12)
    assert "--inflate 2" in out.read_text() and new.cameras == parse_rig(RIG).cameras


def test_a_noisy_still_imu_is_not_taken_for_a_moving_one(tmp_path):
    # a consumer accelerometer: 0.04 m/s^2/sqrt(Hz) moves one-second means by ~0.06 m/s^2 (1 sigma)
    t, g, a = static_imu(1200, RATE, [1e-3, 1e-3, 1e-3, 0.04, 0.04, 0.04], [1e-3, 1e-3, 1e-3, 4e-2, 4e-2, 4e-2],
                         seed=13)
    r = run("imu-noise", write_csv(tmp_path / "imu0.csv", t, g, a), "--out", tmp_path / "o.yaml")
    assert r.exit_code == 0, r.stderr


def test_outputs_never_overwrite_the_recording(recording, tmp_path):
    path, _ = recording
    before = path.read_bytes()
    refused(run("imu-noise", path, "--out", path), "is the recording being read")
    refused(run("imu-noise", path, "--out", tmp_path / "o.yaml", "--report", tmp_path / "o.yaml"), "same file")
    assert path.read_bytes() == before and not (tmp_path / "o.yaml").exists()
