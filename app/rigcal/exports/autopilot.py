"""Flight-controller parameter files for a vision / visual-inertial odometry input.

Both autopilots take the sensor's place in their FRD body frame (x forward, y right,
z down; rigcal.exports.frames.p_frd), measured from rigcal's body-frame origin: declare
that origin at the vehicle's reference point (its centre of gravity) in the rig file.
The sensor is a camera of the rig (``--camera NAME``, default the first).

* ``px4`` — a QGroundControl parameter file (``.params``: ``#`` comments, then
  ``vehicle-id <tab> component-id <tab> name <tab> value <tab> type`` with type 9 =
  float, 6 = int32): ``EKF2_EV_POS_X/Y/Z`` (m) and, when the camera's clock offset is
  calibrated, ``EKF2_EV_DELAY`` (ms) = -time_offset_s (how late the measurement arrives
  after the instant it describes; meaningful when the rig's IMU is the flight
  controller's).
* ``ardupilot`` — an ArduPilot ``.param`` file (``NAME,VALUE`` lines, ``#`` comments):
  ``VISO_POS_X/Y/Z`` (m), ``VISO_ORIENT`` (the camera's viewing direction: 0 forward,
  2 right, 4 back, 6 left, 24 up, 25 down, ArduPilot's rotation enum; refused when the
  camera is more than ORIENT_LIMIT_DEG from all six) and, with a calibrated offset,
  ``VISO_DELAY_MS`` (whole ms).

Further parameters (the magnetometers' calibration, CAL_MAGn_* / COMPASS_*, built
elsewhere) enter through the ``extra`` mapping of px4_params / ardupilot_params: name ->
number, written after these.
"""

from __future__ import annotations

import re
from typing import Mapping

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.rig import Camera, Rig
from rigcal.errors import InputError
from rigcal.exports import targets
from rigcal.exports.formats import Export
from rigcal.exports.frames import R_frd, delay_ms, p_frd

ORIENT_LIMIT_DEG = 10.0  # VISO_ORIENT holds six directions; a camera further from all of them is refused
MAX_DELAY_MS = {"px4": 300.0, "ardupilot": 250.0}  # EKF2_EV_DELAY and VISO_DELAY_MS ranges
PARAM_NAME = re.compile(r"^[A-Z][A-Z0-9_]{0,15}$")  # MAVLink parameter ids: 16 characters at most

# The camera's "sensor FRD" frame S: x = viewing direction (camera z), y = image right
# (camera x), z = image down (camera y). R_cam_S has S's axes as columns in camera terms.
R_CAM_S = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def _R_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _R_y(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


# VISO_ORIENT value -> (name, R_frd_S): ArduPilot's ROTATION_NONE, YAW_90, YAW_180, YAW_270, PITCH_90, PITCH_270.
VISO_ORIENTS = {0: ("forward", _R_z(0)), 2: ("right", _R_z(90)), 4: ("back", _R_z(180)), 6: ("left", _R_z(270)),
                24: ("up", _R_y(90)), 25: ("down", _R_y(270))}


def viso_orient(T_body_cam: np.ndarray) -> tuple[int, str, float]:
    """(VISO_ORIENT value, its name, degrees between the camera's frame and that rotation)."""
    R_frd_S = R_frd(T_body_cam[:3, :3]) @ R_CAM_S
    best = min(VISO_ORIENTS, key=lambda k: geo.rotation_angle_deg(VISO_ORIENTS[k][1].T @ R_frd_S))
    name, R = VISO_ORIENTS[best]
    return best, name, geo.rotation_angle_deg(R.T @ R_frd_S)


def _camera(rig: Rig, label: str, fmt: str, name: str | None) -> Camera:
    cam = targets.camera_named(rig, name, label, fmt)
    targets.posed([cam], label, fmt)
    return cam


def _delay(cam: Camera, fmt: str) -> tuple[float | None, list[str]]:
    if cam.time_offset_s is None:
        return None, []
    d = delay_ms(cam.time_offset_s)
    if d < 0.0:
        return 0.0, [f"cameras.{cam.name}.time_offset_s: {cam.time_offset_s * 1000:+.3f} ms (t_imu = t_cam + offset) "
                     f"stamps images before the instant they show; {fmt}'s delay cannot be negative, wrote 0"]
    if d > MAX_DELAY_MS[fmt]:
        raise InputError(f"cameras.{cam.name}.time_offset_s: gives a delay of {d:.1f} ms, past {fmt}'s "
                         f"{MAX_DELAY_MS[fmt]:g} ms limit")
    return d, []


def _extra(extra: Mapping[str, float] | None, taken: set[str], fmt: str) -> list[tuple[str, float]]:
    out = []
    for name, value in (extra or {}).items():
        if not PARAM_NAME.match(name) or name in taken:
            raise InputError(f"export --format {fmt}: parameter {name!r}: expected a new name of at most 16 "
                             "capitals, digits and underscores")
        if not np.isfinite(value):
            raise InputError(f"export --format {fmt}: parameter {name}: expected a finite number, got {value!r}")
        out.append((name, value))
    return out


def _comment(rig: Rig, label: str, cam: Camera, target: str, delay_name: str, delay: float | None) -> list[str]:
    t = cam.T_body_cam[:3, 3]
    lines = targets.header(rig, label, target) + [
        f"Sensor: camera {cam.name}; position in {target}'s FRD body frame (x forward, y right, z down) = "
        f"rigcal's FLU position ({t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}) m with y and z negated, measured from "
        "rigcal's body-frame origin (put it at the vehicle's centre of gravity in the rig file)."]
    if delay is None:
        lines.append(f"{delay_name} not written: the rig has no calibrated clock offset for {cam.name}.")
    else:
        lines.append(f"{delay_name} = -time_offset_s (rigcal's t_imu = t_cam + time_offset_s), meaningful when the "
                     "rig's IMU is the flight controller's.")
    return lines


def px4_params(rig: Rig, label: str = "<rig>", camera: str | None = None,
               extra: Mapping[str, float] | None = None) -> Export:
    cam = _camera(rig, label, "px4", camera)
    p = p_frd(cam.T_body_cam[:3, 3])
    delay, warnings = _delay(cam, "px4")
    params: list[tuple[str, float, int]] = [("EKF2_EV_POS_X", p[0], 9), ("EKF2_EV_POS_Y", p[1], 9),
                                            ("EKF2_EV_POS_Z", p[2], 9)]
    if delay is not None:
        params.append(("EKF2_EV_DELAY", delay, 9))
    params += [(n, v, 6 if isinstance(v, (int, np.integer)) else 9)
               for n, v in _extra(extra, {q[0] for q in params}, "px4")]
    lines = [f"# {s}" for s in _comment(rig, label, cam, "PX4", "EKF2_EV_DELAY", delay)]
    lines += ["#", "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"1\t1\t{n}\t{int(v) if t == 6 else repr(float(v) + 0.0)}\t{t}" for n, v, t in params]
    return Export({"rigcal.params": "\n".join(lines) + "\n"}, tuple(warnings),
                  tuple(f"{n} = {v:.6g}" for n, v, _ in params))


def ardupilot_params(rig: Rig, label: str = "<rig>", camera: str | None = None,
                     extra: Mapping[str, float] | None = None) -> Export:
    cam = _camera(rig, label, "ardupilot", camera)
    p = p_frd(cam.T_body_cam[:3, 3])
    orient, name, off = viso_orient(cam.T_body_cam)
    if off > ORIENT_LIMIT_DEG:
        raise InputError(f"{label}: cameras.{cam.name}: ArduPilot's VISO_ORIENT holds forward, right, back, left, up "
                         f"or down; this camera is {off:.1f} deg from the nearest ({name}), more than "
                         f"{ORIENT_LIMIT_DEG:g} deg")
    delay, warnings = _delay(cam, "ardupilot")
    params: list[tuple[str, float]] = [("VISO_POS_X", p[0]), ("VISO_POS_Y", p[1]), ("VISO_POS_Z", p[2]),
                                       ("VISO_ORIENT", orient)]
    if delay is not None:
        params.append(("VISO_DELAY_MS", int(round(delay))))
    params += _extra(extra, {q[0] for q in params}, "ardupilot")
    head = _comment(rig, label, cam, "ArduPilot", "VISO_DELAY_MS", delay)
    head.append(f"VISO_ORIENT {orient} = {name}: camera {cam.name} looks {name}, {off:.2f} deg from that exact "
                "orientation (ArduPilot holds no finer one).")
    lines = [f"# {s}" for s in head]
    lines += [f"{n},{int(v) if isinstance(v, (int, np.integer)) else repr(float(v) + 0.0)}" for n, v in params]
    return Export({"rigcal.param": "\n".join(lines) + "\n"}, tuple(warnings),
                  tuple(f"{n} = {v:.6g}" for n, v in params))
