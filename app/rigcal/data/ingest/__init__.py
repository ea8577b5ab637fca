"""`rigcal ingest`: a recording (EuRoC folder, ROS 1/2 bag, video files) -> a dataset folder.

The dataset is the documented layout (docs/formats.md#dataset, #motion-datasets):
`images/<camera>/<t_ns>.<ext>` named by integer-nanosecond capture times, `imu/<imu>.csv` in EuRoC's format,
`mag/<mag>.csv` (docs/magnetometer.md; from a bag's MagneticField topics), and rig.yaml /
target.yaml when known. The source is only read; the dataset is built in a temporary
folder and renamed into place at the end, so it is whole or absent.

One module per source kind (euroc, bag, video); each gives a recording with `items()`
yielding ("camera", name, Frame) and ("imu", name, ImuBlock) in one pass, which
`writer.DatasetWriter` turns into files.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from rigcal.errors import InputError
from rigcal.core.io import atomic_dir
from rigcal.core.rig import NAME_RE, rig_file, rig_from_dict
from rigcal.data.ingest import euroc
from rigcal.data.ingest.bag import BagRecording, declared_cameras, is_bag, open_bag, topic_table, topics
from rigcal.data.ingest.video import VIDEO_SUFFIXES, VideoRecording, is_video
from rigcal.data.ingest.writer import CameraCounts, DatasetWriter, ImuCounts, Window


class TopicListing(InputError):
    """No --camera for a bag or a folder of videos: the listing is the message (exit 2)."""


@dataclass(frozen=True)
class IngestOptions:
    """What to take from the source and how (the command's options, parsed)."""

    cameras: dict[str, str]
    imus: dict[str, str]
    offsets: dict[str, float]
    rate_hz: float | None = None
    start_s: float | None = None
    end_s: float | None = None
    body_axes: tuple[str, str, str] = euroc.EUROC_BODY_AXES
    link: bool = True
    mags: dict[str, str] = field(default_factory=dict)  # --mag NAME=TOPIC (bags)


@dataclass(frozen=True)
class IngestResult:
    """What `rigcal ingest` wrote: the dataset folder, the source kind, per camera and IMU the
    counts read, written and skipped, where rig.yaml and target.yaml came from, and warnings."""

    out_dir: Path
    kind: str
    cameras: dict[str, CameraCounts]
    imus: dict[str, ImuCounts]
    rig_from: str | None
    target_from: str | None
    seconds: float
    warnings: tuple[str, ...]
    mags: dict[str, ImuCounts] = field(default_factory=dict)


def parse_pairs(values: list[str] | None, option: str, numeric: bool = False) -> dict:
    """['left=/cam0/image_raw', ...] -> {'left': '/cam0/image_raw'}; names are rig names."""
    out: dict = {}
    for v in values or []:
        name, sep, value = v.partition("=")
        name = name.strip()
        if not sep or not value.strip():
            raise InputError(f"{option} {v!r}: expected NAME=VALUE")
        if not NAME_RE.match(name):
            raise InputError(f"{option} {v!r}: {name!r} is not a rig name ([a-z0-9_]+)")
        if name in out:
            raise InputError(f"{option}: {name} given twice")
        if numeric:
            try:
                out[name] = float(value)
            except ValueError:
                raise InputError(f"{option} {v!r}: expected a number of seconds after '='") from None
        else:
            out[name] = value.strip()
    return out


def check_options(opts: IngestOptions) -> None:
    if opts.rate_hz is not None and not opts.rate_hz > 0:
        raise InputError(f"--rate: expected a positive frame rate in Hz, got {opts.rate_hz}")
    if opts.start_s is not None and opts.end_s is not None and opts.end_s <= opts.start_s:
        raise InputError(f"--end {opts.end_s}: must be after --start {opts.start_s}")
    unknown = sorted(set(opts.offsets) - set(opts.cameras)) if opts.cameras else []
    if unknown:
        raise InputError(f"--offset {unknown[0]}: not a camera given with --camera ({', '.join(opts.cameras)})")


def open_recording(source: Path, opts: IngestOptions, stack):
    """(kind, recording) for SOURCE; `stack` (an ExitStack) keeps a bag open."""
    if not source.exists():
        raise InputError(f"{source}: does not exist")
    mav0 = euroc.find_mav0(source) if source.is_dir() else None
    if opts.mags and not is_bag(source):
        raise InputError(f"--mag: only for ROS bags (sensor_msgs/MagneticField topics); {source} is not one")
    if opts.offsets and (mav0 is not None or is_bag(source)):
        raise InputError("--offset: only for video files (a bag's or EuRoC folder's header stamps are the capture "
                         "times)")
    if mav0 is not None:
        return "euroc", euroc.open_euroc(mav0, opts.cameras, opts.imus)
    if is_bag(source):
        reader = stack.enter_context(open_bag(source))
        if not opts.cameras and not (opts.imus and opts.mags):  # IMU + magnetometer alone: a compass dance
            raise TopicListing(topic_table(source, topics(reader)) + "\nnothing written: name the cameras with --camera "
                               "(or the IMU and magnetometer with --imu and --mag)")
        return "bag", BagRecording(reader, source, opts.cameras, opts.imus, opts.mags)
    if is_video(source) or source.is_dir():
        return "video", VideoRecording(_video_files(source, opts.cameras), opts.offsets)
    if source.suffix.lower() in (".bag", ".db3", ".mcap"):
        raise InputError(f"{source}: not a readable ROS bag")
    raise InputError(f"{source}: not a EuRoC folder (mav0/<sensor>/sensor.yaml + data.csv), a ROS bag (.bag, "
                     f"ROS 2 bag folder, .db3, .mcap) or a video file")


def _video_files(source: Path, cameras: dict[str, str]) -> dict[str, Path]:
    if is_video(source) and not cameras:
        name = "".join(ch if ch.isalnum() else "_" for ch in source.stem.lower())
        return {name: source}
    base = source if source.is_dir() else source.parent
    if not cameras:
        found = sorted(p.name for p in base.iterdir() if is_video(p))
        raise TopicListing(f"{base}: video files: {', '.join(found) or 'none'}\nnothing written: name one file per "
                           f"camera with --camera NAME=FILE")
    files = {}
    for name, f in cameras.items():
        p = Path(f) if Path(f).is_absolute() else base / f
        if not is_video(p):
            raise InputError(f"--camera {name}={f}: {p} is not a video file ({', '.join(VIDEO_SUFFIXES)})")
        files[name] = p
    return files


def ingest(source: str | Path, out_dir: str | Path, opts: IngestOptions, rig_path: Path | None = None,
           target_path: Path | None = None, force: bool = False, progress: bool = False) -> IngestResult:
    """Read SOURCE and write the dataset at out_dir, whole or not at all."""
    t_start = time.perf_counter()
    check_options(opts)
    source, out_dir = Path(source), Path(out_dir)
    _check_out(source, out_dir, force)
    rig_text = _read_text(rig_file(rig_path) if rig_path is not None else None, "--rig")  # or a shipped rig's name
    target_text = _read_text(target_path, "--target")
    warnings: list[str] = []
    with contextlib.ExitStack() as stack:
        kind, rec = open_recording(source, opts, stack)
        cam_src, imu_src = rec.sources
        rig_from, rig_doc = None, None
        if rig_text is not None:
            rig_from, rig_doc = str(rig_path), _rig_doc(rig_text, rig_path)
        elif kind == "euroc":
            rig_from, rig_doc = "sensor.yaml files", euroc.declared_rig(rec, opts.body_axes, name=_rig_name(source))
        elif kind == "bag":
            rig_from, rig_doc = _rig_from_camera_info(rec, source)
        if rig_text is None and rig_doc is not None:
            rig_text = _dump(rig_doc)
        mag_src = rec.mag_sources if kind == "bag" else {}
        if rig_doc is not None:
            _check_rig_names(rig_doc, list(cam_src), list(imu_src), str(rig_path or "the declared rig"), list(mag_src))
        window = Window(rec.first_stamp_ns(), opts.start_s, opts.end_s)
        with atomic_dir(out_dir, force=force) as tmp:
            writer = DatasetWriter(tmp, cam_src, imu_src, window, opts.rate_hz, opts.link, mags=mag_src)
            try:
                _copy(rec, writer, progress, warnings, rig_doc if kind == "euroc" and rig_path is None else None)
                writer.finish()
            finally:
                writer.close()
            _check_written(writer)
            if rig_text is not None:
                (tmp / "rig.yaml").write_text(rig_text, encoding="utf-8")
            if target_text is not None:
                (tmp / "target.yaml").write_text(target_text, encoding="utf-8")
    warnings += _stamp_warnings(writer)
    if opts.rate_hz is not None and writer.imus:
        warnings.append("warning: --rate with an IMU: the camera-IMU terms want every frame; thinned frames weaken "
                        "the time offset and rotation estimates")
    return IngestResult(out_dir, kind, writer.cameras, writer.imus, rig_from,
                        str(target_path) if target_path else None, time.perf_counter() - t_start, tuple(warnings),
                        writer.mags)


def _copy(rec, writer: DatasetWriter, progress: bool, warnings: list[str], euroc_rig: dict | None) -> None:
    bar = _Progress(rec.total_frames()) if progress else None
    try:
        for kind, name, item in rec.items():
            if kind == "camera":
                writer.add_frame(name, item)
                if bar:
                    bar.advance()
            elif kind == "mag":
                writer.add_mag(name, item)
            else:
                writer.add_imu(name, item)
                if euroc_rig is not None and name in euroc_rig.get("imus", {}):
                    w = euroc.gravity_warning(item, euroc_rig["imus"][name], name)
                    warnings += [w] if w else []
    finally:
        if bar:
            bar.close()


def _rig_from_camera_info(rec: BagRecording, source: Path) -> tuple[str, dict | None]:
    """A rig of intrinsics only (no poses: calibrate finds them, the first camera being the
    body frame) from the bag's CameraInfo topics; none when a camera lacks one, or with an
    IMU (its noise figures are not in the bag)."""
    if rec.imus or rec.mags:
        return "not written: the bag does not give the IMU's or magnetometer's noise figures (pass --rig)", None
    cams, why = declared_cameras(rec.reader, {c: rec.topic_of[c] for c in rec.cameras})
    if cams is None:
        return f"not written: {why} (pass --rig)", None
    return "CameraInfo topics (intrinsics only, no poses)", {"rig": _rig_name(source), "body_frame": "FLU",
                                                             "cameras": cams}


def _rig_name(source: Path) -> str:
    """The recording's name: its folder's (MH_01_easy for MH_01_easy/mav0) or file's stem."""
    path = source.resolve()
    if path.is_file():
        return path.stem
    return (path.parent if path.name == "mav0" else path).name or "recording"


def _check_out(source: Path, out_dir: Path, force: bool) -> None:
    src, out = source.resolve(), out_dir.resolve()
    if out == src or src in out.parents or out in src.parents:
        raise InputError(f"--out {out_dir}: overlaps the source {source}; ingest never writes into its source")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not force:
        raise InputError(f"--out {out_dir}: exists and is not empty (use --force to replace it)")


def _read_text(path: Path | None, option: str) -> str | None:
    if path is None:
        return None
    try:
        return Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{option} {path}: cannot read ({getattr(e, 'strerror', None) or e})") from None


def _rig_doc(text: str, path) -> dict:
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise InputError(f"{path}: not valid YAML ({' '.join(str(e).split())})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("cameras"), dict):
        raise InputError(f"{path}: expected a rig with `cameras` (docs/formats.md#rig-yaml)")
    return doc


def _check_rig_names(doc: dict, cameras: list[str], imus: list[str], label: str, mags: list[str] = ()) -> None:
    rig_from_dict(doc, label)  # the whole rig, imus included, as calibrate will read it
    hints = {"cameras": "choose and name the cameras with --camera NAME=...",
             "imus": "declare each IMU under `imus:` (docs/formats.md#imus) or leave out --imu",
             "magnetometers": "declare each magnetometer under `magnetometers:` (docs/magnetometer.md) or leave out "
                              "--mag"}
    for what, declared, got in (("cameras", list(doc["cameras"]), cameras),
                                ("imus", list(doc.get("imus") or {}), imus),
                                ("magnetometers", list(doc.get("magnetometers") or {}), list(mags))):
        if not got and (what != "cameras" or mags):  # no --imu / --mag; no --camera for a compass dance
            continue
        if sorted(declared) != sorted(got):
            hint = hints[what]
            raise InputError(f"{label}: {what}: declares {', '.join(declared) or 'none'} but the recording gives "
                             f"{', '.join(got) or 'none'} ({hint})")


def _check_written(writer: DatasetWriter) -> None:
    for c, n in writer.cameras.items():
        if n.written == 0:
            why = f"all {n.read} outside --start/--end" if n.outside == n.read else f"{n.read} read"
            raise InputError(f"{n.source}: no frame to write for {c} ({why})")


def _stamp_warnings(writer: DatasetWriter) -> list[str]:
    out = []
    for name, n in {**writer.cameras, **writer.imus, **writer.mags}.items():
        if n.duplicated or n.backwards:
            out.append(f"warning: {n.source}: {n.duplicated} duplicated and {n.backwards} backwards stamps dropped "
                       f"(the first of each kept)")
    return out


def _dump(doc: dict) -> str:
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)


class _Progress:
    """A rich progress bar on stderr: frames done, total, frames per second."""

    def __init__(self, total: int | None):
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self._p = Progress(TextColumn("ingesting"), BarColumn(), MofNCompleteColumn(),
                           TextColumn("{task.fields[rate]}"), TimeElapsedColumn(),
                           console=Console(stderr=True), transient=True)
        self._p.start()
        self._task = self._p.add_task("ingest", total=total, rate="")
        self._t0 = time.perf_counter()
        self._n = 0

    def advance(self) -> None:
        self._n += 1
        rate = self._n / max(time.perf_counter() - self._t0, 1e-9)
        self._p.update(self._task, advance=1, rate=f"{rate:.0f} frames/s")

    def close(self) -> None:
        self._p.stop()


# ----------------------------------------------------------------------------- the command


def run(source, out_dir, *, rig_path=None, target_path=None, cameras=None, imus=None, rate=None, start=None,
        end=None, offsets=None, body_axes=None, copy=False, force=False, mags=None) -> str:
    """`rigcal ingest`: returns the summary for stdout; warnings go to stderr."""
    opts = IngestOptions(cameras=parse_pairs(cameras, "--camera"), imus=parse_pairs(imus, "--imu"),
                         mags=parse_pairs(mags, "--mag"),
                         offsets=parse_pairs(offsets, "--offset", numeric=True), rate_hz=rate, start_s=start,
                         end_s=end, body_axes=tuple(body_axes) if body_axes else euroc.EUROC_BODY_AXES,
                         link=not copy)
    res = ingest(source, out_dir, opts, rig_path=rig_path, target_path=target_path, force=force,
                 progress=sys.stderr.isatty())
    for w in res.warnings:
        print(w, file=sys.stderr)
    return summary(res)


def summary(res: IngestResult) -> str:
    lines = [f"wrote {res.out_dir} from a {res.kind} recording in {res.seconds:.1f} s"]
    for c, n in res.cameras.items():
        span = ((n.last_ns or 0) - (n.first_ns or 0)) / 1e9
        rate = (n.kept - 1) / span if span > 0 and n.kept > 1 else 0.0
        dropped = [f"{k} {v}" for k, v in (("outside window", n.outside), ("duplicated", n.duplicated),
                                           ("backwards", n.backwards), ("thinned", n.thinned)) if v]
        lines.append(f"  images/{c}/: {n.kept} of {n.read} frames from {n.source}, {span:.1f} s, ~{rate:.1f} Hz"
                     + (f" (dropped: {', '.join(dropped)})" if dropped else ""))
    for folder, counts in (("imu", res.imus), ("mag", res.mags)):
        for name, n in counts.items():
            span = ((n.last_ns or 0) - (n.first_ns or 0)) / 1e9
            lines.append(f"  {folder}/{name}.csv: {n.written} of {n.read} samples from {n.source}, {span:.1f} s, "
                         f"~{(n.written - 1) / span if span > 0 else 0.0:.1f} Hz")
    rig = res.rig_from or "not written (pass --rig)"
    lines.append(f"  rig.yaml: {rig if rig.startswith('not written') else 'from ' + rig}")
    lines.append(f"  target.yaml: {'from ' + res.target_from if res.target_from else 'not written (pass --target)'}")
    return "\n".join(lines)
