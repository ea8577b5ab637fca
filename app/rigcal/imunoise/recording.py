"""A static IMU recording, read fast and checked before any Allan deviation is computed.

Input: EuRoC's IMU csv (rigcal's `imu/<imu>.csv`: timestamp in integer ns, gyroscope x y z
rad/s, accelerometer x y z m/s^2), optionally with an 8th column, the temperature in deg C.
Hours at 400 Hz are millions of rows: the file is parsed by numpy in one pass; only when
that fails is it scanned line by line to name the first bad row.

Checks (each refusal an InputError naming the file and, where there is one, the row):
- timestamps strictly increase (a repeated or backward stamp is refused);
- the sample rate is the median interval's; a gap is an interval over GAP_SAMPLES periods;
  the stretches between gaps are all used, their Allan variances pooled with no cluster
  spanning a gap (rigcal.imunoise.allan.pooled_allan_deviation; said in a note);
- the recording is still: consecutive one-second means of the accelerometer (gyroscope)
  differ by at most MOVING_ACCEL m/s^2 (MOVING_GYRO rad/s) plus MOTION_SIGMAS standard
  deviations of what the sensor's white noise alone moves them by (a noisy consumer part
  must not be taken for a moving one); otherwise it is refused with the figure and the time. Differences of neighbouring means, not deviations from the
  median: the bias random walk itself moves the mean by K sqrt(t) over hours (0.3 m/s^2
  in 3 h at K = 3e-3), while motion or a knock changes it within a second;
- a temperature column whose linear trend changes by over TEMP_DRIFT_C gets a note.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigcal.data.imu_csv import GAP_SAMPLES
from rigcal.errors import InputError

MOVING_ACCEL = 0.1  # m/s^2 (~10 mg, a 0.6 deg tilt) between consecutive one-second means
MOVING_GYRO = 0.02  # rad/s (~1 deg/s)
MOTION_SIGMAS = 6.0  # plus this many standard deviations of the white noise's own change
TEMP_DRIFT_C = 1.0
_HINT = "(timestamp [ns], gyroscope x y z, accelerometer x y z[, temperature])"


@dataclass(frozen=True)
class ImuRecording:
    """Samples of one IMU: t_ns (N,) int64, gyro (N, 3) rad/s, accel (N, 3) m/s^2, temp_c (N,)
    or None; `source` names where they came from (a file, or bag:topic)."""

    source: str
    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    temp_c: np.ndarray | None = None


@dataclass(frozen=True)
class Checked:
    """A recording after the checks: the recording, the stretches between its gaps, its rate, the whole recording's span
    and gaps, the stillness figures (largest change between consecutive one-second means,
    accelerometer m/s^2 and gyroscope rad/s) and notes."""

    recording: ImuRecording
    rate_hz: float
    span_s: float
    n_gaps: int
    longest_gap_s: float
    accel_motion: float
    gyro_motion: float
    temp_change_c: float | None
    notes: tuple[str, ...]
    segments: tuple[slice, ...] = ()  # the stretches between gaps, into `recording`; () = all of it


def _columns(path: Path, text_head: str) -> tuple[int, int]:
    """(number of columns of the first data row, its line number)."""
    for lineno, line in enumerate(text_head.splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            return len(line.split(",")), lineno
    raise InputError(f"{path}: no samples (expected rows {_HINT})")


def read_imu_file(path: str | Path) -> ImuRecording:
    """An IMU csv of 7 (or 8, with temperature) columns; InputError naming the first bad row."""
    path = Path(path)
    try:
        with open(path, "r", encoding="utf-8-sig") as f:
            head = f.read(65536)
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    ncol, lineno = _columns(path, head)
    if ncol not in (7, 8):
        raise InputError(f"{path}: row {lineno}: expected 7 or 8 comma-separated columns {_HINT}, got {ncol}")
    dtype = [("t", "i8"), ("v", "f8", (ncol - 1,))]
    try:
        with warnings.catch_warnings():
            # numpy 2.2 and older read an integer column's "1.6e18" through a float (rounded to
            # 256 ns) with a DeprecationWarning: the row is refused instead
            warnings.simplefilter("error", DeprecationWarning)
            data = np.loadtxt(path, delimiter=",", comments="#", dtype=dtype, encoding="utf-8-sig", ndmin=1)
    except (ValueError, OverflowError, DeprecationWarning):
        raise InputError(_first_bad_row(path, ncol)) from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    t, v = data["t"], data["v"]
    if len(t) < 2:
        raise InputError(f"{path}: expected at least 2 samples {_HINT}, got {len(t)}")
    if not np.isfinite(v).all():
        raise InputError(_first_bad_row(path, ncol))
    if (np.diff(t) <= 0).any():
        raise InputError(_first_bad_row(path, ncol))
    # views into the one parsed array: no copy (about 100 bytes a sample at the peak, 24 h at 400 Hz in ~3.5 GB)
    return ImuRecording(str(path), t, v[:, :3], v[:, 3:6], v[:, 6] if ncol == 8 else None)


def _first_bad_row(path: Path, ncol: int) -> str:
    """The message for the first row that breaks the format (slow: only on the error path)."""
    prev = None
    with open(path, "r", encoding="utf-8-sig") as f:
        for lineno, line in enumerate(f, start=1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            cells = [c.strip() for c in line.split(",")]
            if len(cells) != ncol:
                return f"{path}: row {lineno}: expected {ncol} comma-separated columns {_HINT}, got {len(cells)}"
            if not cells[0].isdigit():
                return f"{path}: row {lineno}: timestamp {cells[0][:40]!r} is not an integer number of nanoseconds"
            for col, c in enumerate(cells[1:], start=2):
                try:
                    ok = math.isfinite(float(c))
                except ValueError:
                    ok = False
                if not ok:
                    return f"{path}: row {lineno}: column {col}: {c[:40]!r} is not a finite number"
            t = int(cells[0])
            if prev is not None and t <= prev[0]:
                what = "repeats" if t == prev[0] else "is before"
                return (f"{path}: row {lineno}: timestamp {t} {what} the previous row's ({prev[0]}, row {prev[1]}); "
                        f"timestamps must strictly increase")
            prev = (t, lineno)
    return f"{path}: not readable as rows {_HINT}"


def samples_recording(source: str, t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> ImuRecording:
    """A recording from arrays (a bag's messages): the same stamp checks as a file's."""
    t_ns = np.asarray(t_ns, np.int64)
    bad = np.flatnonzero(np.diff(t_ns) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        what = "repeats" if t_ns[i] == t_ns[i - 1] else "is before"
        raise InputError(f"{source}: message {i + 1}: stamp {t_ns[i]} {what} the previous message's; "
                         f"stamps must strictly increase")
    if len(t_ns) < 2:
        raise InputError(f"{source}: expected at least 2 IMU messages, got {len(t_ns)}")
    return ImuRecording(source, t_ns, np.asarray(gyro, float), np.asarray(accel, float))


def stretches(t_ns: np.ndarray) -> tuple[list[slice], float, int, float]:
    """(the runs between gaps, rate Hz from the median interval, number of gaps, longest gap
    s). A gap: an interval over GAP_SAMPLES median intervals."""
    dt = np.diff(t_ns).astype(np.float64) * 1e-9
    period = float(np.median(dt))
    gap = np.flatnonzero(dt > GAP_SAMPLES * period)
    edges = np.concatenate([[0], gap + 1, [len(t_ns)]])
    runs = [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
    return runs, 1.0 / period, len(gap), float(dt[gap].max()) if len(gap) else 0.0


def motion(x: np.ndarray, rate_hz: float) -> tuple[float, float, float]:
    """(the largest change (norm) between consecutive one-second means of x (N, 3), the time
    in s from the start where it happens, the part of such a change the sensor's own white
    noise explains: MOTION_SIGMAS standard deviations, from the samples' successive
    differences (robust: median absolute), which slow motion hardly touches)."""
    w = max(int(round(rate_hz)), 1)
    k = len(x) // w
    if k < 2:
        return 0.0, 0.0, 0.0
    means = x[:k * w].reshape(k, w, 3).mean(axis=1)
    step = np.linalg.norm(np.diff(means, axis=0), axis=1)
    i = int(np.argmax(step))
    sd = 1.4826 * np.median(np.abs(np.diff(x[:min(len(x), 600 * w)], axis=0)), axis=0) / math.sqrt(2.0)
    noise = MOTION_SIGMAS * float(np.sqrt(np.sum(2.0 * sd ** 2 / w)))
    return float(step[i]), float(i + 1), noise


def check(rec: ImuRecording) -> Checked:
    """The checks of the module docstring; InputError for a moving recording."""
    runs, rate, n_gaps, longest = stretches(rec.t_ns)
    notes = []
    span = (rec.t_ns[-1] - rec.t_ns[0]) * 1e-9
    if n_gaps:
        used = sum((rec.t_ns[r.stop - 1] - rec.t_ns[r.start]) * 1e-9 for r in runs)
        notes.append(f"{rec.source}: {n_gaps} gap(s) over {GAP_SAMPLES} samples (longest {longest:.3f} s); the Allan "
                     f"variance pools the {len(runs)} stretches between them, no cluster spanning a gap: {used:.0f} of "
                     f"{span:.0f} s (the longest stretch: samples {max(runs, key=lambda r: r.stop - r.start).start + 1}"
                     f"-{max(runs, key=lambda r: r.stop - r.start).stop})")
    worst = None
    for r in runs:
        (acc_m, acc_t, acc_n), (gyr_m, gyr_t, gyr_n) = motion(rec.accel[r], rate), motion(rec.gyro[r], rate)
        acc_lim, gyr_lim = MOVING_ACCEL + acc_n, MOVING_GYRO + gyr_n
        score = max(acc_m / acc_lim, gyr_m / gyr_lim)
        if worst is None or score > worst[0]:
            t0 = (rec.t_ns[r.start] - rec.t_ns[0]) * 1e-9
            at = t0 + (acc_t if acc_m / acc_lim >= gyr_m / gyr_lim else gyr_t)
            worst = (score, acc_m, gyr_m, acc_lim, gyr_lim, at)
    _, acc_m, gyr_m, acc_lim, gyr_lim, at = worst
    if acc_m > acc_lim or gyr_m > gyr_lim:
        raise InputError(f"{rec.source}: not a static recording: consecutive one-second means of the accelerometer "
                         f"differ by up to {acc_m:.3g} m/s^2 (gyroscope {gyr_m:.3g} rad/s; worst {at:.0f} s into "
                         f"the recording), over the {acc_lim:.2g} m/s^2 ({gyr_lim:.2g} rad/s) of a still "
                         f"IMU with this noise; record it resting on a firm support, untouched")
    part = rec
    change = None
    if part.temp_c is not None:
        t = (part.t_ns - part.t_ns[0]) * 1e-9
        slope = np.polyfit(t, part.temp_c, 1)[0]
        change = float(slope * (t[-1] - t[0]))
        if abs(change) > TEMP_DRIFT_C:
            notes.append(f"{rec.source}: the temperature trend changes by {change:+.1f} deg C over the recording; the "
                         f"random walk and bias instability include the thermal drift (warm the IMU up first)")
    return Checked(part, rate, float(span), n_gaps, longest, acc_m, gyr_m, change, tuple(notes),
                   tuple(runs) if n_gaps else ())
