"""Magnetometer files (docs/magnetometer.md): reading and checking `mag/<mag>.csv`.

One row per sample, in the magnetometer's own clock (integer nanoseconds) and axes, raw
(no calibration applied), microtesla:

    #timestamp [ns],m_x [uT],m_y [uT],m_z [uT]
    1403715273262142976,21.337,-4.102,-41.876

Every refusal is one DatasetError line naming the file (and row), exit 2. Row numbers are
the file's line numbers (the header is line 1).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from rigcal.core.rig import Rig
from rigcal.core.validate import parses_as_float
from rigcal.data.imu_csv import ImuSamples, _plain, declared_csv_files
from rigcal.errors import DatasetError

MAG_HEADER = "#timestamp [ns],m_x [uT],m_y [uT],m_z [uT]"
COLUMNS = 4
MIN_SAMPLES = 10
_INTEGER = re.compile(r"^[0-9]+$")


@dataclass(frozen=True)
class MagSamples:
    """One magnetometer file: t_ns (N,) int64 strictly increasing (its own clock), m_uT (N, 3)."""

    path: Path
    t_ns: np.ndarray
    m_uT: np.ndarray


def read_mag_csv(path: str | Path) -> MagSamples:
    """Parse and check one mag/<mag>.csv (lines starting with '#' are comments), as
    imu_csv.read_imu_csv does: a file that imu_csv's byte scan passes (no signed stamp, no
    indented line, no '#' inside a row) is parsed by numpy's C reader in one pass; any file it
    does not take, or that fails a check after it, is read again row by row, which names the
    first bad row. Both give the same arrays."""
    path = Path(path)
    fast = _read_fast(path)
    if fast is not None:
        return MagSamples(path, *fast)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read ({e.__class__.__name__}: {e})") from None
    return _read_rows(path, text)


_ROW = np.dtype([("t", np.int64), ("m", np.float64, (3,))])


def _read_fast(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(t_ns, m_uT) when every row is well formed (numpy's reader refuses a row of another
    width or a timestamp that is not an integer), else None."""
    import warnings

    try:
        if not _plain(path):
            return None
        with warnings.catch_warnings():
            # an empty file's warning, too, sends it the slow way, and numpy's deprecated
            # reading of a "1.6e18" timestamp through a float (rounded to 256 ns)
            warnings.simplefilter("error")
            rows = np.loadtxt(path, delimiter=",", comments="#", dtype=_ROW, encoding="utf-8-sig", ndmin=1)
    except (OSError, UnicodeDecodeError, ValueError, OverflowError, UserWarning, DeprecationWarning):
        return None
    t, m = rows["t"], rows["m"]
    if len(t) < MIN_SAMPLES or (t < 0).any() or (np.diff(t) <= 0).any() or not np.isfinite(m).all():
        return None
    return np.ascontiguousarray(t), np.ascontiguousarray(m)


def _read_rows(path: Path, text: str) -> MagSamples:
    rows, stamps, last_row = [], [], 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != COLUMNS:
            raise DatasetError(f"{path}: row {lineno}: expected {COLUMNS} comma-separated columns (timestamp [ns], "
                               f"m_x, m_y, m_z [uT]), got {len(cells)}")
        if not _INTEGER.match(cells[0]):
            raise DatasetError(f"{path}: row {lineno}: timestamp {cells[0][:40]!r} is not an integer number of "
                               f"nanoseconds")
        for i, c in enumerate(cells[1:], start=2):
            if not parses_as_float(c) or not np.isfinite(float(c)):
                raise DatasetError(f"{path}: row {lineno}: column {i}: expected a finite number (uT), got {c[:40]!r}")
        t = int(cells[0])
        if t >= 2 ** 63:
            raise DatasetError(f"{path}: row {lineno}: timestamp {t} does not fit in 64 bits")
        if stamps and t <= stamps[-1]:
            what = "repeats" if t == stamps[-1] else "is before"
            raise DatasetError(f"{path}: row {lineno}: timestamp {t} {what} the previous row's ({stamps[-1]}, row "
                               f"{last_row}); timestamps must strictly increase")
        stamps.append(t)
        last_row = lineno
        rows.append([float(c) for c in cells[1:]])
    if len(rows) < MIN_SAMPLES:
        raise DatasetError(f"{path}: expected at least {MIN_SAMPLES} samples (rows: timestamp [ns], m_x, m_y, m_z), "
                           f"got {len(rows)}")
    return MagSamples(path, np.array(stamps, np.int64), np.array(rows))


def mag_csv(t_ns: np.ndarray, m_uT: np.ndarray) -> str:
    """The text of a mag/<mag>.csv that read_mag_csv reads back to the same doubles."""
    rows = [f"{int(t)}," + ",".join(repr(float(x)) for x in m) for t, m in zip(t_ns, m_uT)]
    return MAG_HEADER + "\n" + "\n".join(rows) + "\n"


def has_mag(root: str | Path) -> bool:
    """Whether the dataset has a mag/ folder."""
    return (Path(root) / "mag").exists()


def check_mag_dataset(root: str | Path, rig: Rig, imus: Mapping[str, ImuSamples]) -> dict[str, MagSamples]:
    """The magnetometer format's checks of mag/: every declared magnetometer has a file and every file
    a declared magnetometer, each file is well formed and overlaps its IMU's samples in time
    (its stamps shifted by the declared time_offset_s). {} when there is no mag/ folder."""
    folder = Path(root) / "mag"
    if not folder.exists():
        return {}
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder (expected mag/<magnetometer>.csv per magnetometer of the rig)")
    files = declared_csv_files(folder, [m.name for m in rig.magnetometers], "magnetometer", "magnetometers")
    out = {}
    for mag in rig.magnetometers:
        s = read_mag_csv(files[mag.name])
        imu = rig.mag_imu(mag)
        if imu.name not in imus:
            raise DatasetError(f"{Path(root) / 'imu' / (imu.name + '.csv')}: missing; magnetometer {mag.name} is "
                               f"calibrated against IMU {imu.name}")
        t = s.t_ns + round((mag.time_offset_s or 0.0) * 1e9)
        ti = imus[imu.name].t_ns
        overlap = min(int(t[-1]), int(ti[-1])) - max(int(t[0]), int(ti[0]))
        if overlap <= 0:
            raise DatasetError(f"{s.path}: its samples ({t[0] * 1e-9:.3f}-{t[-1] * 1e-9:.3f} s on the IMU clock, "
                               f"stamp + time_offset_s) do not overlap {imus[imu.name].path.name}'s "
                               f"({ti[0] * 1e-9:.3f}-{ti[-1] * 1e-9:.3f} s); are both in nanoseconds on the same "
                               f"clock?")
        out[mag.name] = s
    return out
