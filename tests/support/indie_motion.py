"""An independent camera + IMU motion recording: a check of rigcal's camera-IMU calibration
that shares no code with rigcal.

rigcal's own camera-IMU benchmarks record with rigcal.sim (its spline trajectory, its IMU
model, its renderer), so a convention error shared by simulator and estimator would cancel
out. This module imports nothing from rigcal; it builds the recording from the contracts
alone (../shared/spec/imu.md, dataset.md, rig-yaml.md) and renders with
tests/support/indie_render.py's ray caster (itself rigcal-free):

* World ENU, gravity g_world = [0, 0, -9.80665]; body FLU; `T_a_b` maps points of b to a.
* Trajectory: closed-form, not a spline. Position (room frame) and yaw / pitch / roll
  (R_room_body = Rz(yaw) Ry(pitch) Rx(roll)) are each a sum of three sinusoids with random
  amplitudes, frequencies and phases, hand-held-like (about 0.5-1.5 rad/s, 1-3 m/s^2). The
  room frame is the world turned by a random heading and shifted, so the body never faces
  east at rest. Velocity, acceleration, body angular rate and its derivative are exact
  derivatives (`Motion`).
* IMU: mounted off the body origin with a rotation that is not axis-aligned (the rig
  declares it exactly: with an IMU in the rig the IMU defines the body frame). At a rate
  rigcal's simulator does not use (400 Hz by default) it reads, instantaneously at its
  timestamp,
      gyroscope     w_imu = R_body_imu^T w_body                         (+ bias + noise)
      accelerometer f_imu = R_world_imu^T (a_world(imu origin) - g_world) (+ bias + noise)
  with a_world of the IMU's origin including the lever-arm terms (w_dot x r + w x (w x r)).
  White noise at the declared densities (sigma = density / sqrt(dt)) and biases that start
  at a random constant and random-walk at the declared densities. The IMU clock is the
  trajectory's clock.
* Cameras: free-running global-shutter pinhole cameras (radtan distortion), each on its own
  clock phase and rate (20, 30 and 15 Hz by default), a frame period off nominal by up to
  2e-4, +-0.2 ms capture jitter, about 3 % of frames dropped, one camera starting late and
  one stopping early. Each camera has a true clock offset (a few ms, its own sign):
  imu.md's `t_imu = t_cam + time_offset_s`, so an image stamped t_cam is rendered at the
  trajectory's time t_cam + time_offset_s. Stems are integer nanoseconds of the camera clock.
* Boards: static ChArUco boards (disjoint id ranges) on the front and back walls, each
  tilted at random about its centre. Nothing keeps two sheets apart: in some seeds two
  pass through each other (not physical), in others one hangs partly in front of another
  (seed 7: the corners at its edge bias the front cameras' intrinsics; see
  docs/camera-imu-free-running.md).

Truth goes to truth.yaml (dataset.md + imu.md additions: the true rig with time_offset_s,
the IMU's pose, biases sampled at 10 Hz, gravity_world, boards, frames) and
truth_trajectory.csv (T_world_body at the IMU rate, IMU clock, full double precision).

    rec = recording(seed=0, duration=12.0)
    truth = write_recording(rec, out_dir)            # render=False: IMU, rig, target, truth only
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from tests.support import indie_render as ir

G = 9.80665
G_WORLD = np.array([0.0, 0.0, -G])
T0_NS = 1_700_000_000_000_000_000  # epoch of both clocks' stems (ns); internal times are relative seconds
IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
NOISE = {"gyroscope_noise_density": 1.2e-4, "gyroscope_random_walk": 2.0e-5,
         "accelerometer_noise_density": 1.6e-3, "accelerometer_random_walk": 2.5e-3}


# ----------------------------------------------------------------------------- motion


@dataclass(frozen=True)
class Sines:
    """x(t) = sum_j a_j sin(2 pi f_j t + p_j), per channel: a, f, p are (C, J)."""

    a: np.ndarray
    f: np.ndarray
    p: np.ndarray

    def __call__(self, t: float, order: int = 0) -> np.ndarray:
        """The order-th time derivative (C,) at t (seconds)."""
        w = 2 * np.pi * self.f
        ph = w * t + self.p + order * np.pi / 2  # d/dt sin(x) = sin(x + pi/2)
        return np.sum(self.a * w ** order * np.sin(ph), axis=1)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


@dataclass(frozen=True)
class Motion:
    """T_world_body(t) = T_world_room @ (Rz(yaw) Ry(pitch) Rx(roll), p_room(t))."""

    T_world_room: np.ndarray
    position: Sines  # room-frame position, metres, channels x y z
    angles: Sines    # roll, pitch, yaw, radians

    def T_world_body(self, t: float) -> np.ndarray:
        r, p, y = self.angles(t)
        R = self.T_world_room[:3, :3] @ _rz(y) @ _ry(p) @ _rx(r)
        return ir.pose(R, self.T_world_room[:3, :3] @ self.position(t) + self.T_world_room[:3, 3])

    def acc_world(self, t: float) -> np.ndarray:
        """Acceleration of the body origin (3,), world frame, m/s^2."""
        return self.T_world_room[:3, :3] @ self.position(t, 2)

    def omega_body(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Angular velocity (3,) of the body in body axes (R^T dR/dt = [w]x) and its time
        derivative (3,): w = Rx^T Ry^T e_z yaw' + Rx^T e_y pitch' + e_x roll'."""
        r, p, _ = self.angles(t)
        dr, dp, dy = self.angles(t, 1)
        ddr, ddp, ddy = self.angles(t, 2)
        cr, sr, cp, sp = np.cos(r), np.sin(r), np.cos(p), np.sin(p)
        w = np.array([dr - dy * sp, dp * cr + dy * cp * sr, -dp * sr + dy * cp * cr])
        wd = np.array([ddr - ddy * sp - dy * dp * cp,
                       ddp * cr - dp * dr * sr + ddy * cp * sr - dy * dp * sp * sr + dy * dr * cp * cr,
                       -ddp * sr - dp * dr * cr + ddy * cp * cr - dy * dp * sp * cr - dy * dr * cp * sr])
        return w, wd


def motion(seed: int) -> Motion:
    """Hand-held-like motion in front of the walls: three sinusoids per channel, the slowest
    carrying most of the amplitude (the boards stay in view), the fastest the excitation."""
    rng = np.random.default_rng(seed + 35_000)
    f = np.array([[0.2, 0.4], [0.6, 1.0], [1.2, 1.8]])  # Hz, per term
    freq = lambda n: rng.uniform(f[:, 0], f[:, 1], (n, 3))  # noqa: E731
    phase = lambda n: rng.uniform(0, 2 * np.pi, (n, 3))  # noqa: E731
    pos = Sines(rng.uniform(0.6, 1.0, (3, 1)) * np.array([[0.10, 0.04, 0.015]]) * [[1.0], [1.2], [0.8]],
                freq(3), phase(3))
    ang = Sines(rng.uniform(0.7, 1.0, (3, 1)) * np.array([[0.15, 0.07, 0.03]]) * [[1.0], [1.0], [2.0]],
                freq(3), phase(3))
    heading = rng.uniform(-np.pi, np.pi)
    return Motion(ir.pose(_rz(heading), [2.0, -1.0, 1.5] + rng.uniform(-0.5, 0.5, 3)), pos, ang)


# ----------------------------------------------------------------------------- rig


IMU_NAME = "imu0"
# R_body_imu: the IMU's x along body left, y along body back, z up, then tilted by 3 deg
R_BODY_IMU = ir.axes_R(["L", "-F", "U"]) @ ir.rotvec_R(np.radians([2.0, -2.2, 0.0]))
T_BODY_IMU = ir.pose(R_BODY_IMU, [0.03, -0.02, 0.015])
CAMERAS = {  # name: (position, look, nominal rate Hz)
    "front_left": ([0.10, 0.05, 0.01], "forward", 20.0),
    "front_right": ([0.10, -0.05, 0.01], "forward", 30.0),
    "back": ([-0.10, 0.0, 0.02], "backward", 15.0),
}
SIZE = (480, 360)
FOCAL = 280.0


def declared_rig(rates: dict[str, float], T_body_imu: np.ndarray = T_BODY_IMU) -> dict:
    """rig.yaml as a user writes it: nominal camera poses and intrinsics, the IMU exactly."""
    cams = {}
    for name, (pos, look, _) in CAMERAS.items():
        cams[name] = {"model": "pinhole", "resolution": list(SIZE), "intrinsics": {"focal": FOCAL},
                      "distortion": [0, 0, 0, 0, 0], "position": pos, "look": look}
    imu = {"position": [float(x) for x in T_body_imu[:3, 3]],
           "rotation": [[float(x) for x in r] for r in T_body_imu[:3, :3]], "update_rate": 400.0, **NOISE}
    return {"rig": "indie-motion", "body_frame": "FLU", "imus": {IMU_NAME: imu}, "cameras": cams,
            "stereo_pairs": [["front_left", "front_right"]]}


def true_cameras(rng: np.random.Generator) -> tuple[ir.Camera, ...]:
    """Mounting ~3 mm / ~0.8 deg off the declared pose, focal +-1.5 %, principal point
    +-6 px, mild radtan distortion."""
    out = []
    for name, (pos, look, _) in CAMERAS.items():
        T = ir._perturbed(ir.pose(ir.axes_R(ir.LOOK[look]), pos), rng, 3.0, 0.8)
        f = FOCAL * (1 + rng.uniform(-0.015, 0.015, 2))
        c = np.array(SIZE) / 2 + rng.uniform(-6, 6, 2)
        dist = [rng.uniform(-0.12, -0.06), rng.uniform(0.01, 0.05), rng.uniform(-6e-4, 6e-4),
                rng.uniform(-6e-4, 6e-4), 0.0]
        out.append(ir._pinhole(name, tuple(f), c[0], c[1], dist, T, size=SIZE))
    return tuple(out)


def walls(rng: np.random.Generator, T_world_room: np.ndarray) -> dict[str, tuple[ir.Board, np.ndarray]]:
    """Static boards on the room's front and back walls: name -> (Board, T_world_board)."""
    F, L, U = np.eye(3)
    spec = {
        "front_a": (ir.Board("front_a", (8, 6), 0.12, 0.09, 0), [1.25, 0.45, 0.15], F, -L),
        "front_b": (ir.Board("front_b", (7, 5), 0.13, 0.10, 24), [1.2, -0.55, 0.2], F, -L),
        "front_c": (ir.Board("front_c", (9, 6), 0.10, 0.075, 60), [1.0, 0.0, -0.45], F - 0.6 * U, -L),
        "back_a": (ir.Board("back_a", (8, 6), 0.12, 0.09, 100), [-1.1, -0.4, 0.1], -F, L),
        "back_b": (ir.Board("back_b", (6, 5), 0.14, 0.105, 200), [-1.05, 0.5, 0.0], -F, L),
    }
    return {n: (b, T_world_room @ ir._centred(ir._board_facing(c, nrm, right, 20, rng), b))
            for n, (b, c, nrm, right) in spec.items()}


# ----------------------------------------------------------------------------- streams


def imu_stream(mot: Motion, duration: float, rate: float, rng: np.random.Generator,
               T_body_imu: np.ndarray = T_BODY_IMU, noise: dict = NOISE, noiseless: bool = False) -> dict:
    """IMU samples over [0, duration]: {"t_ns": (N,) int64 stamps, "gyro", "accel": (N, 3)
    readings, "gyro_bias", "accel_bias": (N, 3) true biases, "gyro_true", "accel_true": (N, 3)
    noise- and bias-free readings}."""
    dt_ns = int(round(1e9 / rate))
    n = int(np.floor(duration * 1e9 / dt_ns)) + 1
    t_ns = T0_NS + dt_ns * np.arange(n, dtype=np.int64)
    R_bi, r_bi = T_body_imu[:3, :3], T_body_imu[:3, 3]
    gyro_true, accel_true = np.empty((n, 3)), np.empty((n, 3))
    for k in range(n):
        t = (t_ns[k] - T0_NS) * 1e-9
        T = mot.T_world_body(t)
        w, wd = mot.omega_body(t)
        a_imu = mot.acc_world(t) + T[:3, :3] @ (np.cross(wd, r_bi) + np.cross(w, np.cross(w, r_bi)))
        gyro_true[k] = R_bi.T @ w
        accel_true[k] = (T[:3, :3] @ R_bi).T @ (a_imu - G_WORLD)
    dt = dt_ns * 1e-9
    if noiseless:
        zero = np.zeros((n, 3))
        return {"t_ns": t_ns, "gyro": gyro_true, "accel": accel_true, "gyro_bias": zero, "accel_bias": zero,
                "gyro_true": gyro_true, "accel_true": accel_true}
    bg0, ba0 = rng.normal(0, 0.004, 3), rng.normal(0, 0.04, 3)  # turn-on biases: rad/s, m/s^2
    bg = bg0 + np.cumsum(np.vstack([np.zeros(3), rng.normal(0, noise["gyroscope_random_walk"] * np.sqrt(dt),
                                                            (n - 1, 3))]), axis=0)
    ba = ba0 + np.cumsum(np.vstack([np.zeros(3), rng.normal(0, noise["accelerometer_random_walk"] * np.sqrt(dt),
                                                            (n - 1, 3))]), axis=0)
    gyro = gyro_true + bg + rng.normal(0, noise["gyroscope_noise_density"] / np.sqrt(dt), (n, 3))
    accel = accel_true + ba + rng.normal(0, noise["accelerometer_noise_density"] / np.sqrt(dt), (n, 3))
    return {"t_ns": t_ns, "gyro": gyro, "accel": accel, "gyro_bias": bg, "accel_bias": ba,
            "gyro_true": gyro_true, "accel_true": accel_true}


def camera_stamps(rng: np.random.Generator, rate: float, start: float, stop: float, drop: float = 0.03) -> np.ndarray:
    """Free-running capture stamps (int64 ns, camera clock) in [start, stop] seconds: own
    phase, period off nominal by up to 2e-4, +-0.2 ms jitter, a share `drop` of frames lost."""
    period = (1 + rng.uniform(-2e-4, 2e-4)) / rate
    t = start + rng.uniform(0, period) + period * np.arange(int((stop - start) * rate) + 2)
    t = t + rng.uniform(-2e-4, 2e-4, t.size)
    t = t[t <= stop]
    t = t[rng.random(t.size) >= drop]
    return T0_NS + np.round(t * 1e9).astype(np.int64)


# ----------------------------------------------------------------------------- recording


@dataclass(frozen=True)
class Recording:
    seed: int
    duration: float
    imu_rate: float
    motion: Motion
    cameras: tuple[ir.Camera, ...]
    rates: dict            # camera -> nominal Hz
    time_offsets: dict     # camera -> true time_offset_s (t_imu = t_cam + offset)
    stamps: dict           # camera -> (K,) int64 stems, camera clock
    boards: dict           # name -> (Board, T_world_board)
    photometry: dict
    T_body_imu: np.ndarray = field(default_factory=lambda: T_BODY_IMU.copy())  # the IMU's mounting, declared exactly


def recording(seed: int = 0, duration: float = 12.0, imu_rate: float = 400.0,
              rates: dict | None = None, T_body_imu: np.ndarray = T_BODY_IMU) -> Recording:
    """Everything of one recording but the pixels and the IMU noise: cameras at 20 / 30 /
    15 Hz; front_right starts 1.5 s late, back stops 1.5 s early; time offsets of
    1.5-6 ms, signs mixed."""
    rng = np.random.default_rng(seed)
    rates = rates or {n: r for n, (_, _, r) in CAMERAS.items()}
    mot = motion(seed)
    cams = true_cameras(rng)
    mag = rng.uniform(1.5, 6.0, len(cams)) / 1000
    offsets = {c.name: float(s * m) for c, s, m in zip(cams, (1, -1, 1) if seed % 2 == 0 else (-1, 1, -1), mag)}
    spans = {"front_left": (0.3, duration - 0.3), "front_right": (1.5, duration - 0.3),
             "back": (0.3, duration - 1.5)}
    stamps = {}
    for c in cams:
        a, b = spans[c.name]
        # stamps in the camera clock whose true instants (t_cam + offset) lie inside the IMU's span
        stamps[c.name] = camera_stamps(rng, rates[c.name], a - offsets[c.name], b - offsets[c.name])
    ph = {"front_left": ir.Photometry(0.6, 2.0, 1.05, 2.2, 0.25),
          "front_right": ir.Photometry(0.8, 2.5, 0.95, 1.8, 0.3),
          "back": ir.Photometry(0.7, 3.0, 1.1, 2.0, 0.35)}
    return Recording(seed, duration, imu_rate, mot, cams, rates, offsets, stamps, walls(rng, mot.T_world_room), ph,
                     T_body_imu)


def capture_time(rec: Recording, camera: str, stem: int) -> float:
    """The trajectory (IMU clock) time, relative seconds, of an image stamped `stem`."""
    return (int(stem) - T0_NS) * 1e-9 + rec.time_offsets[camera]


def render_camera(rec: Recording, cam: ir.Camera, folder: Path, S: int = 2) -> int:
    """Render every stamped frame of one camera as 8-bit grey PNG; returns the count."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([rec.seed, sum(map(ord, cam.name))])
    rays, valid = ir.pixel_rays(cam, S)
    textures = {n: b.texture() for n, (b, _) in rec.boards.items()}
    lighting = ir.lighting_field(cam.size, rng)
    for stem in rec.stamps[cam.name]:
        T_world_cam = rec.motion.T_world_body(capture_time(rec, cam.name, stem)) @ cam.T_body_cam
        hits = [(*textures[n], ir.inv(T) @ T_world_cam) for n, (_, T) in rec.boards.items()]
        img = ir.develop(ir.render_radiance(rays, valid, S, hits), rec.photometry[cam.name], False, lighting, rng)
        assert cv2.imwrite(str(folder / f"{int(stem)}.png"), img)
    return len(rec.stamps[cam.name])


def write_recording(rec: Recording, out: Path, S: int = 2, render: bool = True) -> dict:
    """Write the dataset (rig.yaml, target.yaml, imu/imu0.csv, images/<camera>/<t_ns>.png,
    truth.yaml, truth_trajectory.csv) under `out`; returns the truth as arrays:
    {"T_imu_cam": {camera: (4, 4)}, "time_offset_s": {camera: s}, "gyro_bias_mean",
     "accel_bias_mean": (3,), "imu": imu_stream's dict}."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([rec.seed, 400])
    imu = imu_stream(rec.motion, rec.duration, rec.imu_rate, rng, rec.T_body_imu)
    declared = declared_rig(rec.rates, rec.T_body_imu)
    declared["imus"][IMU_NAME]["update_rate"] = float(rec.imu_rate)
    _yaml(out / "rig.yaml", declared)
    _yaml(out / "target.yaml", {"boards": [b.yaml_entry() for b, _ in rec.boards.values()]})
    (out / "imu").mkdir(exist_ok=True)
    rows = [IMU_HEADER] + [f"{t}," + ",".join(repr(float(x)) for x in (*g, *a))
                           for t, g, a in zip(imu["t_ns"], imu["gyro"], imu["accel"])]
    (out / "imu" / f"{IMU_NAME}.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    if render:
        for cam in rec.cameras:
            render_camera(rec, cam, out / "images" / cam.name, S)
    _write_truth(rec, out, imu, declared)
    return {"T_imu_cam": {c.name: ir.inv(rec.T_body_imu) @ c.T_body_cam for c in rec.cameras},
            "time_offset_s": dict(rec.time_offsets), "gyro_bias_mean": _bias_samples(imu, "gyro_bias")[1].mean(0),
            "accel_bias_mean": _bias_samples(imu, "accel_bias")[1].mean(0), "imu": imu}


def _bias_samples(imu: dict, key: str) -> tuple[np.ndarray, np.ndarray]:
    """The true bias at 10 Hz: every sample whose stamp is a multiple of 100 ms."""
    keep = (imu["t_ns"] - T0_NS) % 100_000_000 == 0
    return imu["t_ns"][keep], imu[key][keep]


def _write_truth(rec: Recording, out: Path, imu: dict, declared: dict) -> None:
    cams = {}
    for c in rec.cameras:
        d = {"model": c.model, "resolution": list(c.size),
             "intrinsics": {"fx": float(c.K[0, 0]), "fy": float(c.K[1, 1]), "cx": float(c.K[0, 2]),
                            "cy": float(c.K[1, 2])},
             "distortion": [float(x) for x in c.dist], **ir._pose_doc(c.T_body_cam),
             "quaternion": [float(x) for x in ir.quat_wxyz(c.T_body_cam[:3, :3])],
             "time_offset_s": rec.time_offsets[c.name]}
        cams[c.name] = d
    imu_decl = declared["imus"][IMU_NAME]
    imus = {IMU_NAME: {**ir._pose_doc(rec.T_body_imu),
                       "quaternion": [float(x) for x in ir.quat_wxyz(rec.T_body_imu[:3, :3])],
                       **{k: v for k, v in imu_decl.items() if k not in ("position", "rotation")}}}
    rig = {"rig": "indie-motion-truth", "body_frame": "FLU", "imus": imus, "cameras": cams,
           "stereo_pairs": declared["stereo_pairs"]}
    frames = {}
    for c in rec.cameras:
        for stem in rec.stamps[c.name]:
            assert str(int(stem)) not in frames, "two cameras share a stem: the truth per stem would be ambiguous"
            frames[str(int(stem))] = ir._pose_doc(rec.motion.T_world_body(capture_time(rec, c.name, stem)))
    biases = {}
    for key, name in (("gyro_bias", "gyroscope_bias"), ("accel_bias", "accelerometer_bias")):
        t, v = _bias_samples(imu, key)
        biases[name] = {"t_ns": [int(x) for x in t], "values": [[float(x) for x in r] for r in v]}
    doc = {"rig": rig, "imus": {IMU_NAME: biases}, "gravity_world": [float(x) for x in G_WORLD],
           "boards": {n: ir._pose_doc(T) for n, (_, T) in rec.boards.items()}, "frames": frames,
           "render": {"renderer": "tests/support/indie_motion.py (indie_render.py's ray caster)",
                      "seed": rec.seed, "duration_s": rec.duration, "imu_rate_hz": rec.imu_rate,
                      "camera_rates_hz": {k: float(v) for k, v in rec.rates.items()}}}
    _yaml(out / "truth.yaml", doc)
    lines = ["#t_ns,px,py,pz,qw,qx,qy,qz"]
    for t in imu["t_ns"]:
        T = rec.motion.T_world_body((t - T0_NS) * 1e-9)
        lines.append(f"{t}," + ",".join(repr(float(x)) for x in (*T[:3, 3], *ir.quat_wxyz(T[:3, :3]))))
    (out / "truth_trajectory.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")


def _yaml(path: Path, doc: dict) -> None:
    path.write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None), encoding="utf-8")
