"""basalt: its calibration JSON (``value0``, in the layout of basalt's
data/t265_kb4_calib.json).

* ``T_imu_cam``: per camera its pose in the IMU frame (maps camera points into the IMU
  frame) as ``px py pz qx qy qz qw`` (Eigen's quaternion order, w last).
* ``intrinsics``: ``kb4`` (fx fy cx cy k1..k4) for a rigcal fisheye camera — the same
  model exactly; ``pinhole-radtan8`` (fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6 rpmax) for a
  pinhole one — OpenCV's rational model, exact for rigcal's radial2, radtan4, radtan5
  and rational8 (missing terms are zero); thinprism12 keeps its first eight when the
  four thin-prism terms move no pixel by more than 0.01 px, and is refused otherwise.
  ``rpmax`` is the normalised radius up to which the distortion is one-to-one
  (rigcal.core.camera.max_valid_radius_pinhole).
* ``resolution``, ``calib_accel_bias`` (9 zeros) and ``calib_gyro_bias`` (12 zeros):
  rigcal estimates no IMU biases or scale, and zeros are basalt's identity.
* ``imu_update_rate``; ``accel_noise_std``, ``gyro_noise_std``, ``accel_bias_std``,
  ``gyro_bias_std`` per axis: Kalibr's continuous-time densities (basalt's meaning too).
* ``cam_time_offset_ns``: the first camera's clock offset (t_imu = t_cam + offset), ns.
* ``vignette``: empty (rigcal does not estimate it).

JSON has no comments: the statement of frames, version and source rig is a top-level
``comment`` member after ``value0``, which basalt's reader does not read.
"""

from __future__ import annotations

import json

from rigcal.core.camera import max_valid_radius_pinhole
from rigcal.core.rig import Rig
from rigcal.exports import targets
from rigcal.exports.formats import Export, kalibr_order
from rigcal.exports.frames import T_imu_cam, offset_ns, pose_xyzw

FMT = "basalt"
TARGET = "basalt"


def basalt_file(rig: Rig, label: str = "<rig>") -> Export:
    imu = targets.first_imu(rig, label, FMT)
    order = kalibr_order(rig)
    cams = [rig.camera(n) for n in order]
    targets.posed(cams, label, FMT)
    warnings: list[str] = []
    intrinsics = []
    for cam in cams:
        m = cam.intrinsics
        base = {"fx": float(m.fx), "fy": float(m.fy), "cx": float(m.cx), "cy": float(m.cy)}
        if m.model == "fisheye":
            intrinsics.append({"camera_type": "kb4",
                               "intrinsics": {**base, **dict(zip(("k1", "k2", "k3", "k4"), targets.kb4(cam)))}})
            continue
        coeffs, warning = targets.pinhole_coeffs(cam, 8, label, "basalt's pinhole-radtan8 model")
        warnings += [warning] if warning else []
        names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
        intrinsics.append({"camera_type": "pinhole-radtan8",
                           "intrinsics": {**base, **dict(zip(names, coeffs)),
                                          "rpmax": float(max_valid_radius_pinhole(coeffs))}})
    offset, w = targets.one_offset(cams, TARGET, "cam_time_offset_ns")
    warnings += w
    value = {
        "T_imu_cam": [pose_xyzw(T_imu_cam(imu.T_body_imu, c.T_body_cam)) for c in cams],
        "intrinsics": intrinsics,
        "resolution": [[int(c.intrinsics.width), int(c.intrinsics.height)] for c in cams],
        "calib_accel_bias": [0.0] * 9,
        "calib_gyro_bias": [0.0] * 12,
        "imu_update_rate": float(imu.update_rate),
        "accel_noise_std": [float(imu.accelerometer_noise_density)] * 3,
        "gyro_noise_std": [float(imu.gyroscope_noise_density)] * 3,
        "accel_bias_std": [float(imu.accelerometer_random_walk)] * 3,
        "gyro_bias_std": [float(imu.gyroscope_random_walk)] * 3,
        "cam_time_offset_ns": offset_ns(offset),
        "vignette": [],
    }
    comment = (" ".join(targets.header(rig, label, TARGET))
               + f" T_imu_cam: each camera's pose in IMU {imu.name}'s frame (maps camera points into it), metres, "
               "quaternion qx qy qz qw. cam_time_offset_ns: t_imu = t_cam + offset. Cameras: "
               + ", ".join(f"{i} = {n}" for i, n in enumerate(order)) + ".")
    text = json.dumps({"value0": value, "comment": comment}, indent=4) + "\n"
    summary = tuple(f"camera {i} = {n}" for i, n in enumerate(order)) + (f"imu = {imu.name}",)
    return Export({"calibration.json": text}, tuple(warnings), summary)
