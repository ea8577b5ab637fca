"""`rigcal ingest --mag NAME=TOPIC`: a bag's sensor_msgs/MagneticField topic (tesla) becomes
mag/NAME.csv (microtesla, the magnetometer format), beside imu/ from the Imu topic, in bags
written by rosbags' own ROS 1 and ROS 2 writers; the dataset calibrates as the simulated one
does; a topic that is not in the bag, or not a MagneticField, is one line (listing the topics
that are), exit 2, nothing written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core.rig import load_rig
from rigcal.data.imu_csv import read_imu_csv
from rigcal.data.mag_csv import read_mag_csv

from tests.support import recordings as R
from tests.support.mag_data import mag_dataset

runner = CliRunner()


@pytest.fixture(scope="module")
def dance(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bagmag") / "ds"
    mag_dataset(d, seed=1, duration=20.0)
    return d


def _bag(dance: Path, path: Path, kind: str) -> Path:
    imu = read_imu_csv(dance / "imu" / "imu0.csv")
    mag = read_mag_csv(dance / "mag" / "mag0.csv")
    return R.write_bag(path, kind, {}, (imu.t_ns, imu.gyro, imu.accel), mag=(mag.t_ns, mag.m_uT * 1e-6))


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_bag_magnetic_field_topic_becomes_mag_csv(dance, tmp_path, kind):
    bag = _bag(dance, tmp_path / ("rec.bag" if kind == "ros1" else "rec"), kind)
    ds = tmp_path / "ds"
    r = runner.invoke(app, ["ingest", str(bag), "--out", str(ds), "--imu", "imu0=/imu0", "--mag", "mag0=/mag0",
                            "--rig", str(dance / "rig.yaml")])
    assert r.exit_code == 0, r.stderr
    want, got = read_mag_csv(dance / "mag" / "mag0.csv"), read_mag_csv(ds / "mag" / "mag0.csv")
    n = len(want.t_ns)
    assert f"mag/mag0.csv: {n} of {n} samples from {bag}:/mag0, 20.0 s, ~100.0 Hz" in " ".join(r.stdout.split())
    assert sorted(p.name for p in ds.iterdir()) == ["imu", "mag", "rig.yaml"]
    np.testing.assert_array_equal(got.t_ns, want.t_ns)
    np.testing.assert_allclose(got.m_uT, want.m_uT, rtol=1e-12, atol=0)  # tesla -> microtesla
    wi, gi = read_imu_csv(dance / "imu" / "imu0.csv"), read_imu_csv(ds / "imu" / "imu0.csv")
    np.testing.assert_array_equal(gi.t_ns, wi.t_ns)
    np.testing.assert_array_equal(gi.gyro, wi.gyro)
    if kind == "ros1":  # the ingested dataset calibrates as the simulated one does
        outs = []
        for src in (dance, ds):
            out = tmp_path / f"{src.name}-cal.yaml"
            r = runner.invoke(app, ["calibrate", str(src), "--out", str(out)])
            assert r.exit_code == 0, r.stderr
            outs.append(load_rig(out).magnetometers[0].calibration)
        np.testing.assert_allclose(outs[1]["hard_iron_uT"], outs[0]["hard_iron_uT"], rtol=0, atol=1e-6)
        np.testing.assert_allclose(outs[1]["soft_iron"], outs[0]["soft_iron"], rtol=0, atol=1e-8)


def test_bag_without_the_requested_magnetometer_topic(dance, tmp_path):
    bag = _bag(dance, tmp_path / "rec.bag", "ros1")
    for topic, want in (("/compass", "no topic '/compass' for mag0 (image, IMU and magnetometer topics: /imu0 (Imu), "
                                     "/mag0 (MagneticField))"),
                        ("/imu0", "topic /imu0 is sensor_msgs/msg/Imu, expected sensor_msgs/msg/MagneticField")):
        ds = tmp_path / "ds"
        r = runner.invoke(app, ["ingest", str(bag), "--out", str(ds), "--imu", "imu0=/imu0", "--mag", f"mag0={topic}",
                                "--rig", str(dance / "rig.yaml")])
        assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert want in r.stderr and not ds.exists()
    # no --camera, --imu or --mag: the listing names the magnetometer topic too
    r = runner.invoke(app, ["ingest", str(bag), "--out", str(tmp_path / "ds")])
    assert r.exit_code == 2 and "--mag NAME=TOPIC" in r.stderr and "MagneticField" in r.stderr
    assert not (tmp_path / "ds").exists()


def test_mag_option_needs_a_bag_and_a_declared_magnetometer(dance, tmp_path):
    bag = _bag(dance, tmp_path / "rec.bag", "ros1")
    r = runner.invoke(app, ["ingest", str(bag), "--out", str(tmp_path / "ds"), "--imu", "imu0=/imu0", "--mag",
                            "compass=/mag0", "--rig", str(dance / "rig.yaml")])
    assert r.exit_code == 2 and "magnetometers: declares mag0 but the recording gives compass" in r.stderr, r.stderr
    assert not (tmp_path / "ds").exists()
    r = runner.invoke(app, ["ingest", str(dance), "--out", str(tmp_path / "ds"), "--mag", "mag0=/mag0"])
    assert r.exit_code == 2 and "--mag: only for ROS bags" in r.stderr, r.stderr
