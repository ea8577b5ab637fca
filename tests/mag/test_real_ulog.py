"""`rigcal ingest` on a real PX4 ULog (tests/mag/data/px4_cubeorange_small.md: a Cube Orange at
rest, pyulog's own test log): imu/ from sensor_combined and mag/ from sensor_mag instance 0,
in the magnetometer format's units; `rigcal calibrate` refuses its six readings with one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.data.imu_csv import read_imu_csv
from rigcal.data.mag_csv import MAG_HEADER

from tests.support.mag_data import MAG_RIG

LOG = Path(__file__).parent / "data" / "px4_cubeorange_small.ulg"
runner = CliRunner()


def test_real_px4_log_is_ingested_and_its_few_readings_refused(tmp_path):
    from pyulog import ULog

    ds = tmp_path / "ds"
    r = runner.invoke(app, ["ingest", str(LOG), "--out", str(ds), "--rig", str(MAG_RIG)])
    assert r.exit_code == 0, r.stderr
    assert "1298 IMU and 6 magnetometer samples over 6.5 s" in " ".join(r.stdout.split())
    ulog = ULog(str(LOG), ["sensor_mag"])
    mag = next(d.data for d in ulog.data_list if d.name == "sensor_mag" and d.multi_id == 0)
    # six rows, below read_mag_csv's minimum: read as plain numbers
    lines = (ds / "mag" / "mag0.csv").read_text().splitlines()
    assert lines[0] == MAG_HEADER and len(lines) == 7
    t_ns = np.array([int(row.split(",")[0]) for row in lines[1:]], np.int64)
    m_uT = np.array([[float(x) for x in row.split(",")[1:]] for row in lines[1:]])
    np.testing.assert_array_equal(t_ns, mag["timestamp_sample"].astype(np.int64) * 1000)  # microseconds -> ns
    np.testing.assert_allclose(m_uT, np.column_stack([mag[a] for a in "xyz"]) * 100.0, rtol=1e-7)  # gauss -> uT
    assert 40.0 < np.linalg.norm(m_uT, axis=1).mean() < 70.0  # an Earth field plus the frame's hard iron
    imu = read_imu_csv(ds / "imu" / "imu0.csv")
    assert len(imu.t_ns) == 1298 and abs(np.linalg.norm(imu.accel, axis=1).mean() - 9.7) < 0.2  # at rest
    r = runner.invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml")])
    assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "mag0.csv: expected at least 10 samples" in r.stderr and "got 6" in r.stderr
    assert not (tmp_path / "cal.yaml").exists()
