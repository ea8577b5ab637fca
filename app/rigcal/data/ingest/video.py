"""Video files, one per camera, through PyAV (FFmpeg's demuxers and decoders).

A frame's time is its presentation timestamp, `pts * time_base` (exact rational
arithmetic), plus the camera's --offset: cameras started at different times are
brought onto one clock by the offsets. Each frame is decoded once.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Iterator

from rigcal.errors import InputError
from rigcal.data.ingest.writer import Frame, ImuBlock

VIDEO_SUFFIXES = (".mp4", ".mkv", ".avi", ".mov", ".webm", ".m4v", ".mpg", ".mpeg", ".ts", ".nut", ".h264", ".264",
                  ".h265", ".hevc")
_GREY_FORMATS = ("gray", "gray8", "gray10le", "gray12le", "gray16le", "y8")


def is_video(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES


def _open(path: Path):
    import av

    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError) as e:
        raise InputError(f"{path}: not a readable video ({' '.join(str(e).split())})") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"{path}: holds no video stream")
    return container


def frame_time_ns(pts: int | None, time_base: Fraction | None, offset_s: Fraction, where: str) -> int:
    """pts * time_base + offset in integer nanoseconds (rounded to the nearest)."""
    if pts is None or time_base is None:
        raise InputError(f"{where}: has no timestamp (pts); rigcal takes frame times from the container and does "
                         f"not guess them from a frame rate")
    return round((Fraction(pts) * Fraction(time_base) + offset_s) * 1_000_000_000)


class VideoRecording:
    """Per camera a video file and a clock offset in seconds."""

    def __init__(self, cameras: dict[str, Path], offsets: dict[str, float]):
        self.cameras = cameras
        self.offsets = {c: Fraction(str(offsets.get(c, 0.0))) for c in cameras}
        self.imus: dict[str, Path] = {}
        self._counts = {}
        for c, path in cameras.items():
            container = _open(path)
            self._counts[c] = container.streams.video[0].frames
            container.close()

    @property
    def sources(self) -> tuple[dict[str, str], dict[str, str]]:
        return {c: str(p) for c, p in self.cameras.items()}, {}

    def total_frames(self) -> int | None:
        n = sum(self._counts.values())
        return n or None

    def first_stamp_ns(self) -> int:
        """The earliest first-frame time over the cameras (demuxed, not decoded)."""
        firsts = []
        for c, path in self.cameras.items():
            container = _open(path)
            try:
                stream = container.streams.video[0]
                pts = next((p.pts for p in container.demux(stream) if p.pts is not None), None)
                firsts.append(frame_time_ns(pts, stream.time_base, self.offsets[c], str(path)))
            finally:
                container.close()
        return min(firsts)

    def items(self) -> Iterator[tuple[str, str, Frame | ImuBlock]]:
        import av

        for c, path in self.cameras.items():
            container = _open(path)
            try:
                stream = container.streams.video[0]
                fmt = "gray" if (stream.codec_context.pix_fmt or "") in _GREY_FORMATS else "bgr24"
                for i, frame in enumerate(container.decode(stream)):
                    where = f"{path}: frame {i + 1}"
                    t = frame_time_ns(frame.pts, frame.time_base or stream.time_base, self.offsets[c], where)
                    yield "camera", c, Frame(t_ns=t, where=where, pixels=frame.to_ndarray(format=fmt))
            except av.error.FFmpegError as e:
                raise InputError(f"{path}: cannot decode ({' '.join(str(e).split())})") from None
            finally:
                container.close()
