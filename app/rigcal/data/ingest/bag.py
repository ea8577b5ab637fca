"""ROS 1 `.bag` and ROS 2 bags (sqlite3, mcap) through `rosbags` (pure Python, no ROS).

Images are `sensor_msgs/Image` (encodings of images.ENCODINGS) or `CompressedImage`
(png or jpeg bytes, written as they are); IMU samples are `sensor_msgs/Imu`; magnetometer
readings are `sensor_msgs/MagneticField` (tesla, converted to microtesla for mag/<name>.csv; the
raw readings the driver published, in the chip's axes). Times are the messages' header stamps
(the capture time the driver set), never the record times.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from rigcal.errors import InputError
from rigcal.data.ingest.images import EncodingError, compressed_suffix, decode, raw_pixels
from rigcal.data.ingest.writer import Frame, ImuBlock, MagBlock

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
IMU_TYPE = "sensor_msgs/msg/Imu"
MAG_TYPE = "sensor_msgs/msg/MagneticField"
TESLA_TO_UT = 1e6
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
# CameraInfo distortion models -> rigcal camera model and the number of coefficients kept
_INFO_MODELS = {"plumb_bob": ("pinhole", 5), "rational_polynomial": ("pinhole", 8), "equidistant": ("fisheye", 4)}
BAG_SUFFIXES = (".bag", ".db3", ".mcap")


def is_bag(source: Path) -> bool:
    return (source.is_file() and source.suffix.lower() in BAG_SUFFIXES) or (source / "metadata.yaml").is_file()


def _bag_path(source: Path) -> Path:
    """rosbags opens a ROS 2 bag by its folder; a .db3/.mcap file given alone means its folder."""
    if source.is_file() and source.suffix.lower() in (".db3", ".mcap") and (source.parent / "metadata.yaml").is_file():
        return source.parent
    return source


@contextlib.contextmanager
def open_bag(source: Path):
    """An opened rosbags AnyReader, or InputError naming the file (not a bag, truncated...)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([_bag_path(source)], default_typestore=get_typestore(Stores.LATEST))
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as e:
        raise InputError(f"{source}: not a readable ROS bag ({' '.join(str(e).split()) or e.__class__.__name__})"
                         ) from None
    try:
        yield reader
    finally:
        reader.close()


@dataclass(frozen=True)
class TopicInfo:
    """One image, IMU or magnetometer topic of a bag: its message type, message count and mean
    rate (Hz)."""

    topic: str
    msgtype: str
    count: int
    rate_hz: float


def topics(reader, rates: bool = True) -> list[TopicInfo]:
    """Image, IMU and magnetometer topics with their message counts, and (rates=True) each
    topic's mean rate between its first and last record time (one pass over those topics'
    messages, undecoded)."""
    infos = {t: i for t, i in sorted(reader.topics.items()) if i.msgtype in IMAGE_TYPES + (IMU_TYPE, MAG_TYPE)}
    span: dict[str, list[int]] = {}
    if rates and infos:
        conns = [c for c in reader.connections if c.topic in infos]
        for conn, t, _ in reader.messages(connections=conns):
            s = span.setdefault(conn.topic, [t, t])
            s[0], s[1] = min(s[0], t), max(s[1], t)
    rows = []
    for topic, info in infos.items():
        lo, hi = span.get(topic, (0, 0))
        n = info.msgcount
        rows.append(TopicInfo(topic, info.msgtype, n, (n - 1) / ((hi - lo) / 1e9) if n > 1 and hi > lo else 0.0))
    return rows


def topic_table(source: Path, rows: list[TopicInfo]) -> str:
    if not rows:
        return f"{source}: no sensor_msgs/Image, CompressedImage, Imu or MagneticField topic"
    w = max(len(r.topic) for r in rows)
    lines = [f"{source}: image, IMU and magnetometer topics (choose with --camera NAME=TOPIC, --imu NAME=TOPIC, "
             f"--mag NAME=TOPIC):"]
    lines += [f"  {r.topic:<{w}}  {r.msgtype.split('/')[-1]:<15} {r.count:>7} msgs  {r.rate_hz:7.1f} Hz" for r in rows]
    return "\n".join(lines)


def _connections(reader, source: Path, chosen: dict[str, str], types: tuple[str, ...]) -> dict[str, list]:
    by_topic: dict[str, list] = {}
    for c in reader.connections:
        by_topic.setdefault(c.topic, []).append(c)
    out = {}
    for name, topic in chosen.items():
        conns = by_topic.get(topic)
        if not conns:
            listed = ", ".join(f"{r.topic} ({r.msgtype.split('/')[-1]})" for r in topics(reader, rates=False))
            raise InputError(f"{source}: no topic {topic!r} for {name} (image, IMU and magnetometer topics: "
                             f"{listed or 'none'})")
        if conns[0].msgtype not in types:
            raise InputError(f"{source}: topic {topic} is {conns[0].msgtype}, expected {' or '.join(types)}")
        out[name] = conns
    return out


class BagRecording:
    """The chosen topics of an opened bag, read in one pass."""

    def __init__(self, reader, source: Path, cameras: dict[str, str], imus: dict[str, str],
                 mags: dict[str, str] | None = None):
        self.reader, self.source = reader, source
        self.cameras = _connections(reader, source, cameras, IMAGE_TYPES)
        self.imus = _connections(reader, source, imus, (IMU_TYPE,))
        self.mags = _connections(reader, source, mags or {}, (MAG_TYPE,))
        self.topic_of = {**cameras, **imus, **(mags or {})}

    @property
    def sources(self) -> tuple[dict[str, str], dict[str, str]]:
        return ({c: f"{self.source}:{self.topic_of[c]}" for c in self.cameras},
                {n: f"{self.source}:{self.topic_of[n]}" for n in self.imus})

    @property
    def mag_sources(self) -> dict[str, str]:
        return {n: f"{self.source}:{self.topic_of[n]}" for n in self.mags}

    def total_frames(self) -> int:
        return sum(c.msgcount for conns in self.cameras.values() for c in conns)

    def first_stamp_ns(self) -> int:
        """The earliest header stamp among the first message of each camera topic (of each IMU
        and magnetometer topic for a recording without cameras: a compass dance)."""
        firsts = []
        streams = self.cameras or {**self.imus, **self.mags}
        for name, conns in streams.items():
            for conn, _, raw in self.reader.messages(connections=conns):
                firsts.append(_stamp(self.reader.deserialize(raw, conn.msgtype), conn.topic, 1))
                break
        if not firsts:
            what = "camera" if self.cameras else "IMU and magnetometer"
            raise InputError(f"{self.source}: the chosen {what} topics hold no message")
        return min(firsts)

    def items(self) -> Iterator[tuple[str, str, Frame | ImuBlock]]:
        name_of = {id(c): ("camera", n) for n, cs in self.cameras.items() for c in cs}
        name_of.update({id(c): ("imu", n) for n, cs in self.imus.items() for c in cs})
        name_of.update({id(c): ("mag", n) for n, cs in self.mags.items() for c in cs})
        conns = [c for cs in [*self.cameras.values(), *self.imus.values(), *self.mags.values()] for c in cs]
        index = {id(c): 0 for c in conns}
        try:
            for conn, _, raw in self.reader.messages(connections=conns):
                index[id(conn)] += 1
                kind, name = name_of[id(conn)]
                where = f"{self.source}: topic {conn.topic}, message {index[id(conn)]}"
                msg = self.reader.deserialize(raw, conn.msgtype)
                t = _stamp(msg, conn.topic, index[id(conn)])
                if kind == "imu":
                    yield kind, name, _imu_block(msg, t)
                elif kind == "mag":
                    yield kind, name, _mag_block(msg, t)
                else:
                    yield kind, name, _frame(msg, conn.msgtype, t, where)
        except InputError:
            raise
        except Exception as e:  # rosbags' reader errors on a truncated or corrupt bag
            if e.__class__.__module__.startswith("rosbags"):
                raise InputError(f"{self.source}: cannot read the bag ({' '.join(str(e).split())})") from None
            raise


def info_topic(image_topic: str) -> str:
    """The CameraInfo topic beside an image topic (image_transport's layout):
    /cam0/image_raw and /cam0/image_raw/compressed -> /cam0/camera_info."""
    base = image_topic[: -len("/compressed")] if image_topic.endswith("/compressed") else image_topic
    return base.rsplit("/", 1)[0] + "/camera_info"


def declared_cameras(reader, cameras: dict[str, str]) -> tuple[dict | None, str]:
    """(rig `cameras` mapping from each camera's first CameraInfo, or None; why not). The
    poses are left out: a CameraInfo does not say where the camera sits on the body."""
    conns = {c.topic: c for c in reader.connections if c.msgtype == INFO_TYPE}
    out = {}
    for name, topic in cameras.items():
        conn = conns.get(info_topic(topic))
        if conn is None:
            return None, f"no {info_topic(topic)} (CameraInfo) for {name}"
        msg = next((reader.deserialize(raw, conn.msgtype) for _, _, raw in reader.messages(connections=[conn])), None)
        entry = _camera_from_info(msg) if msg is not None else None
        if entry is None:
            model = getattr(msg, "distortion_model", "?")
            return None, f"{conn.topic}: distortion model {model!r} or its K/D cannot be used"
        out[name] = entry
    return out, ""


def _camera_from_info(msg) -> dict | None:
    K = np.asarray(getattr(msg, "k", getattr(msg, "K", None)), np.float64).ravel()
    D = np.asarray(getattr(msg, "d", getattr(msg, "D", [])), np.float64).ravel()
    model = _INFO_MODELS.get(str(msg.distortion_model).lower())
    if model is None or K.size != 9 or K[0] <= 0 or K[4] <= 0 or not np.isfinite(D).all():
        return None
    kind, n = model
    dist = np.zeros(n)
    dist[: min(n, D.size)] = D[:n]
    if kind == "pinhole" and n == 5 and dist[4] == 0.0:
        dist = dist[:4]  # plumb_bob with k3 = 0 is radtan4
    return {"model": kind, "resolution": [int(msg.width), int(msg.height)],
            "intrinsics": {"fx": float(K[0]), "fy": float(K[4]), "cx": float(K[2]), "cy": float(K[5])},
            "distortion": [float(x) for x in dist]}


def _stamp(msg, topic: str, index: int) -> int:
    s = msg.header.stamp
    t = int(s.sec) * 1_000_000_000 + int(s.nanosec)
    if t == 0:
        raise InputError(f"topic {topic}, message {index}: header stamp is 0 (not set by the driver); rigcal uses "
                         f"header stamps, not record times")
    return t


def _frame(msg, msgtype: str, t: int, where: str) -> Frame:
    try:
        if msgtype.endswith("CompressedImage"):
            data = bytes(msg.data)
            suffix = compressed_suffix(data)
            if suffix is None:
                raise EncodingError(f"compressed format {msg.format!r} is not png or jpeg")
            decode(data)  # a frame that does not decode is bad input now, not a detection failure later
            return Frame(t_ns=t, where=where, encoded=data, suffix=suffix)
        return Frame(t_ns=t, where=where, pixels=raw_pixels(msg.encoding, int(msg.height), int(msg.width),
                                                            int(msg.step), bool(msg.is_bigendian), msg.data))
    except EncodingError as e:
        raise InputError(f"{where}: {e}") from None


def _imu_block(msg, t: int) -> ImuBlock:
    w, a = msg.angular_velocity, msg.linear_acceleration
    return ImuBlock(np.array([t], np.int64), np.array([[w.x, w.y, w.z]], np.float64),
                    np.array([[a.x, a.y, a.z]], np.float64))


def _mag_block(msg, t: int) -> MagBlock:
    f = msg.magnetic_field
    return MagBlock(np.array([t], np.int64), np.array([[f.x, f.y, f.z]], np.float64) * TESLA_TO_UT)
