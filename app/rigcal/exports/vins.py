"""VINS-Fusion: ``<rig>_config.yaml`` and one camodocal camera file per camera.

VINS-Fusion takes one camera or one stereo pair (``num_of_cam`` 1 or 2): the first stereo
pair, or the pair / camera named by ``--camera``. The config holds every key its
readParameters reads (cv::FileStorage reads a missing number as 0 without a word):

* ``imu`` 1 with the rig's first IMU: ``body_T_cam0``/``body_T_cam1`` map camera points
  into that IMU's frame; ``acc_n``, ``gyr_n``, ``acc_w``, ``gyr_w`` are Kalibr's
  continuous-time densities of the rig file; ``td`` the first camera's clock offset
  (t_imu = t_cam + td, rigcal's time_offset_s).
* ``imu`` 0 without one: ``body_T_camN`` map camera points into rigcal's FLU body frame.
* ``image_width``/``image_height`` (both cameras must share them), ``cam0_calib``/
  ``cam1_calib`` (the camera file names), topics, and VINS-Fusion's own EuRoC values for
  the tracker and solver (HKUST-Aerial-Robotics/VINS-Fusion config/euroc/
  euroc_stereo_imu_config.yaml).

Camera files (camodocal): ``model_type: PINHOLE`` with ``distortion_parameters`` k1 k2
p1 p2 and ``projection_parameters`` fx fy cx cy, or ``KANNALA_BRANDT`` with
``projection_parameters`` k2 k3 k4 k5 mu mv u0 v0 (camodocal's k2..k5 are OpenCV's
fisheye k1..k4; mu, mv, u0, v0 are fx, fy, cx, cy). Every file starts ``%YAML:1.0``.
"""

from __future__ import annotations

import numpy as np

from rigcal.core.rig import Camera, Rig
from rigcal.errors import InputError
from rigcal.exports import targets
from rigcal.exports.cvyaml import Mat, cv_yaml
from rigcal.exports.formats import Export
from rigcal.exports.frames import T_imu_cam

FMT = "vins"
TARGET = "VINS-Fusion"

TRACKER_DEFAULTS = (("multiple_thread", 1), ("max_cnt", 150), ("min_dist", 30), ("freq", 10), ("F_threshold", 1.0),
                    ("show_track", 1), ("flow_back", 1), ("max_solver_time", 0.04), ("max_num_iterations", 8),
                    ("keyframe_parallax", 10.0))


def camera_file_name(cam: Camera) -> str:
    return f"{cam.name}_{'fisheye' if cam.intrinsics.model == 'fisheye' else 'pinhole'}.yaml"


def _camera_text(cam: Camera, head: list[str], label: str) -> tuple[str, str | None]:
    m = cam.intrinsics
    if m.model == "fisheye":
        k = targets.kb4(cam)
        body = [("model_type", "KANNALA_BRANDT"), ("camera_name", cam.name), ("image_width", int(m.width)),
                ("image_height", int(m.height)),
                ("projection_parameters", {"k2": k[0], "k3": k[1], "k4": k[2], "k5": k[3], "mu": float(m.fx),
                                           "mv": float(m.fy), "u0": float(m.cx), "v0": float(m.cy)})]
        what, warning = "camodocal KANNALA_BRANDT (k2..k5 = OpenCV fisheye k1..k4; mu mv u0 v0 = fx fy cx cy)", None
    else:
        (k1, k2, p1, p2), warning = targets.pinhole_coeffs(cam, 4, label, "VINS-Fusion's PINHOLE model")
        body = [("model_type", "PINHOLE"), ("camera_name", cam.name), ("image_width", int(m.width)),
                ("image_height", int(m.height)), ("distortion_parameters", {"k1": k1, "k2": k2, "p1": p1, "p2": p2}),
                ("projection_parameters", {"fx": float(m.fx), "fy": float(m.fy), "cx": float(m.cx), "cy": float(m.cy)})]
        what = "camodocal PINHOLE (OpenCV k1 k2 p1 p2)"
    return cv_yaml([("#", "\n".join(head + [f"Camera {cam.name}: {what}, pixels."]))] + body), warning


def vins_files(rig: Rig, label: str = "<rig>", camera: str | None = None) -> Export:
    cams = targets.one_or_pair(rig, label, FMT, camera)
    sizes = {c.intrinsics.resolution for c in cams}
    if len(sizes) > 1:
        raise InputError(f"{label}: cameras.{cams[1].name}.resolution: VINS-Fusion takes one image size for both "
                         f"cameras; {cams[0].name} is {cams[0].intrinsics.resolution}, "
                         f"{cams[1].name} {cams[1].intrinsics.resolution}")
    imu = rig.imus[0] if rig.imus else None
    head = targets.header(rig, label, TARGET)
    warnings: list[str] = []
    files: dict[str, str] = {}
    for c in cams:
        text, warning = _camera_text(c, head, label)
        files[camera_file_name(c)] = text
        warnings += [warning] if warning else []
    if imu is not None:
        body = f"IMU {imu.name}'s frame"
        T = [T_imu_cam(imu.T_body_imu, c.T_body_cam) for c in cams]
        td, w = targets.one_offset(cams, TARGET, "td")
        warnings += w
    else:
        body = "rigcal's FLU body frame (no IMU: imu 0)"
        T = [c.T_body_cam for c in cams]
        td = 0.0
    m = cams[0].intrinsics
    entries: list[tuple[str, object]] = [
        ("#", "\n".join(head + [f"body_T_camN maps camera N's points into {body}, metres; td: t_imu = t_cam + td, s.",
                                "Cameras: " + ", ".join(f"cam{i} = {c.name}" for i, c in enumerate(cams)) + "."])),
        ("imu", 1 if imu is not None else 0), ("num_of_cam", len(cams)),
        ("imu_topic", f"/{imu.name}" if imu is not None else "/imu0")]
    entries += [(f"image{i}_topic", f"/{c.name}/image_raw") for i, c in enumerate(cams)]
    entries += [("output_path", "/tmp/vins_output/")]
    entries += [(f"cam{i}_calib", camera_file_name(c)) for i, c in enumerate(cams)]
    entries += [("image_width", int(m.width)), ("image_height", int(m.height)), ("fisheye", 0),
                ("estimate_extrinsic", 0)]
    entries += [(f"body_T_cam{i}", Mat(np.asarray(Ti, float))) for i, Ti in enumerate(T)]
    entries += list(TRACKER_DEFAULTS)
    if imu is not None:
        entries += [("#", "Kalibr's continuous-time densities from the rig file; VINS-Fusion's own EuRoC file "
                          "inflates them (acc_n 0.1, gyr_n 0.01, acc_w 0.001, gyr_w 0.0001)."),
                    ("acc_n", float(imu.accelerometer_noise_density)), ("gyr_n", float(imu.gyroscope_noise_density)),
                    ("acc_w", float(imu.accelerometer_random_walk)), ("gyr_w", float(imu.gyroscope_random_walk)),
                    ("g_norm", 9.81007)]
    entries += [("estimate_td", 0), ("td", float(td)), ("load_previous_pose_graph", 0),
                ("pose_graph_save_path", "/tmp/vins_output/pose_graph/"), ("save_image", 0)]
    stem = rig.name.replace("/", "_").replace(" ", "_")
    files[f"{stem}_config.yaml"] = cv_yaml(entries)
    summary = tuple(f"cam{i} = {c.name}" for i, c in enumerate(cams)) + ((f"imu = {imu.name}",) if imu else ())
    return Export(dict(sorted(files.items())), tuple(warnings), summary)
