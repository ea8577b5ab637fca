"""`rigcal ingest LOG.bin | LOG.ulg`: an ArduPilot DataFlash log (pymavlink's reader) or a PX4
ULog (pyulog's) -> a dataset of imu/ and mag/ for the magnetometer calibration.

PX4 logs `sensor_mag` uncalibrated (gauss, the sensor's axes; its calibration is applied
downstream, in vehicle_magnetometer), so the readings are taken as they are; the IMU is
`sensor_combined` (gyro_rad, accelerometer_m_s2: calibrated, forward-right-down), stamped
with its `timestamp` (microseconds).

ArduPilot logs the IMU (message IMU: TimeUS, GyrX..Z rad/s, AccX..Z m/s^2) in the vehicle's
forward-right-down axes, and the magnetometer (MAG: MagX..Z, OfsX..Z, MOX..Z, milligauss) with
its calibration applied (AP_Compass_Backend: rotate_field, then correct_field):

    field = M @ (scale * (R @ q + ofs)) + motor        q: the chip's raw reading
    R = R_AHRS_ORIENTATION (internal compass only) @ R_COMPASS_ORIENT

with M from COMPASS_DIA_* / COMPASS_ODI_* (identity when unset), scale COMPASS_SCALE (1 when
unset), the rotations from the log's parameters (PARM). The raw reading is recovered as
q = R.T @ (inv(M) @ (field - motor) / scale - ofs) and written in microtesla, in the chip's
axes. Instance 0 of each message becomes the rig's first IMU and first magnetometer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigcal.core.io import atomic_dir
from rigcal.core.rig import load_rig
from rigcal.data.imu_csv import imu_csv
from rigcal.data.mag_csv import mag_csv
from rigcal.errors import InputError
from rigcal.mag.autopilot import CUSTOM_ENUMS, ROTATION_ENUM, R_from_euler_deg

UT_PER_MILLIGAUSS = 0.1
UT_PER_GAUSS = 100.0
LOG_SUFFIXES = (".bin", ".ulg")
ULOG_MAGIC = b"ULog\x01\x12\x35"


@dataclass(frozen=True)
class DataflashLog:
    """IMU and MAG instance 0 and the parameters of a DataFlash log (times in microseconds)."""

    imu_t_us: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    mag_t_us: np.ndarray
    field_mG: np.ndarray
    ofs_mG: np.ndarray
    motor_mG: np.ndarray
    params: dict[str, float]


def is_flight_log(path: Path) -> bool:
    return Path(path).suffix.lower() in LOG_SUFFIXES and Path(path).is_file()


def read_dataflash(path: str | Path) -> DataflashLog:
    """IMU, MAG and PARM of a DataFlash log; InputError (one line) for a truncated log or one
    without those messages (naming what it has)."""
    from pymavlink import DFReader

    path = Path(path)
    try:
        reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    except Exception as e:  # pymavlink raises bare errors on files that are not logs
        raise InputError(f"{path}: not a readable DataFlash log ({e.__class__.__name__}: {e})") from None
    imu, mag, params, seen = [], [], {}, set()
    rows = {"IMU": imu, "MAG": mag}
    fields: dict[str, list] = {}
    while True:
        msg = reader.recv_msg()
        if msg is None:
            break
        kind = msg.get_type()
        seen.add(kind)
        if kind in rows and getattr(msg, "I", 0) == 0:
            if kind not in fields:
                fields[kind] = _fields(msg, kind, path)
            rows[kind].append(tuple(getattr(msg, name) * k if name else 0.0 for name, k in fields[kind]))
        elif kind == "PARM":
            params[str(msg.Name)] = float(msg.Value)
    if reader.offset < reader.data_len:
        raise InputError(f"{path}: truncated: the last message stops at byte {reader.data_len} of one that needs "
                         f"more (read {len(imu)} IMU and {len(mag)} MAG messages before it)")
    for name, rows in (("IMU", imu), ("MAG", mag)):
        if len(rows) < 2:
            have = ", ".join(sorted(seen - {"FMT"})) or "none"
            raise InputError(f"{path}: no {name} messages (instance 0); the log has: {have}")
    a, b = np.array(imu, float), np.array(mag, float)
    return DataflashLog(a[:, 0].astype(np.int64), a[:, 1:4], a[:, 4:7], b[:, 0].astype(np.int64), b[:, 1:4],
                        b[:, 4:7], b[:, 7:10], params)


# the columns read, in order, each with the names ArduPilot's versions log it under (the time
# in microseconds: TimeUS, or TimeMS times 1000 in older logs such as ArduCopter 3.3-dev's)
# and None where a log may lack it (the motor compensation: MOX.., or MOfsX.. as ArduCopter
# 3.3 and 3.4 log it; 0 without either)
_COLUMNS = {
    "IMU": [("TimeUS", "TimeMS"), ("GyrX",), ("GyrY",), ("GyrZ",), ("AccX",), ("AccY",), ("AccZ",)],
    "MAG": [("TimeUS", "TimeMS"), ("MagX",), ("MagY",), ("MagZ",), ("OfsX",), ("OfsY",), ("OfsZ",),
            ("MOX", "MOfsX", None), ("MOY", "MOfsY", None), ("MOZ", "MOfsZ", None)],
}


def _fields(msg, kind: str, path: Path) -> list[tuple[str | None, float]]:
    """(field name or None for 0, scale) per column of _COLUMNS[kind], from a message's own
    format; InputError naming the fields the log has where a needed one is missing."""
    have = list(msg.get_fieldnames())
    out = []
    for names in _COLUMNS[kind]:
        name = next((n for n in names if n is None or n in have), "")
        if name == "":
            raise InputError(f"{path}: {kind} messages have no {' or '.join(n for n in names if n)} field (they have "
                             f"{', '.join(have)})")
        out.append((name, 1000.0 if name == "TimeMS" else 1.0))
    return out


def _enum_rotation(value: float, params: dict[str, float], key: str, path: Path) -> np.ndarray:
    v = int(round(value))
    if 0 <= v < len(ROTATION_ENUM):
        return R_from_euler_deg(*ROTATION_ENUM[v])
    if v in CUSTOM_ENUMS:
        k = v - CUSTOM_ENUMS[0] + 1
        return R_from_euler_deg(*(params.get(f"CUST_ROT{k}_{a}", 0.0) for a in ("ROLL", "PITCH", "YAW")))
    raise InputError(f"{path}: {key} = {v}: a rotation rigcal does not know (0-37, 101, 102)")


def raw_readings_uT(log: DataflashLog, path: Path) -> np.ndarray:
    """The chip's raw readings (N, 3) uT: the logged field with ArduPilot's correction undone."""
    p = log.params
    R = _enum_rotation(p.get("COMPASS_ORIENT", 0.0), p, "COMPASS_ORIENT", path)
    if p.get("COMPASS_EXTERNAL", 0.0) == 0.0:
        R = _enum_rotation(p.get("AHRS_ORIENTATION", 0.0), p, "AHRS_ORIENTATION", path) @ R
    dia = np.array([p.get(f"COMPASS_DIA_{a}", 0.0) for a in "XYZ"])
    odi = np.array([p.get(f"COMPASS_ODI_{a}", 0.0) for a in "XYZ"])
    if not dia.any():
        dia, odi = np.ones(3), np.zeros(3)
    M = np.diag(dia)
    M[0, 1] = M[1, 0] = odi[0]
    M[0, 2] = M[2, 0] = odi[1]
    M[1, 2] = M[2, 1] = odi[2]
    scale = p.get("COMPASS_SCALE", 0.0) or 1.0
    rotated = (log.field_mG - log.motor_mG) @ np.linalg.inv(M).T / scale - log.ofs_mG
    return rotated @ R * UT_PER_MILLIGAUSS  # R.T @ v per row


@dataclass(frozen=True)
class Samples:
    """What a log gives the dataset: IMU and magnetometer stamps (us), gyro, accel, raw m (uT)."""

    imu_t_us: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    mag_t_us: np.ndarray
    m_uT: np.ndarray
    summary: str


def check_ulog_framing(path: Path) -> None:
    """InputError unless `path` is a ULog whose last message is whole (pyulog stops quietly at
    a cut message): the 16-byte header, then messages of (uint16 size, uint8 type, payload)."""
    data = path.read_bytes()
    if data[:7] != ULOG_MAGIC:
        raise InputError(f"{path}: not a ULog file (no ULog header)")
    pos = 16
    while pos + 3 <= len(data):
        size = int.from_bytes(data[pos:pos + 2], "little")
        if pos + 3 + size > len(data):
            break
        pos += 3 + size
    if pos != len(data):
        raise InputError(f"{path}: truncated: the message at byte {pos} needs more than the {len(data) - pos} "
                         f"bytes left")


def read_ulog(path: Path) -> Samples:
    """sensor_combined and sensor_mag (instance 0) of a PX4 ULog; InputError naming the topics
    the log has when one is missing."""
    from pyulog import ULog

    check_ulog_framing(path)
    try:
        ulog = ULog(str(path), ["sensor_combined", "sensor_mag"])
    except Exception as e:  # pyulog raises its own and plain errors on malformed files
        raise InputError(f"{path}: not a readable ULog ({e.__class__.__name__}: {e})") from None
    got = {d.name: d for d in ulog.data_list if d.multi_id == 0}
    for topic in ("sensor_combined", "sensor_mag"):
        if topic not in got or len(got[topic].data["timestamp"]) < 2:
            have = ", ".join(sorted({d.name for d in ULog(str(path)).data_list})) or "none"
            raise InputError(f"{path}: no {topic} messages (instance 0); the log has: {have}")
    imu, mag = got["sensor_combined"].data, got["sensor_mag"].data
    vec = lambda d, k: np.column_stack([d[f"{k}[{i}]"] for i in range(3)]).astype(float)  # noqa: E731
    t_mag = mag["timestamp_sample"] if "timestamp_sample" in mag else mag["timestamp"]
    m = np.column_stack([mag[a] for a in "xyz"]).astype(float) * UT_PER_GAUSS
    return Samples(imu["timestamp"].astype(np.int64), vec(imu, "gyro_rad"), vec(imu, "accelerometer_m_s2"),
                   np.asarray(t_mag, np.int64), m, "a PX4 ULog (sensor_mag read as logged: uncalibrated)")


def _dataflash_samples(path: Path) -> Samples:
    log = read_dataflash(path)
    return Samples(log.imu_t_us, log.gyro, log.accel, log.mag_t_us, raw_readings_uT(log, path),
                   f"an ArduPilot DataFlash log (its compass calibration, COMPASS_ORIENT "
                   f"{int(log.params.get('COMPASS_ORIENT', 0))}, offsets and soft iron, undone)")


def run(source: str | Path, out_dir: str | Path, rig_path: str | Path | None, force: bool = False) -> str:
    """Write DATASET (rig.yaml from --rig, imu/<first IMU>.csv, mag/<first magnetometer>.csv)."""
    source = Path(source)
    if rig_path is None:
        raise InputError("--rig: a flight log has no cameras or mounts to build a rig from; give a rig YAML "
                         "with an IMU (axes [F, -L, -U]: ArduPilot logs forward-right-down) and a magnetometer")
    rig = load_rig(rig_path)
    if not rig.imus or not rig.magnetometers:
        raise InputError(f"{rig_path}: a flight log fills the rig's first IMU and first magnetometer; declare both")
    log = read_ulog(source) if source.suffix.lower() == ".ulg" else _dataflash_samples(source)
    imu, mag = rig.imus[0].name, rig.magnetometers[0].name
    with atomic_dir(Path(out_dir), force=force) as tmp:
        (tmp / "rig.yaml").write_text(Path(rig_path).read_text(encoding="utf-8"), encoding="utf-8")
        (tmp / "imu").mkdir()
        (tmp / "mag").mkdir()
        (tmp / "imu" / f"{imu}.csv").write_text(imu_csv(log.imu_t_us * 1000, log.gyro, log.accel), encoding="utf-8")
        (tmp / "mag" / f"{mag}.csv").write_text(mag_csv(log.mag_t_us * 1000, log.m_uT), encoding="utf-8")
    span = (log.imu_t_us[-1] - log.imu_t_us[0]) * 1e-6
    return (f"wrote {out_dir} from {log.summary}: {len(log.imu_t_us)} IMU and {len(log.mag_t_us)} magnetometer "
            f"samples over {span:.1f} s")
