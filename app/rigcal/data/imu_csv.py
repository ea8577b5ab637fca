"""Motion datasets (docs/formats.md#motion-datasets): reading and checking `imu/<imu>.csv` and the
integer-nanosecond image stems, before anything is detected or solved.

Every refusal is one DatasetError line naming the file (and row), exit 2. Row numbers are
the file's line numbers (the header is line 1), as an editor shows them.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from rigcal.data.dataset import DatasetImages
from rigcal.errors import DatasetError
from rigcal.core.rig import Rig
from rigcal.core.validate import parses_as_float

IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
COLUMNS = 7
OVERLAP_SLACK_S = 1.0  # images and IMU samples must overlap within this (docs/formats.md#motion-datasets)
GAP_SAMPLES = 5  # a gap longer than this many nominal sample periods is reported
_INTEGER = re.compile(r"^[0-9]+$")


@dataclass(frozen=True)
class ImuSamples:
    """One IMU file: t_ns (N,) int64 strictly increasing, gyro (N, 3) rad/s, accel (N, 3) m/s^2."""

    path: Path
    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.split(",")]


def read_imu_csv(path: str | Path) -> ImuSamples:
    """Parse and check one EuRoC-format IMU file (lines starting with '#' are comments).

    Hours at hundreds of Hz are millions of rows: a file that passes `_plain` is parsed by
    numpy's C reader in one pass (`_read_fast`, ~5x faster than a Python loop); any file it
    does not take, or that fails a check after it, is read row by row (`_read_rows`), which
    names the first bad row. Both give the same arrays (both read numbers correctly rounded)."""
    path = Path(path)
    fast = _read_fast(path)
    return fast if fast is not None else _read_rows(path)


_SCAN_BYTES = 1 << 24
# bytes that the row-by-row reader treats differently from np.loadtxt at a line's start: a
# signed timestamp (refused there, taken by numpy) and white space (a blank line, an indented
# comment or row): such files go the slow way
_ODD_START = np.zeros(256, bool)
_ODD_START[list(b"+- \t")] = True


def _plain(path: Path) -> bool:
    """Whether np.loadtxt(comments='#') reads this file exactly as `_read_rows` would: no odd
    line start (above) and every '#' opens a line (numpy also cuts a row at a '#' inside it,
    which `_read_rows` refuses). A streaming scan: memory independent of the file's size."""
    prev = b"\n"  # the start of the file is a line start
    with open(path, "rb") as f:
        if f.read(3) != b"\xef\xbb\xbf":  # a BOM is not part of the first line
            f.seek(0)
        while block := f.read(_SCAN_BYTES):
            chunk = np.frombuffer(prev + block, np.uint8)
            starts = chunk[np.flatnonzero((chunk[:-1] == 10) | (chunk[:-1] == 13)) + 1]  # the byte after each \n, \r
            if _ODD_START[starts].any() or block.count(b"#") != np.count_nonzero(starts == 35):
                return False
            prev = block[-1:]
    return True


def _read_fast(path: Path) -> ImuSamples | None:
    """The file in one np.loadtxt pass, or None for `_read_rows` to read (and refuse)."""
    try:
        if not _plain(path):
            return None
        with warnings.catch_warnings():  # an empty file is refused by _read_rows, in one line
            warnings.simplefilter("ignore", UserWarning)
            # numpy reads an integer column's "1.6e18" through a float (deprecated, with a
            # warning): a timestamp rounded to 256 ns, accepted. As an error it goes to
            # _read_rows, which refuses the row
            warnings.simplefilter("error", DeprecationWarning)
            data = np.loadtxt(path, delimiter=",", comments="#", dtype=[("t", "i8"), ("v", "f8", (COLUMNS - 1,))],
                              encoding="utf-8-sig", ndmin=1)
    except (OSError, UnicodeDecodeError, ValueError, OverflowError, DeprecationWarning):
        return None
    t, v = data["t"], data["v"]
    if len(t) < 2 or not np.isfinite(v).all() or t[0] < 0 or (np.diff(t) <= 0).any():
        return None
    return ImuSamples(path, np.ascontiguousarray(t), np.ascontiguousarray(v[:, :3]), np.ascontiguousarray(v[:, 3:]))


def _read_rows(path: Path) -> ImuSamples:
    """Row by row, refusing the first bad row with one DatasetError line."""
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM (Windows editors) is not part of the header
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read ({e.__class__.__name__}: {e})") from None
    rows, t_ns = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = _cells(line)
        if len(cells) != COLUMNS:
            raise DatasetError(f"{path}: row {lineno}: expected {COLUMNS} comma-separated columns (timestamp [ns], "
                               f"gyroscope x y z, accelerometer x y z), got {len(cells)}")
        if not _INTEGER.match(cells[0]):
            raise DatasetError(f"{path}: row {lineno}: timestamp {cells[0][:40]!r} is not an integer number of "
                               f"nanoseconds")
        try:
            vals = [float(c) for c in cells[1:]]
        except ValueError:
            bad = next(i for i, c in enumerate(cells[1:], start=2) if not parses_as_float(c))
            raise DatasetError(f"{path}: row {lineno}: column {bad}: {cells[bad - 1][:40]!r} is not a number") from None
        if not all(np.isfinite(vals)):
            bad = next(i for i, v in enumerate(vals, start=2) if not np.isfinite(v))
            raise DatasetError(f"{path}: row {lineno}: column {bad}: expected a finite number, got {cells[bad - 1]!r}")
        t = int(cells[0])
        if t_ns and t <= t_ns[-1][0]:
            what = "repeats" if t == t_ns[-1][0] else "is before"
            raise DatasetError(f"{path}: row {lineno}: timestamp {t} {what} the previous row's ({t_ns[-1][0]}, row "
                               f"{t_ns[-1][1]}); timestamps must strictly increase")
        if t >= 2 ** 63:
            raise DatasetError(f"{path}: row {lineno}: timestamp {t} does not fit in 64 bits")
        t_ns.append((t, lineno))
        rows.append(vals)
    if len(rows) < 2:
        raise DatasetError(f"{path}: expected at least 2 samples (rows: timestamp [ns], gyro x y z, accel x y z), "
                           f"got {len(rows)}")
    data = np.array(rows)
    return ImuSamples(path, np.array([t for t, _ in t_ns], np.int64), data[:, :3], data[:, 3:])


def imu_csv(t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> str:
    """The text of an imu/<imu>.csv (EuRoC's imu0/data.csv, docs/formats.md#motion-datasets) that read_imu_csv reads:
    integer-ns stamps and every number as the shortest text that reads back to the same double."""
    rows = [f"{int(t)}," + ",".join(repr(float(x)) for x in (*g, *a)) for t, g, a in zip(t_ns, gyro, accel)]
    return IMU_HEADER + "\n" + "\n".join(rows) + "\n"


def corner_frame_stems(path: Path) -> dict[str, int]:
    """The frames of a corners/<camera>.csv (its first column) -> the first row naming each;
    the full check of the file is rigcal.data.corners' when calibrate reads it."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    out: dict[str, int] = {}
    for n, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.setdefault(s.split(",", 1)[0].strip(), n)
    return out


def image_times_ns(images: DatasetImages) -> dict[str, np.ndarray]:
    """Per camera the image stems as int64 nanoseconds (camera clock), or, for a camera given
    as corners/<camera>.csv, its frames; DatasetError naming the first image (or row) whose
    stem is not an integer."""
    out = {}
    for cam in images.cameras:
        if cam in images.corners:
            frames = corner_frame_stems(images.corners[cam])
            for stem, row in frames.items():
                if not _INTEGER.match(stem):
                    raise DatasetError(f"{images.corners[cam]}: row {row}: frame {stem!r} is not an integer; a "
                                       f"dataset with imu/ names every frame by its capture time in nanoseconds")
            out[cam] = np.array(sorted(int(s) for s in frames), np.int64)
            continue
        for stem, path in images.frames[cam].items():
            if not _INTEGER.match(stem):
                raise DatasetError(f"{path}: image stem {stem!r} is not an integer; a dataset with imu/ names every "
                                   f"image by its capture time in nanoseconds (e.g. 1403715273262142976.png)")
        out[cam] = np.array(sorted(int(s) for s in images.frames[cam]), np.int64)
    return out


def gaps(t_ns: np.ndarray, rate_hz: float) -> tuple[int, float]:
    """(number of gaps longer than GAP_SAMPLES nominal periods, longest gap in seconds)."""
    dt = np.diff(t_ns) * 1e-9
    long = dt > GAP_SAMPLES / rate_hz
    return int(long.sum()), float(dt.max()) if len(dt) else 0.0


@dataclass(frozen=True)
class MotionCheck:
    """What check_motion_dataset found: the IMU files read (name -> samples), each camera's
    image times (ns, camera clock), and notes for the console; frame_t_ns (camera -> frame
    -> the image's own stem in ns) once calibrate has grouped free-running cameras' images
    into shared frames (rigcal.data.dataset.associate_by_time), else None."""

    imus: Mapping[str, ImuSamples]
    image_t_ns: Mapping[str, np.ndarray]
    notes: tuple[str, ...]
    frame_t_ns: Mapping[str, Mapping[str, int]] | None = None



def declared_csv_files(folder: Path, declared: list[str], what: str, key: str) -> dict[str, Path]:
    """A sensor folder's `<name>.csv` files (imu/, mag/) by name: every file a sensor the rig
    declares under `key` and every declared sensor a file, or one DatasetError naming the file."""
    files = {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() == ".csv" and not p.name.startswith(".")}
    for name, p in files.items():
        if name not in declared:
            have = f"declares {', '.join(declared)}" if declared else f"declares no {what}"
            raise DatasetError(f"{p}: {what} {name!r} is not declared in the rig (it {have}); add it under `{key}:` "
                               f"or remove the file")
    for name in declared:
        if name not in files:
            raise DatasetError(f"{folder / (name + '.csv')}: missing; the rig declares {what} {name!r}")
    return files

def check_motion_dataset(root: str | Path, rig: Rig, images: DatasetImages, min_overlap_s: float = 0.0
                         ) -> MotionCheck:
    """The checks of docs/formats.md#motion-datasets for a dataset with imu/: every declared IMU has a file and every
    file a declared IMU, each file is well formed, every image stem is an integer, and each
    camera's images (shifted by its declared time_offset_s) overlap each IMU's samples within
    1 s, and for at least min_overlap_s (what the camera-IMU step's spline needs). Without
    imu/ nothing is checked; a rig with IMUs gets the note that the reference falls back to
    `aligned`."""
    folder = Path(root) / "imu"
    if not folder.exists():
        if not rig.imus:
            return MotionCheck({}, {}, ())
        names = ", ".join(i.name for i in rig.imus)
        return MotionCheck({}, {}, (f"the rig declares IMU(s) {names} but the dataset has no imu/ folder: their blocks "
                                    f"are carried through unchanged and the reference is `aligned` (docs/formats.md#motion-datasets)",))
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder (expected imu/<imu>.csv per IMU of the rig)")
    declared = [i.name for i in rig.imus]
    files = declared_csv_files(folder, declared, "IMU", "imus")
    samples = {name: read_imu_csv(files[name]) for name in declared}
    times = image_times_ns(images)
    for cam in images.cameras:
        offset_ns = round((rig.camera(cam).time_offset_s or 0.0) * 1e9)
        t = times[cam] + offset_ns
        for name, s in samples.items():
            lo, hi = int(s.t_ns[0]), int(s.t_ns[-1])
            slack = round(OVERLAP_SLACK_S * 1e9)
            if t[-1] < lo - slack or t[0] > hi + slack:
                first = images.corners[cam] if cam in images.corners else min(
                    images.frames[cam].items(), key=lambda kv: int(kv[0]))[1]
                raise DatasetError(
                    f"{first}: camera {cam}'s images ({t[0] * 1e-9:.3f}-{t[-1] * 1e-9:.3f} s on the IMU clock, "
                    f"stem + time_offset_s) do not overlap {s.path.name}'s samples ({lo * 1e-9:.3f}-{hi * 1e-9:.3f} s) "
                    f"within {OVERLAP_SLACK_S:g} s; are both in nanoseconds on the same clock?")
            shared = (min(int(t[-1]), hi) - max(int(t[0]), lo)) * 1e-9
            if shared < min_overlap_s:
                first = images.corners[cam] if cam in images.corners else min(
                    images.frames[cam].items(), key=lambda kv: int(kv[0]))[1]
                raise DatasetError(
                    f"{first}: camera {cam}'s images overlap {s.path.name}'s samples for {max(shared, 0.0):.2f} s "
                    f"({t[0] * 1e-9:.3f}-{t[-1] * 1e-9:.3f} s on the IMU clock); the camera-IMU calibration needs at "
                    f"least {min_overlap_s:g} s: record longer or drop the camera")
    notes = []
    for name, s in samples.items():
        n_gaps, longest = gaps(s.t_ns, rig.imu(name).update_rate)
        if n_gaps:
            notes.append(f"{s.path}: {n_gaps} gap(s) longer than {GAP_SAMPLES} samples, the longest {longest:.3f} s")
    return MotionCheck(samples, times, tuple(notes))
