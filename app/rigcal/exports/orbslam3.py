"""ORB-SLAM3: one settings file (``File.version: "1.0"``, read by its Settings class).

One camera (monocular, and monocular-inertial when the rig has an IMU) or one stereo pair
(stereo, stereo-inertial): the first stereo pair, or the pair / camera named by
``--camera``; both cameras of a pair must share one model and one image size.

* ``Camera.type`` ``PinHole`` (``CameraN.k1 k2 p1 p2`` and ``k3`` when the camera has one;
  ORB-SLAM3 rectifies a pinhole pair itself) or ``KannalaBrandt8`` (``CameraN.k1..k4``,
  OpenCV's fisheye coefficients; ``CameraN.overlappingBegin/End`` 0 and width - 1; a
  warning for a pair with different coefficients, since ORB-SLAM3 1.0's Settings reads
  camera 2's from the Camera1 keys).
* ``Stereo.T_c1_c2``: camera 2's pose in camera 1 (maps camera-2 points into camera 1);
  ``IMU.T_b_c1``: camera 1's pose in the IMU frame (maps camera-1 points into the IMU
  frame, ORB-SLAM3's body). Both ``!!opencv-matrix`` with ``dt: f``, which ORB-SLAM3's
  converter requires (it reads the matrix as float).
* ``IMU.NoiseGyro``, ``IMU.NoiseAcc``, ``IMU.GyroWalk``, ``IMU.AccWalk`` are Kalibr's
  continuous-time densities; ``IMU.Frequency`` the IMU rate.
* Integers where ORB-SLAM3 reads ints (``Camera.width``, ``Camera.height``,
  ``Camera.fps``, ``Camera.RGB``, ``ORBextractor.nFeatures`` ...); ``ORBextractor.*`` and
  ``Viewer.*`` take ORB-SLAM3's EuRoC values. The rig file holds no frame rate, so
  ``Camera.fps`` is 20 (EuRoC's) with a warning.

ORB-SLAM3 has no camera-IMU clock offset: a calibrated one is reported as a warning.
"""

from __future__ import annotations

import numpy as np

from rigcal.core.rig import Rig
from rigcal.errors import InputError
from rigcal.exports import targets
from rigcal.exports.cvyaml import Mat, cv_yaml
from rigcal.exports.formats import Export
from rigcal.exports.frames import T_cam_cam, T_imu_cam

FMT = "orbslam3"
TARGET = "ORB-SLAM3"
DEFAULT_FPS = 20

ORB_DEFAULTS = (("ORBextractor.nFeatures", 1200), ("ORBextractor.scaleFactor", 1.2), ("ORBextractor.nLevels", 8),
                ("ORBextractor.iniThFAST", 20), ("ORBextractor.minThFAST", 7))
VIEWER_DEFAULTS = (("Viewer.KeyFrameSize", 0.05), ("Viewer.KeyFrameLineWidth", 1.0), ("Viewer.GraphLineWidth", 0.9),
                   ("Viewer.PointSize", 2.0), ("Viewer.CameraSize", 0.08), ("Viewer.CameraLineWidth", 3.0),
                   ("Viewer.ViewpointX", 0.0), ("Viewer.ViewpointY", -0.7), ("Viewer.ViewpointZ", -3.5),
                   ("Viewer.ViewpointF", 500.0))


def orbslam3_file(rig: Rig, label: str = "<rig>", camera: str | None = None) -> Export:
    cams = targets.one_or_pair(rig, label, FMT, camera)
    models = {c.intrinsics.model for c in cams}
    if len(models) > 1:
        raise InputError(f"{label}: cameras.{cams[1].name}.model: ORB-SLAM3 takes one Camera.type for both cameras; "
                         f"{cams[0].name} is {cams[0].intrinsics.model}, {cams[1].name} {cams[1].intrinsics.model}")
    if len({c.intrinsics.resolution for c in cams}) > 1:
        raise InputError(f"{label}: cameras.{cams[1].name}.resolution: ORB-SLAM3 takes one Camera.width/height; "
                         f"{cams[0].name} is {cams[0].intrinsics.resolution}, "
                         f"{cams[1].name} {cams[1].intrinsics.resolution}")
    fisheye = cams[0].intrinsics.model == "fisheye"
    imu = rig.imus[0] if rig.imus else None
    head = targets.header(rig, label, TARGET)
    lines = [f"Camera1 = {cams[0].name}" + (f", Camera2 = {cams[1].name}" if len(cams) == 2 else "") + "."]
    if len(cams) == 2:
        lines.append("Stereo.T_c1_c2 maps Camera2's points into Camera1's frame, metres.")
    if imu is not None:
        lines.append(f"IMU.T_b_c1 maps Camera1's points into IMU {imu.name}'s frame (ORB-SLAM3's body b), metres.")
    entries: list[tuple[str, object]] = [("#", "\n".join(head + lines)), ("File.version", "1.0"),
                                         ("Camera.type", "KannalaBrandt8" if fisheye else "PinHole")]
    warnings: list[str] = []
    for i, c in enumerate(cams, start=1):
        m = c.intrinsics
        entries += [(f"Camera{i}.fx", float(m.fx)), (f"Camera{i}.fy", float(m.fy)), (f"Camera{i}.cx", float(m.cx)),
                    (f"Camera{i}.cy", float(m.cy))]
        if fisheye:
            entries += [(f"Camera{i}.k{j}", k) for j, k in enumerate(targets.kb4(c), start=1)]
        else:
            keep = 5 if len(m.dist) >= 5 else 4
            coeffs, warning = targets.pinhole_coeffs(c, keep, label, "ORB-SLAM3's PinHole model")
            warnings += [warning] if warning else []
            entries += [(f"Camera{i}.{n}", k) for n, k in zip(("k1", "k2", "p1", "p2", "k3"), coeffs)]
        if fisheye and len(cams) == 2:
            entries += [(f"Camera{i}.overlappingBegin", 0), (f"Camera{i}.overlappingEnd", int(m.width) - 1)]
    if fisheye and len(cams) == 2 and targets.kb4(cams[0]) != targets.kb4(cams[1]):
        warnings.append(f"ORB-SLAM3 1.0 reads Camera2's KannalaBrandt8 k1..k4 from the Camera1.k1..k4 keys "
                        f"(Settings::readCamera2): {cams[1].name} gets {cams[0].name}'s distortion unless your "
                        "build reads Camera2.k1..k4, which are written too")
    m = cams[0].intrinsics
    entries += [("Camera.width", int(m.width)), ("Camera.height", int(m.height)), ("Camera.fps", DEFAULT_FPS),
                ("Camera.RGB", 1)]
    warnings.append(f"Camera.fps: the rig file holds no frame rate; wrote {DEFAULT_FPS}, set your cameras' rate")
    if len(cams) == 2:
        entries += [("Stereo.ThDepth", 60.0),
                    ("Stereo.T_c1_c2", Mat(T_cam_cam(cams[0].T_body_cam, cams[1].T_body_cam), "f"))]
    if imu is not None:
        entries += [("IMU.T_b_c1", Mat(T_imu_cam(imu.T_body_imu, cams[0].T_body_cam), "f")),
                    ("IMU.NoiseGyro", float(imu.gyroscope_noise_density)),
                    ("IMU.NoiseAcc", float(imu.accelerometer_noise_density)),
                    ("IMU.GyroWalk", float(imu.gyroscope_random_walk)),
                    ("IMU.AccWalk", float(imu.accelerometer_random_walk)),
                    ("IMU.Frequency", float(imu.update_rate))]
        offset = cams[0].time_offset_s or 0.0
        if abs(offset) > 1e-4:
            warnings.append(f"ORB-SLAM3 has no camera-IMU clock offset: {cams[0].name}'s is {offset * 1000:.3f} ms "
                            f"(t_imu = t_cam + offset); add it to the image timestamps")
    entries += list(ORB_DEFAULTS) + list(VIEWER_DEFAULTS)
    summary = tuple(f"Camera{i} = {c.name}" for i, c in enumerate(cams, start=1)) + (
        (f"IMU = {imu.name}",) if imu else ())
    return Export({"orbslam3.yaml": cv_yaml(entries)}, tuple(warnings), summary)
