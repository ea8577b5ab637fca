"""A minimal PX4 ULog writer from the published format (docs.px4.io, "ULog File Format"): the
16-byte header (magic, version 1, start time), a flag-bits message, format ('F') and
parameter ('P') definitions, then per topic an add-logged ('A') message and its data ('D')
messages; each message is (uint16 payload size, uint8 type, payload). pyulog reads it as it
reads PX4's."""

from __future__ import annotations

import struct
from pathlib import Path

MAGIC = b"ULog\x01\x12\x35"
FORMATS = {
    "sensor_combined": "uint64_t timestamp;float[3] gyro_rad;uint32_t gyro_integral_dt;"
                       "int32_t accelerometer_timestamp_relative;float[3] accelerometer_m_s2;",
    "sensor_mag": "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;"
                  "float temperature;",
}
PACK = {"sensor_combined": "<Q3fIi3f", "sensor_mag": "<QQI4f"}


def _msg(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def write_ulog(path: Path, topics: dict[str, list[tuple]], params: dict[str, float] | None = None) -> bytes:
    """topics: name -> rows of values in FORMATS' field order (timestamps in microseconds)."""
    out = bytearray(MAGIC + bytes([1]) + struct.pack("<Q", 0))
    out += _msg("B", bytes(40))  # compat and incompat flags all 0, no appended data
    for name in topics:
        out += _msg("F", f"{name}:{FORMATS[name]}".encode())
    for k, v in (params or {}).items():
        key = f"float {k}".encode()
        out += _msg("P", bytes([len(key)]) + key + struct.pack("<f", v))
    for msg_id, name in enumerate(topics):
        out += _msg("A", struct.pack("<BH", 0, msg_id) + name.encode())
    rows = sorted((r[0], msg_id, r) for msg_id, name in enumerate(topics) for r in topics[name])
    names = list(topics)
    for _, msg_id, r in rows:
        out += _msg("D", struct.pack("<H", msg_id) + struct.pack(PACK[names[msg_id]], *r))
    Path(path).write_bytes(bytes(out))
    return bytes(out)
