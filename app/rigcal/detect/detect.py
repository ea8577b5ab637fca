"""Board detection, the pipeline's first stage: every image of a dataset -> board views.

Conventions: pixel coordinates are OpenCV's (integer = pixel centre); a view's `ids`
index its board's `Board.corners` (ChArUco: getChessboardCorners order; chessboard:
row-major inner corners, x fastest, from the corner next to the black top-left square;
AprilGrid: Kalibr's 4 * tag + k).

Per image, each step in its own module:

1. image_read: the file -> 8-bit grey; unreadable files are skipped and counted, flat
   (all-black/all-white) images skip detection.
2. board_detectors: every board of the target as OpenCV finds it (ChArUco by its
   markers, AprilGrid by its tags, chessboards), corners in Board.corners' order.
3. corner_refine: each corner re-estimated as the centre of point symmetry of the
   image around it (corner_fit, along the grid's local axes and bends from
   corner_grid), with its own 1-sigma error (BoardView.sigma); a corner that cannot be
   placed is left out.
4. board_detectors: views with too few or collinear corners are dropped and counted.

Here: the DetectionResult type (its views are observations.BoardView), detect_image
for one image and detect_dataset for a dataset, spread over processes (`jobs`,
forkserver workers, or a Dask cluster); each worker builds its OpenCV detectors once
from the plain Target. Output order does not depend on scheduling. detect_diagnose
says why no board showed.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from rigcal.detect.board_detectors import BoardDetector
from rigcal.detect.corner_refine import REFINE_MODES
from rigcal.data.image_read import read_gray, to_gray8
from rigcal.core.observations import BoardView
from rigcal.core.target import Target
from rigcal.core.workers import interrupts_deferred, pool


@dataclass
class DetectionResult:
    """What detect_dataset found in a dataset: the views, and per camera what was read,
    skipped or dropped (for the console summary and the calibration's warnings)."""

    views: list[BoardView]
    cameras: tuple[str, ...]
    frames: tuple[str, ...]
    image_size: dict[str, tuple[int, int]]  # per camera (w, h) as read (the first readable image)
    n_images: dict[str, int]
    unreadable: list[tuple[str, str]]  # (path, reason)
    no_board: dict[str, int]  # images read fine with no usable board
    dropped: dict[str, int]  # views dropped: too few corners or collinear
    size_mismatch: list[tuple[str, str, tuple, tuple]]  # (camera, path, got (w, h), expected (w, h))
    seconds: float
    jobs: int = 1  # worker processes actually used
    unreadable_by_camera: dict[str, int] = field(default_factory=dict)

    def views_of(self, camera: str) -> list[BoardView]:
        return [v for v in self.views if v.camera == camera]

    def summary(self) -> str:
        """A few lines for the console: per camera images, views, corners and what was skipped."""
        n = sum(self.n_images.values())
        rate = n / self.seconds if self.seconds > 0 else float("inf")
        lines = [f"detection: {n} images, {len(self.views)} board views in {self.seconds:.1f} s "
                 f"({rate:.1f} images/s, {self.jobs} process{'es' if self.jobs > 1 else ''})"]
        bad = self.unreadable_by_camera
        for cam in self.cameras:
            vs = self.views_of(cam)
            frames = len({v.frame for v in vs})
            corners = sum(len(v.ids) for v in vs)
            amb = sum(v.ambiguous for v in vs)
            extra = [f"{self.no_board.get(cam, 0)} without a board"]
            if self.dropped.get(cam, 0):
                n = self.dropped[cam]
                extra.append(f"{n} view{'s' if n != 1 else ''} dropped (too few or collinear corners)")
            if bad.get(cam):
                extra.append(f"{bad[cam]} unreadable")
            if amb:
                extra.append(f"{amb} with a 180-degree ambiguous order")
            size = self.image_size.get(cam)
            size_s = f"{size[0]}x{size[1]}" if size else "-"
            lines.append(f"  {cam}: {self.n_images.get(cam, 0)} images ({size_s}), {len(vs)} views in {frames} "
                         f"frames, {corners} corners; " + ", ".join(extra))
        for path, reason in self.unreadable:
            lines.append(f"  skipped {path}: {reason}")
        for cam, path, got, expected in self.size_mismatch:
            lines.append(f"  {path}: camera {cam}: {got[0]}x{got[1]}, rig says {expected[0]}x{expected[1]}")
        return "\n".join(lines)


def detect_image(gray: np.ndarray, target: Target, min_corners: int = 6, refine: str = "symmetric",
                 detector: BoardDetector | None = None) -> list[tuple[str, np.ndarray, np.ndarray, bool]]:
    """Boards in one grey (or colour, any depth) image: [(board name, ids, uv, ambiguous)]."""
    detector = detector or BoardDetector(target, min_corners, refine)
    return detector.detect(to_gray8(np.asarray(gray)))[0]


# ----------------------------------------------------------------------------- datasets


@dataclass
class _ImageOut:
    size: tuple[int, int] | None
    reason: str | None
    views: list
    dropped: int


_WORKER: BoardDetector | None = None


def _init_worker(target: Target, min_corners: int, refine: str) -> None:
    global _WORKER
    cv2.setNumThreads(1)  # the processes are the parallelism
    _WORKER = BoardDetector(target, min_corners, refine)


def _work(path: str) -> _ImageOut:
    gray, reason = read_gray(path)
    if gray is None:
        return _ImageOut(None, reason, [], 0)
    views, dropped = _WORKER.detect_with_sigma(gray)
    return _ImageOut((gray.shape[1], gray.shape[0]), None, views, dropped)


def _detect_serial(paths: list[str], target: Target, min_corners: int, refine: str, bar) -> list[_ImageOut]:
    global _WORKER
    keep = _WORKER
    _WORKER = BoardDetector(target, min_corners, refine)
    try:
        bar.start()
        out = []
        for p in paths:
            out.append(_work(p))
            bar.advance()
        return out
    finally:
        _WORKER = keep


def _detect_parallel(paths: list[str], target: Target, jobs: int, min_corners: int, refine: str,
                     bar, scheduler: str | None = None) -> list[_ImageOut]:
    chunk = max(1, min(8, len(paths) // (jobs * 6)))
    with pool(jobs, "rigcal.detect.detect", _init_worker, (target, min_corners, refine), scheduler) as ex:
        with interrupts_deferred():  # a worker interrupted while it starts prints a traceback
            results = ex.map(_work, paths, chunksize=chunk)  # submits all, workers start now; yields in order
        bar.start()  # after the workers started: no progress-bar thread is copied into them
        out = []
        for r in results:
            out.append(r)
            bar.advance()
    return out


class _Progress:
    """rich progress bar on stderr with counts and rate, or nothing."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, bool(enabled) and total > 0
        self.bar = None

    def start(self) -> None:
        if not self.enabled or self.bar is not None:
            return
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.bar = Progress(TextColumn("detecting"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("{task.fields[rate]}"), TimeElapsedColumn(),
                            console=Console(stderr=True), transient=False)
        self.task = self.bar.add_task("detect", total=self.total, rate="")
        self.t0, self.done = time.perf_counter(), 0
        self.bar.start()

    def advance(self) -> None:
        if self.bar is not None:
            self.done += 1
            dt = time.perf_counter() - self.t0
            self.bar.update(self.task, advance=1, rate=f"{self.done / dt:.1f} img/s" if dt > 0 else "")

    def stop(self) -> None:
        if self.bar is not None:
            self.bar.stop()


def detect_dataset(images, target: Target, rig=None, jobs: int | None = None, progress: bool = True,
                   min_corners: int = 6, refine: str = "symmetric", scheduler: str | None = None) -> DetectionResult:
    """Detect every board in every image of a dataset (dataset.DatasetImages).

    rig: when given, each image's size is checked against the camera's resolution
    (mismatches are listed in `size_mismatch`, not raised). jobs: worker processes
    (default os.cpu_count()). scheduler: a Dask scheduler's address; its workers do the
    work instead, reading the images at their absolute paths (a file system they share).
    The result is the same whatever `jobs` or `scheduler` is."""
    if refine not in REFINE_MODES:
        raise ValueError(f"refine: expected one of {', '.join(REFINE_MODES)}, got {refine!r}")
    t0 = time.perf_counter()
    jobs = max(1, int(jobs if jobs is not None else (os.cpu_count() or 1)))
    items = images.items()
    paths = [str(p) for _, _, p in items]
    bar = _Progress(len(paths), progress)
    try:
        if scheduler is not None:
            outs = _detect_parallel([os.path.abspath(p) for p in paths], target, jobs, min_corners, refine, bar,
                                    scheduler)
        elif jobs <= 1 or len(paths) < 2 * jobs:
            jobs = 1
            outs = _detect_serial(paths, target, min_corners, refine, bar)
        else:
            outs = _detect_parallel(paths, target, jobs, min_corners, refine, bar)
    finally:
        bar.stop()
    expected = {}
    if rig is not None:
        for cam in images.cameras:
            m = rig.camera(cam).intrinsics
            expected[cam] = (int(m.width), int(m.height))
    res = DetectionResult(views=[], cameras=tuple(images.cameras), frames=tuple(images.all_frames),
                          image_size={}, n_images={c: 0 for c in images.cameras}, unreadable=[],
                          no_board={c: 0 for c in images.cameras}, dropped={c: 0 for c in images.cameras},
                          size_mismatch=[], seconds=0.0, jobs=jobs)
    for (cam, frame, path), o in zip(items, outs):
        res.n_images[cam] += 1
        if o.size is None:
            res.unreadable.append((str(path), o.reason))
            res.unreadable_by_camera[cam] = res.unreadable_by_camera.get(cam, 0) + 1
            continue
        res.image_size.setdefault(cam, o.size)
        if cam in expected and o.size != expected[cam]:
            res.size_mismatch.append((cam, str(path), o.size, expected[cam]))
        res.dropped[cam] += o.dropped
        if not o.views:
            res.no_board[cam] += 1
        for name, ids, uv, amb, sigma in o.views:
            res.views.append(BoardView(cam, frame, name, ids, uv, amb, sigma))
    res.seconds = time.perf_counter() - t0
    return res
