"""A minimal ArduPilot DataFlash (.bin) writer from the published format (each message:
0xA3 0x95, a type byte, the packed fields; FMT messages (type 128) define the others), for
logs that pymavlink's reader reads as it reads ArduPilot's."""

from __future__ import annotations

import struct
from pathlib import Path

HEAD = b"\xa3\x95"
STRUCT = {"Q": "Q", "B": "B", "f": "f", "h": "h", "N": "16s", "Z": "64s", "n": "4s", "I": "I"}
FORMATS = {  # name: (type, format, columns)
    "IMU": (129, "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "MAG": (130, "QBhhhhhhhhh", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ"),
    "PARM": (131, "QNf", "TimeUS,Name,Value"),
}
LEGACY = {  # older ArduCopter's (3.3-dev): milliseconds, no instance field, MOfsX.. for the motor offsets
    "IMU": (129, "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "MAG": (130, "Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
    "PARM": (131, "Nf", "Name,Value"),
}


def _pack(fmt: str, values) -> bytes:
    return struct.pack("<" + "".join(STRUCT[c] for c in fmt), *values)


def _fmt_message(mtype: int, name: str, fmt: str, columns: str) -> bytes:
    length = 3 + struct.calcsize("<" + "".join(STRUCT[c] for c in fmt))
    return HEAD + bytes([128]) + struct.pack("<BB4s16s64s", mtype, length, name.encode(), fmt.encode(),
                                             columns.encode())


def write_log(path: Path, imu_rows, mag_rows, params: dict[str, float], legacy: bool = False,
              formats: dict | None = None) -> bytes:
    """imu_rows: (TimeUS, gx, gy, gz, ax, ay, az); mag_rows: (TimeUS, mx, my, mz, ox, oy, oz,
    mox, moy, moz) in integer milligauss; both merged in time order after the parameters.
    legacy: in older ArduCopter's formats (LEGACY; the times written in whole milliseconds);
    formats: other message formats (e.g. a MAG with fewer fields) in place of those."""
    formats = formats or (LEGACY if legacy else FORMATS)
    out = bytearray(_fmt_message(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    for name, (mtype, fmt, cols) in formats.items():
        out += _fmt_message(mtype, name, fmt, cols)
    for k, v in params.items():
        out += HEAD + bytes([formats["PARM"][0]]) + _pack(formats["PARM"][1], ((k.encode(), v) if legacy else
                                                                              (0, k.encode(), v)))
    rows = [(r[0], 0, r) for r in imu_rows] + [(r[0], 1, r) for r in mag_rows]
    for t, kind, r in sorted(rows, key=lambda x: (x[0], x[1])):
        stamp = (int(r[0]) // 1000,) if legacy else (int(r[0]), 0)
        if kind == 0:
            out += HEAD + bytes([formats["IMU"][0]]) + _pack(formats["IMU"][1], (*stamp, *r[1:]))
        else:
            out += HEAD + bytes([formats["MAG"][0]]) + _pack(formats["MAG"][1], (*stamp, *(int(x) for x in r[1:])))
    Path(path).write_bytes(bytes(out))
    return bytes(out)
