"""Writing a recording into the dataset layout (docs/formats.md#dataset, #motion-datasets), one
frame at a time.

Every source (EuRoC folder, bag, video) hands `Frame`s and IMU blocks to one
`DatasetWriter`, which keeps per camera the first of duplicated or backwards stamps,
applies the --start/--end window, writes `images/<camera>/<t_ns>.<ext>` and at the end
`imu/<imu>.csv`, and (with --rate) removes all but the sharpest instant of each slot.
It writes into a folder the caller made (a temporary one renamed into place at the end).
"""

from __future__ import annotations

import os
import shutil
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from rigcal.data.dataset import IMAGE_EXTENSIONS
from rigcal.errors import InputError
from rigcal.data.imu_csv import imu_csv
from rigcal.data.mag_csv import mag_csv
from rigcal.data.ingest.images import decode, focus_measure

# IMU samples are kept this far outside the image window: the IMU terms need samples
# around the first and last image, and docs/formats.md#motion-datasets tolerates clocks that differ by up to 1 s.
IMU_PAD_NS = 500_000_000


@dataclass(frozen=True)
class Frame:
    """One image of one camera: its capture time and where its pixels are.

    Exactly one of `pixels` (decoded, 8-bit grey or BGR), `encoded` (png/jpeg bytes written
    as they are, suffix `suffix`) or `file` (a file in a dataset format, linked or copied)."""

    t_ns: int
    where: str
    pixels: np.ndarray | None = None
    encoded: bytes | None = None
    suffix: str = ".png"
    file: Path | None = None

    def image(self) -> np.ndarray:
        if self.pixels is not None:
            return self.pixels
        if self.encoded is not None:
            return decode(self.encoded)
        img = cv2.imread(str(self.file), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"{self.where}: cannot read the image")
        return img


@dataclass(frozen=True)
class ImuBlock:
    """IMU samples: t_ns (N,) int64, gyro (N, 3) rad/s, accel (N, 3) m/s^2, IMU axes."""

    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray


@dataclass(frozen=True)
class MagBlock:
    """Magnetometer readings: t_ns (N,) int64, m_uT (N, 3) microtesla, the chip's axes, raw."""

    t_ns: np.ndarray
    m_uT: np.ndarray


@dataclass
class StreamCounts:
    """What happened to one camera's frames or one IMU's samples."""

    source: str
    read: int = 0
    written: int = 0
    duplicated: int = 0
    backwards: int = 0
    outside: int = 0
    first_ns: int | None = None
    last_ns: int | None = None


@dataclass
class CameraCounts(StreamCounts):
    """One camera's frame counts, with the frames dropped by --rate thinning."""

    thinned: int = 0
    _last_kept: int | None = field(default=None, repr=False)

    @property
    def kept(self) -> int:
        return self.written - self.thinned


ImuCounts = StreamCounts


@dataclass(frozen=True)
class Window:
    """Stamps kept: t0_ns + start_s .. t0_ns + end_s (None: open)."""

    t0_ns: int
    start_s: float | None = None
    end_s: float | None = None

    def bounds(self, pad_ns: int = 0) -> tuple[int, int]:
        """(lo, hi) in integer ns: stamps near 1.4e18 ns are 256 ns apart as doubles, so the
        window is never computed in floating point."""
        lo = _INT64_MIN if self.start_s is None else self.t0_ns + round(self.start_s * 1e9) - pad_ns
        hi = _INT64_MAX if self.end_s is None else self.t0_ns + round(self.end_s * 1e9) + pad_ns
        return lo, hi


_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1


class DatasetWriter:
    """Writes frames and IMU samples under `root` (see the module docstring)."""

    def __init__(self, root: Path, cameras: dict[str, str], imus: dict[str, str], window: Window,
                 rate_hz: float | None = None, link: bool = True, threads: int | None = None,
                 mags: dict[str, str] | None = None):
        self.root = root
        self.window = window
        self.rate_hz = rate_hz
        self.link = link
        self.cameras = {c: CameraCounts(src) for c, src in cameras.items()}
        self.imus = {n: ImuCounts(src) for n, src in imus.items()}
        self._imu_blocks: dict[str, list[ImuBlock]] = {n: [] for n in imus}
        self.mags = {n: ImuCounts(src) for n, src in (mags or {}).items()}
        self._mag_blocks: dict[str, list[MagBlock]] = {n: [] for n in self.mags}
        self._written: dict[str, dict[int, Path]] = {c: {} for c in cameras}
        self._focus: dict[str, dict[int, float]] = {c: {} for c in cameras}
        for c in cameras:
            (root / "images" / c).mkdir(parents=True, exist_ok=True)
        # PNG encoding is most of the work and OpenCV releases the GIL while it encodes, so
        # frames are encoded and written by threads, at most `_max_pending` ahead (memory).
        self._threads = threads or os.cpu_count() or 1
        self._pool = ThreadPoolExecutor(self._threads) if self._threads > 1 else None
        self._pending: deque = deque()
        self._max_pending = 4 * self._threads

    def close(self) -> None:
        """Stop the writer threads (after finish, or on an error: queued frames are dropped)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def add_frame(self, camera: str, frame: Frame) -> None:
        n = self.cameras[camera]
        n.read += 1
        t = frame.t_ns
        lo, hi = self.window.bounds()
        if not lo <= t <= hi:
            n.outside += 1
            return
        if n._last_kept is not None and t <= n._last_kept:
            if t == n._last_kept:
                n.duplicated += 1
            else:
                n.backwards += 1
            return
        if t < 0:
            raise InputError(f"{frame.where}: capture time {t} ns is before 0; image stems are non-negative "
                             f"integers (check --offset)")
        n._last_kept = t
        n.first_ns = t if n.first_ns is None else n.first_ns
        n.last_ns = t
        n.written += 1
        if self._pool is None:
            self._done(*self._write(camera, frame))
            return
        self._pending.append(self._pool.submit(self._write, camera, frame))
        while len(self._pending) > self._max_pending:
            self._done(*self._pending.popleft().result())

    def _done(self, camera: str, t: int, path: Path, focus: float | None) -> None:
        self._written[camera][t] = path
        if focus is not None:
            self._focus[camera][t] = focus

    def _write(self, camera: str, frame: Frame) -> tuple[str, int, Path, float | None]:
        """(camera, t_ns, written path, focus measure with --rate else None)."""
        focus = focus_measure(frame.image()) if self.rate_hz is not None else None
        return camera, frame.t_ns, self._write_file(camera, frame), focus

    def _write_file(self, camera: str, frame: Frame) -> Path:
        folder = self.root / "images" / camera
        if frame.file is not None and frame.file.suffix.lower() in IMAGE_EXTENSIONS:
            dst = folder / f"{frame.t_ns}{frame.file.suffix.lower()}"
            src = frame.file.resolve()
            if self.link:
                os.symlink(src, dst)
            else:
                shutil.copyfile(src, dst)
            return dst
        if frame.encoded is not None:
            dst = folder / f"{frame.t_ns}{frame.suffix}"
            dst.write_bytes(frame.encoded)
            return dst
        dst = folder / f"{frame.t_ns}.png"
        ok, buf = cv2.imencode(".png", frame.image())
        if not ok:  # pragma: no cover - OpenCV encodes every 8-bit grey or BGR array
            raise InputError(f"{frame.where}: cannot encode the image as PNG")
        dst.write_bytes(buf.tobytes())
        return dst

    def add_imu(self, name: str, block: ImuBlock) -> None:
        self._imu_blocks[name].append(block)

    def add_mag(self, name: str, block: MagBlock) -> None:
        self._mag_blocks[name].append(block)

    def finish(self) -> None:
        """Wait for the frames in flight, write imu/*.csv and thin the frames (--rate)."""
        while self._pending:
            self._done(*self._pending.popleft().result())
        self.close()
        for name, blocks in self._imu_blocks.items():
            self._finish_imu(name, blocks)
        for name, blocks in self._mag_blocks.items():
            self._finish_mag(name, blocks)
        if self.rate_hz is not None:
            kept = thin_by_rate(self._focus, self.window.t0_ns, self.rate_hz)
            for camera, paths in self._written.items():
                for t in sorted(set(paths) - set(kept[camera])):
                    paths.pop(t).unlink()
                    self.cameras[camera].thinned += 1
                if paths:
                    self.cameras[camera].first_ns, self.cameras[camera].last_ns = min(paths), max(paths)

    def _finish_imu(self, name: str, blocks: list[ImuBlock]) -> None:
        n = self.imus[name]
        if not blocks:
            raise InputError(f"{n.source}: no IMU samples")
        t = np.concatenate([b.t_ns for b in blocks]).astype(np.int64)
        gyro = np.concatenate([b.gyro for b in blocks]).reshape(-1, 3)
        accel = np.concatenate([b.accel for b in blocks]).reshape(-1, 3)
        keep = self._kept(n, t, "IMU sample")
        t, gyro, accel = t[keep], gyro[keep], accel[keep]
        n.written, n.first_ns, n.last_ns = len(t), int(t[0]), int(t[-1])
        (self.root / "imu").mkdir(exist_ok=True)
        (self.root / "imu" / f"{name}.csv").write_text(imu_csv(t, gyro, accel), encoding="utf-8")

    def _finish_mag(self, name: str, blocks: list[MagBlock]) -> None:
        n = self.mags[name]
        if not blocks:
            raise InputError(f"{n.source}: no magnetometer readings")
        t = np.concatenate([b.t_ns for b in blocks]).astype(np.int64)
        m = np.concatenate([b.m_uT for b in blocks]).reshape(-1, 3)
        keep = self._kept(n, t, "magnetometer reading")
        t, m = t[keep], m[keep]
        n.written, n.first_ns, n.last_ns = len(t), int(t[0]), int(t[-1])
        (self.root / "mag").mkdir(exist_ok=True)
        (self.root / "mag" / f"{name}.csv").write_text(mag_csv(t, m), encoding="utf-8")

    def _kept(self, n: StreamCounts, t: np.ndarray, what: str) -> np.ndarray:
        """The samples kept (the first of each stamp, in order, inside the window padded by
        IMU_PAD_NS), with n's counts filled in."""
        n.read = len(t)
        keep, dup, back = first_of_monotonic(t)
        n.duplicated, n.backwards = dup, back
        lo, hi = self.window.bounds(IMU_PAD_NS)
        inside = (t >= lo) & (t <= hi)
        n.outside = int((keep & ~inside).sum())
        keep &= inside
        if not keep.any():
            raise InputError(f"{n.source}: no {what} inside the chosen time window")
        return keep


def first_of_monotonic(t: np.ndarray) -> tuple[np.ndarray, int, int]:
    """(keep mask, duplicated count, backwards count): a stamp is kept when it exceeds every
    stamp before it, so of repeated or backwards stamps the first is kept."""
    t = np.asarray(t, np.int64)
    keep = np.ones(len(t), bool)
    if len(t) < 2:
        return keep, 0, 0
    before = np.maximum.accumulate(t)[:-1]
    keep[1:] = t[1:] > before
    dup = int((t[1:] == before).sum())
    return keep, dup, int((~keep).sum()) - dup


def thin_by_rate(focus: dict[str, dict[int, float]], t0_ns: int, rate_hz: float) -> dict[str, list[int]]:
    """Per camera, the stamps kept when each slot of 1/rate_hz seconds keeps one instant.

    An instant is a stamp; the cameras that have it share it (a synchronised rig), so
    the slot keeps the stamp seen by the most cameras, sharpest (highest smallest focus
    over those cameras) first; cameras it does not cover (unsynchronised clocks) get their
    own sharpest stamp of the slot the same way."""
    slot_ns = 1e9 / rate_hz
    by_slot: dict[int, dict[int, dict[str, float]]] = {}
    for camera, stamps in focus.items():
        for t, f in stamps.items():
            by_slot.setdefault(int((t - t0_ns) // slot_ns), {}).setdefault(t, {})[camera] = f
    kept: dict[str, list[int]] = {c: [] for c in focus}
    for instants in by_slot.values():
        left = {c for cams in instants.values() for c in cams}
        while left:
            t, cams = max(instants.items(), key=lambda kv: (len(left & set(kv[1])), min(kv[1].values()), -kv[0]))
            for c in left & set(cams):
                kept[c].append(t)
            left -= set(cams)
    return kept
