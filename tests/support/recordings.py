"""Recordings built from a simulated dataset, in the formats `rigcal ingest` reads: EuRoC
folders, ROS 1 / ROS 2 bags (written with rosbags' own writers) and videos (PyAV).

Frames are placed at `T0_NS + i * DT_NS` (frame i of the simulated dataset, in stem order);
the IMU is a synthetic 200 Hz stream (seeded) that only needs to be copied faithfully.
Used by tests/data/test_ingest.py and bench/ingest.py.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from rigcal.core import geometry as geo

T0_NS = 1_403_715_273_262_142_976
DT_NS = 50_000_000  # 20 Hz
IMU_DT_NS = 5_000_000  # 200 Hz
EUROC_HEADER = "#timestamp [ns],filename"
IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
NOISE = {"gyroscope_noise_density": 1.6968e-04, "gyroscope_random_walk": 1.9393e-05,
         "accelerometer_noise_density": 2.0e-3, "accelerometer_random_walk": 3.0e-3}


def sim_frames(sim_dir: Path, camera: str) -> list[Path]:
    return sorted((sim_dir / "images" / camera).glob("*.png"))



def small_imu_rig(tmp: Path) -> Path:
    """rigs/drone-stereo-back-imu.yaml at 480x360 (f = 225), written to tmp/rig.yaml: renders 2x
    faster than 640x480 (at 320x240 too few boards are found)."""
    rig = Path(__file__).resolve().parents[2] / "rigs" / "drone-stereo-back-imu.yaml"
    text = rig.read_text().replace("[640, 480]", "[480, 360]").replace(
        "{fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}", "{fx: 225.0, fy: 225.0, cx: 240.0, cy: 180.0}")
    p = tmp / "rig.yaml"
    p.write_text(text)
    return p


def stamps(n: int) -> np.ndarray:
    return T0_NS + DT_NS * np.arange(n, dtype=np.int64)


def synthetic_imu(t_first: int, t_last: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_ns, gyro, accel) at 200 Hz from 0.2 s before t_first to 0.2 s after t_last; the
    accelerometer reads gravity along the IMU's +x (EuRoC's ADIS16448 is mounted x up)."""
    t = np.arange(t_first - 200_000_000, t_last + 200_000_001, IMU_DT_NS, dtype=np.int64)
    rng = np.random.default_rng(seed)
    s = (t - t[0]) / 1e9
    gyro = np.column_stack([0.3 * np.sin(2.1 * s), 0.2 * np.cos(1.3 * s), 0.1 * np.sin(0.7 * s)])
    gyro += rng.normal(0, 1e-3, gyro.shape)
    accel = np.array([9.80665, 0.0, 0.0]) + rng.normal(0, 2e-2, (len(t), 3))
    return t, gyro, accel


def imu_rows(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> str:
    lines = [IMU_HEADER] + [f"{ti}," + ",".join(repr(float(x)) for x in np.r_[g, a])
                            for ti, g, a in zip(t.tolist(), gyro, accel)]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- EuRoC


def _sensor_yaml(T_BS: np.ndarray, body: str) -> str:
    data = ", ".join(repr(float(x)) for x in T_BS.ravel())
    lines = body.splitlines()
    return (f"%YAML:1.0\n---\n# General sensor definitions.\n{lines[0]}\n{lines[1]}\n\n"
            f"# Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n  data: [{data}]\n\n"
            + "\n".join(lines[2:]) + "\n")


def write_euroc(root: Path, sim_dir: Path, rig, folders: dict[str, str], body_axes=("U", "-L", "F"),
                imu: bool = True) -> dict[str, np.ndarray]:
    """A `mav0/` folder as EuRoC ships it: folders maps sensor folder -> rig camera. T_BS is
    the declared pose with B's axes `body_axes` in FLU terms. Returns per camera its stamps."""
    T_B_flu = geo.inv_T(geo.make_T(geo.R_from_axes(list(body_axes)), np.zeros(3)))
    mav0 = root / "mav0"
    out = {}
    for folder, cam in folders.items():
        d = mav0 / folder
        (d / "data").mkdir(parents=True)
        frames = sim_frames(sim_dir, cam)
        t = stamps(len(frames))
        for ti, f in zip(t, frames):
            (d / "data" / f"{ti}.png").write_bytes(f.read_bytes())
        (d / "data.csv").write_text(EUROC_HEADER + "\n" + "".join(f"{ti},{ti}.png\n" for ti in t.tolist()))
        c = rig.camera(cam)
        m = c.intrinsics
        body = (f"sensor_type: camera\ncomment: VI-Sensor {folder} (MT9M034)\n# Camera specific definitions.\n"
                f"rate_hz: 20\nresolution: [{m.width}, {m.height}]\ncamera_model: pinhole\n"
                f"intrinsics: [{m.fx!r}, {m.fy!r}, {m.cx!r}, {m.cy!r}] #fu, fv, cu, cv\n"
                f"distortion_model: radial-tangential\n"
                f"distortion_coefficients: [{', '.join(repr(float(x)) for x in m.dist[:4])}]")
        (d / "sensor.yaml").write_text(_sensor_yaml(T_B_flu @ c.T_body_cam, body))
        out[cam] = t
    if imu:
        all_t = np.concatenate(list(out.values()))
        t, g, a = synthetic_imu(int(all_t.min()), int(all_t.max()))
        (mav0 / "imu0").mkdir()
        (mav0 / "imu0" / "data.csv").write_text(imu_rows(t, g, a))
        body = ("sensor_type: imu\ncomment: VI-Sensor IMU (ADIS16448)\nrate_hz: 200\n"
                + "\n".join(f"{k}: {v!r}" for k, v in NOISE.items()))
        (mav0 / "imu0" / "sensor.yaml").write_text(_sensor_yaml(np.eye(4), body))
    return out


# ----------------------------------------------------------------------------- bags


def _header(ts, t_ns: int, ros1: bool, frame_id: str = "cam"):
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    stamp = Time(sec=int(t_ns) // 1_000_000_000, nanosec=int(t_ns) % 1_000_000_000)
    return Header(seq=0, stamp=stamp, frame_id=frame_id) if ros1 else Header(stamp=stamp, frame_id=frame_id)


def image_msg(ts, img: np.ndarray, t_ns: int, ros1: bool, encoding: str | None = None):
    if encoding is None:
        encoding = "mono8" if img.ndim == 2 else "bgr8"
    data = img if encoding != "rgb8" else img[:, :, ::-1]
    data = np.ascontiguousarray(data)
    ch = 1 if data.ndim == 2 else data.shape[2]
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, t_ns, ros1), height=img.shape[0], width=img.shape[1], encoding=encoding,
        is_bigendian=0, step=img.shape[1] * ch * data.itemsize, data=data.view(np.uint8).ravel())


def compressed_msg(ts, img: np.ndarray, t_ns: int, ros1: bool, fmt: str = "png"):
    ok, buf = cv2.imencode("." + fmt, img)
    assert ok
    return ts.types["sensor_msgs/msg/CompressedImage"](header=_header(ts, t_ns, ros1), format=fmt,
                                                       data=buf.ravel())


def imu_msg(ts, t_ns: int, g, a, ros1: bool):
    V = ts.types["geometry_msgs/msg/Vector3"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    z9 = np.zeros(9)
    return ts.types["sensor_msgs/msg/Imu"](
        header=_header(ts, t_ns, ros1, "imu"), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=z9,
        angular_velocity=V(x=float(g[0]), y=float(g[1]), z=float(g[2])), angular_velocity_covariance=z9,
        linear_acceleration=V(x=float(a[0]), y=float(a[1]), z=float(a[2])), linear_acceleration_covariance=z9)


def mag_msg(ts, t_ns: int, b_tesla, ros1: bool):
    V = ts.types["geometry_msgs/msg/Vector3"]
    return ts.types["sensor_msgs/msg/MagneticField"](
        header=_header(ts, t_ns, ros1, "mag"), magnetic_field=V(x=float(b_tesla[0]), y=float(b_tesla[1]),
                                                                z=float(b_tesla[2])),
        magnetic_field_covariance=np.zeros(9))


def camera_info_msg(ts, m, t_ns: int, ros1: bool):
    """A CameraInfo for rigcal CameraModel m (plumb_bob: k1 k2 p1 p2 k3)."""
    K = np.array([m.fx, 0.0, m.cx, 0.0, m.fy, m.cy, 0.0, 0.0, 1.0])
    D = np.zeros(5)
    D[: len(m.dist[:5])] = m.dist[:5]
    P = np.array([m.fx, 0.0, m.cx, 0.0, 0.0, m.fy, m.cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    keys = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, t_ns, ros1), height=m.height, width=m.width, distortion_model="plumb_bob",
        binning_x=0, binning_y=0, roi=roi, **dict(zip(keys, (D, K, np.eye(3).ravel(), P))))


def write_bag(path: Path, kind: str, images: dict[str, list[tuple[int, np.ndarray]]],
              imu: tuple[np.ndarray, np.ndarray, np.ndarray] | None, compressed: bool = False,
              encoding: str | None = None, record_delay_ns: int = 3_000_000, camera_info: dict | None = None,
              mag: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """A bag (kind 'ros1', 'sqlite3' or 'mcap') with one image topic per entry of `images`
    (`/<name>/image_raw`, or `/<name>/image_raw/compressed`) and `/imu0` when imu is given.
    Record times lag the header stamps by record_delay_ns, as a real recorder's do;
    camera_info (name -> CameraModel) adds `/<name>/camera_info` with each frame; mag
    (t_ns, field in tesla (N, 3)) adds `/mag0`, sensor_msgs/MagneticField."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    msgs = []  # (record time, topic, msgtype, message)
    for name, frames in images.items():
        topic = f"/{name}/image_raw" + ("/compressed" if compressed else "")
        mtype = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
        for t, img in frames:
            msg = compressed_msg(ts, img, t, ros1) if compressed else image_msg(ts, img, t, ros1, encoding)
            msgs.append((t + record_delay_ns, topic, mtype, msg))
            if camera_info and name in camera_info:
                msgs.append((t + record_delay_ns, f"/{name}/camera_info", "sensor_msgs/msg/CameraInfo",
                             camera_info_msg(ts, camera_info[name], t, ros1)))
    if imu is not None:
        for t, g, a in zip(*imu):
            msgs.append((int(t) + record_delay_ns, "/imu0", "sensor_msgs/msg/Imu", imu_msg(ts, int(t), g, a, ros1)))
    if mag is not None:
        for t, b in zip(*mag):
            msgs.append((int(t) + record_delay_ns, "/mag0", "sensor_msgs/msg/MagneticField", mag_msg(ts, int(t), b, ros1)))
    msgs.sort(key=lambda m: m[0])
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
    with writer:
        conns = {}
        for rt, topic, mtype, msg in msgs:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, mtype, typestore=ts)
            writer.write(conns[topic], rt, serialize(msg, mtype))
    return path


# ----------------------------------------------------------------------------- video


def write_video(path: Path, frames: list[np.ndarray], fps: int = 20, codec: str = "ffv1") -> Path:
    """A video (lossless ffv1 in .mkv by default) whose frame i has pts i at time base 1/fps."""
    import av

    grey = frames[0].ndim == 2
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=fps)
        s.width, s.height = frames[0].shape[1], frames[0].shape[0]
        s.pix_fmt = "gray" if grey and codec == "ffv1" else ("bgr0" if codec == "ffv1" else "yuv420p")
        s.time_base = Fraction(1, fps)
        for i, img in enumerate(frames):
            f = av.VideoFrame.from_ndarray(img, format="gray" if grey else "bgr24")
            f.pts = i
            f.time_base = Fraction(1, fps)
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


# ----------------------------------------------------------------------------- the README's examples

SMALL_STEREO = """
rig: small-stereo
body_frame: FLU
cameras:
  left: {model: pinhole, resolution: [480, 320], intrinsics: {fx: 340.0, fy: 340.0, cx: 240.0, cy: 160.0},
         distortion: [-0.05, 0.02, 0.0, 0.0], position: [0.1, 0.05, 0.0], look: forward}
  right: {model: pinhole, resolution: [480, 320], intrinsics: {fx: 340.0, fy: 340.0, cx: 240.0, cy: 160.0},
          distortion: [-0.05, 0.02, 0.0, 0.0], position: [0.1, -0.05, 0.0], look: forward}
stereo_pairs:
  - [left, right]
"""
IMU_BLOCK = """imus:
  imu0: {position: [0.0, 0.0, 0.0], axes: [U, -L, F], update_rate: 200.0, gyroscope_noise_density: 1.7e-4,
         gyroscope_random_walk: 1.9e-5, accelerometer_noise_density: 2.0e-3, accelerometer_random_walk: 3.0e-3}
"""


def build_examples(out: Path, frames: int = 10, drop: int = 3) -> None:
    """What README's "From your recording" runs on: OUT/rig.yaml (cameras), rig_imu.yaml (and
    imu0), target.yaml, euroc_seq/, rec.bag (ROS 1, raw, IMU), rec_mcap/ (ROS 2 mcap,
    PNG-compressed, CameraInfo), videos/{left,right}.mkv (right started `drop` / 20 s later)."""
    from rigcal.core.rig import parse_rig
    from rigcal.sim.simulate import simulate_dataset

    out.mkdir(parents=True, exist_ok=True)
    rig = parse_rig(SMALL_STEREO)
    (out / "rig.yaml").write_text(SMALL_STEREO)
    (out / "rig_imu.yaml").write_text(SMALL_STEREO + IMU_BLOCK)
    sim = out / "sim"
    simulate_dataset(rig, sim, scene="board", frames=frames, noise=1.0, jobs=2, seed=5)
    (out / "target.yaml").write_text((sim / "target.yaml").read_text())
    write_euroc(out / "euroc_seq", sim, rig, {"cam0": "left", "cam1": "right"})
    imgs = {c: [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in sim_frames(sim, c)] for c in ("left", "right")}
    images = {c: list(zip(stamps(frames).tolist(), v)) for c, v in imgs.items()}
    t = stamps(frames)
    imu = synthetic_imu(int(t[0]), int(t[-1]))
    write_bag(out / "rec.bag", "ros1", images, imu)
    write_bag(out / "rec_mcap", "mcap", images, None, compressed=True,
              camera_info={c.name: c.intrinsics for c in rig.cameras})
    (out / "videos").mkdir()
    write_video(out / "videos" / "left.mkv", imgs["left"])
    write_video(out / "videos" / "right.mkv", imgs["right"][drop:])


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=build_examples.__doc__)
    ap.add_argument("--out", type=Path, required=True)
    build_examples(ap.parse_args().out)
