"""`rigcal ingest LOG.bin` (ArduPilot DataFlash, written here by tests/support/dataflash.py
from the published format): the logged, corrected compass field is undone to the chip's raw
readings (custom rotation, offsets, soft iron, scale and motor offsets as in the log's
parameters), the dataset calibrates to the simulation's truth, and a truncated log or one
without MAG messages is one line, exit 2, nothing written."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core import geometry as geo
from rigcal.core.rig import load_rig
from rigcal.data.imu_csv import read_imu_csv
from rigcal.data.mag_csv import read_mag_csv
from rigcal.mag.autopilot import R_from_euler_deg

from tests.support.dataflash import write_log
from tests.support.mag_data import MAG_RIG, mag_dataset

FRD = np.diag([1.0, -1.0, -1.0])
PARAMS = {"COMPASS_ORIENT": 101.0, "CUST_ROT_ENABLE": 1.0, "CUST_ROT1_ROLL": 3.0, "CUST_ROT1_PITCH": -2.0,
          "CUST_ROT1_YAW": 91.0, "COMPASS_EXTERNAL": 1.0, "COMPASS_DIA_X": 1.05, "COMPASS_DIA_Y": 0.97,
          "COMPASS_DIA_Z": 1.01, "COMPASS_ODI_X": 0.02, "COMPASS_ODI_Y": -0.01, "COMPASS_ODI_Z": 0.015,
          "COMPASS_SCALE": 1.02}
OFS = np.array([-120.0, 85.0, 40.0])  # mG
MOTOR = np.array([3.0, -2.0, 1.0])  # mG


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    d = tmp_path_factory.mktemp("fl")
    sim = mag_dataset(d / "sim", seed=1, duration=20.0)
    imu = read_imu_csv(sim.out_dir / "imu" / "imu0.csv")
    mag = read_mag_csv(sim.out_dir / "mag" / "mag0.csv")
    t0 = int(imu.t_ns[0])
    imu_rows = [((t - t0) // 1000, *(FRD @ g), *(FRD @ a)) for t, g, a in zip(imu.t_ns, imu.gyro, imu.accel)]
    # ArduPilot's correct_field on the chip's reading q (mG): M (scale (R q + ofs)) + motor
    R = R_from_euler_deg(PARAMS["CUST_ROT1_ROLL"], PARAMS["CUST_ROT1_PITCH"], PARAMS["CUST_ROT1_YAW"])
    M = np.diag([PARAMS["COMPASS_DIA_X"], PARAMS["COMPASS_DIA_Y"], PARAMS["COMPASS_DIA_Z"]])
    M[0, 1] = M[1, 0] = PARAMS["COMPASS_ODI_X"]
    M[0, 2] = M[2, 0] = PARAMS["COMPASS_ODI_Y"]
    M[1, 2] = M[2, 1] = PARAMS["COMPASS_ODI_Z"]
    q = mag.m_uT * 10.0
    field = np.rint(((q @ R.T + OFS) * PARAMS["COMPASS_SCALE"]) @ M.T + MOTOR)
    mag_rows = [((t - t0) // 1000, *f, *OFS, *MOTOR) for t, f in zip(mag.t_ns, field)]
    path = d / "flight.bin"
    write_log(path, imu_rows, mag_rows, PARAMS)
    rig = d / "rig.yaml"
    rig.write_text(MAG_RIG.read_text().replace("    axes: [F, L, U]\n    update_rate: 200.0",
                                                "    axes: [F, -L, -U]\n    update_rate: 200.0"))
    return path, rig, sim, mag


def _ingested(path, rig, tmp_path):
    """`rigcal ingest` of a flight log into tmp_path/ds; the dataset's folder."""
    out = tmp_path / "ds"
    r = CliRunner().invoke(app, ["ingest", str(path), "--out", str(out), "--rig", str(rig)])
    assert r.exit_code == 0, r.stderr
    return out


def _calibrated_mag(dataset, tmp_path):
    """`rigcal calibrate` of an ingested dataset; its first magnetometer."""
    cal_out = tmp_path / "cal.yaml"
    r = CliRunner().invoke(app, ["calibrate", str(dataset), "--out", str(cal_out)])
    assert r.exit_code == 0, r.stderr
    return load_rig(cal_out).magnetometers[0]


def test_the_logged_calibration_is_undone_to_the_raw_readings(log, tmp_path):
    path, rig, sim, mag = log
    out = _ingested(path, rig, tmp_path)
    got = read_mag_csv(out / "mag" / "mag0.csv")
    assert len(got.t_ns) == len(mag.t_ns)
    assert np.abs(got.m_uT - mag.m_uT).max() < 0.1  # the log's 1 mG (0.1 uT) rounding, through M^-1
    m = _calibrated_mag(out, tmp_path)
    assert np.abs(np.array(m.calibration["hard_iron_uT"]) - sim.mags["mag0"].hard_iron).max() < 0.2
    assert geo.rotation_angle_deg(m.T_body_mag[:3, :3] @ sim.truth.magnetometers[0].T_body_mag[:3, :3].T) < 0.2


def test_an_older_log_format_reads_the_same(log, tmp_path):
    """Older ArduCopter DataFlash formats (3.3-dev's: TimeMS, no instance field, MOfsX..) give the same
    dataset as today's (the simulation's stamps are whole milliseconds); a MAG message without
    the offsets is one line naming the fields it has."""
    path, rig, _, _ = log
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    imu_rows, mag_rows, params = [], [], {}
    while (m := reader.recv_msg()) is not None:
        if m.get_type() == "IMU":
            imu_rows.append((m.TimeUS, m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY, m.AccZ))
        elif m.get_type() == "MAG":
            mag_rows.append((m.TimeUS, m.MagX, m.MagY, m.MagZ, m.OfsX, m.OfsY, m.OfsZ, m.MOX, m.MOY, m.MOZ))
        elif m.get_type() == "PARM":
            params[m.Name] = m.Value
    assert all(r[0] % 1000 == 0 for r in imu_rows + mag_rows)
    old = tmp_path / "old.bin"
    write_log(old, imu_rows, mag_rows, params, legacy=True)
    outs = {}
    for p in (path, old):
        outs[p] = tmp_path / f"ds-{p.stem}"
        r = CliRunner().invoke(app, ["ingest", str(p), "--out", str(outs[p]), "--rig", str(rig)])
        assert r.exit_code == 0, r.stderr
    for f in ("imu/imu0.csv", "mag/mag0.csv"):
        assert (outs[old] / f).read_text() == (outs[path] / f).read_text(), f
    from tests.support.dataflash import LEGACY

    bad = tmp_path / "bad.bin"
    fmt = {**LEGACY, "MAG": (130, "Ihhh", "TimeMS,MagX,MagY,MagZ")}
    write_log(bad, imu_rows[:20], [r[:4] for r in mag_rows[:20]], {}, legacy=True, formats=fmt)
    r = CliRunner().invoke(app, ["ingest", str(bad), "--out", str(tmp_path / "x"), "--rig", str(rig)])
    assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "MAG messages have no OfsX field (they have TimeMS, MagX, MagY, MagZ)" in r.stderr
    assert not (tmp_path / "x").exists()


def test_truncated_log_and_log_without_mag_are_refused(log, tmp_path):
    path, rig, _, _ = log
    data = path.read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[:-7])
    nomag = tmp_path / "nomag.bin"
    write_log(nomag, [(i * 5000, 0, 0, 0, 0, 0, 9.8) for i in range(10)], [], {"COMPASS_ORIENT": 0.0})
    for bad, expected in ((cut, "truncated"), (nomag, "no MAG messages (instance 0); the log has: IMU, PARM")):
        out = tmp_path / f"out-{bad.stem}"
        r = CliRunner().invoke(app, ["ingest", str(bad), "--out", str(out), "--rig", str(rig)])
        assert r.exit_code == 2, (bad, r.stdout, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0] and str(bad) in lines[0], r.stderr
        assert not out.exists()


@pytest.fixture(scope="module")
def ulog(tmp_path_factory, log):
    from tests.support.ulog import write_ulog

    _, rig, sim, mag = log
    imu = read_imu_csv(sim.out_dir / "imu" / "imu0.csv")
    t0 = int(imu.t_ns[0])
    combined = [((t - t0) // 1000, *(FRD @ g), 5000, 0, *(FRD @ a)) for t, g, a in zip(imu.t_ns, imu.gyro, imu.accel)]
    mags = [((t - t0) // 1000 + 300, (t - t0) // 1000, 7, *(m / 100.0), 25.0) for t, m in zip(mag.t_ns, mag.m_uT)]
    path = tmp_path_factory.mktemp("ulog") / "flight.ulg"
    write_ulog(path, {"sensor_combined": combined, "sensor_mag": mags}, {"CAL_MAG0_ROT": 0.0})
    return path, rig, sim, mag


def test_px4_ulog_is_read_as_logged_and_calibrates(ulog, tmp_path):
    path, rig, sim, mag = ulog
    out = _ingested(path, rig, tmp_path)
    got = read_mag_csv(out / "mag" / "mag0.csv")
    np.testing.assert_array_equal(got.t_ns, (mag.t_ns - mag.t_ns[0]) // 1000 * 1000)  # timestamp_sample, us
    assert np.abs(got.m_uT - mag.m_uT).max() < 1e-4  # float32 gauss
    m = _calibrated_mag(out, tmp_path)
    assert np.abs(np.array(m.calibration["hard_iron_uT"]) - sim.mags["mag0"].hard_iron).max() < 0.2


def test_truncated_ulog_and_ulog_without_sensor_mag_are_refused(ulog, tmp_path):
    from tests.support.ulog import write_ulog

    path, rig, _, _ = ulog
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(path.read_bytes()[:-5])
    nomag = tmp_path / "nomag.ulg"
    write_ulog(nomag, {"sensor_combined": [(i * 5000, 0, 0, 0, 5000, 0, 0, 0, -9.8) for i in range(10)]})
    for bad, expected in ((cut, "truncated"), (nomag, "no sensor_mag messages (instance 0); the log has: "
                                                      "sensor_combined")):
        out = tmp_path / f"out-{bad.stem}"
        r = CliRunner().invoke(app, ["ingest", str(bad), "--out", str(out), "--rig", str(rig)])
        assert r.exit_code == 2, (bad, r.stdout, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0] and str(bad) in lines[0], r.stderr
        assert not out.exists()
