"""OpenVINS: the three files of one of its ``config/<dataset>/`` folders.

* ``kalibr_imucam_chain.yaml`` — per camera ``camN``: ``T_imu_cam`` (camera -> IMU, as
  OpenVINS reads it: R_CtoI, p_CinI), ``cam_overlaps``, ``camera_model: pinhole``,
  ``distortion_model`` ``radtan`` (k1 k2 p1 p2) or ``equidistant`` (k1..k4),
  ``distortion_coeffs``, ``intrinsics`` [fx, fy, cx, cy], ``resolution`` [w, h],
  ``rostopic``, ``timeshift_cam_imu`` (t_imu = t_cam + shift; OpenVINS reads cam0's).
  Cameras in Kalibr's order (each stereo pair's left then right).
* ``kalibr_imu_chain.yaml`` — ``imu0``: ``T_i_b`` (identity), Kalibr's four noise
  densities, ``rostopic``, ``time_offset``, ``update_rate``, ``model: kalibr`` and the IMU
  intrinsics blocks OpenVINS reads (``Tw``, ``R_IMUtoGYRO``, ``Ta``, ``R_IMUtoACC``
  identities, ``Tg`` zero: rigcal does not estimate them).
* ``estimator_config.yaml`` — every key OpenVINS's estimator requires (it stops on a
  missing one): the sensor keys from the rig (``max_cameras``, ``use_stereo``, the two
  relative file names) and OpenVINS's own EuRoC values for the rest (rpng/open_vins
  config/euroc_mav/estimator_config.yaml at 69488123).

All three start with ``%YAML:1.0`` (OpenVINS reads them with cv::FileStorage).
"""

from __future__ import annotations

import numpy as np

from rigcal.core.rig import Rig
from rigcal.exports import targets
from rigcal.exports.cvyaml import cv_yaml
from rigcal.exports.formats import Export, camera_overlaps, kalibr_order
from rigcal.exports.frames import T_imu_cam

FMT = "openvins"
TARGET = "OpenVINS"

# OpenVINS's EuRoC estimator_config.yaml values for the keys a rig does not decide.
ESTIMATOR_DEFAULTS = (
    ("verbosity", "INFO"), ("use_fej", True), ("integration", "rk4"),
    ("calib_cam_extrinsics", True), ("calib_cam_intrinsics", True), ("calib_cam_timeoffset", True),
    ("calib_imu_intrinsics", False), ("calib_imu_g_sensitivity", False),
    ("max_clones", 11), ("max_slam", 50), ("max_slam_in_update", 25), ("max_msckf_in_update", 40),
    ("dt_slam_delay", 1), ("gravity_mag", 9.81),
    ("feat_rep_msckf", "GLOBAL_3D"), ("feat_rep_slam", "ANCHORED_MSCKF_INVERSE_DEPTH"),
    ("feat_rep_aruco", "ANCHORED_MSCKF_INVERSE_DEPTH"),
    ("try_zupt", False), ("zupt_chi2_multipler", 0), ("zupt_max_velocity", 0.1), ("zupt_noise_multiplier", 10),
    ("zupt_max_disparity", 0.5), ("zupt_only_at_beginning", False),
    ("init_window_time", 2.0), ("init_imu_thresh", 1.5), ("init_max_disparity", 10.0), ("init_max_features", 50),
    ("init_dyn_use", False), ("init_dyn_mle_opt_calib", False), ("init_dyn_mle_max_iter", 50),
    ("init_dyn_mle_max_time", 0.05), ("init_dyn_mle_max_threads", 6), ("init_dyn_num_pose", 6),
    ("init_dyn_min_deg", 10.0), ("init_dyn_inflation_ori", 10), ("init_dyn_inflation_vel", 100),
    ("init_dyn_inflation_bg", 10), ("init_dyn_inflation_ba", 100), ("init_dyn_min_rec_cond", 1e-12),
    ("init_dyn_bias_g", [0.0, 0.0, 0.0]), ("init_dyn_bias_a", [0.0, 0.0, 0.0]),
    ("record_timing_information", False), ("record_timing_filepath", "/tmp/traj_timing.txt"),
    ("save_total_state", False), ("filepath_est", "/tmp/ov_estimate.txt"), ("filepath_std", "/tmp/ov_estimate_std.txt"),
    ("filepath_gt", "/tmp/ov_groundtruth.txt"),
    ("use_klt", True), ("num_pts", 200), ("fast_threshold", 20), ("grid_x", 5), ("grid_y", 5), ("min_px_dist", 10),
    ("knn_ratio", 0.70), ("track_frequency", 21.0), ("downsample_cameras", False), ("num_opencv_threads", 4),
    ("histogram_method", "HISTOGRAM"), ("use_aruco", False), ("num_aruco", 1024), ("downsize_aruco", True),
    ("up_msckf_sigma_px", 1), ("up_msckf_chi2_multipler", 1), ("up_slam_sigma_px", 1), ("up_slam_chi2_multipler", 1),
    ("up_aruco_sigma_px", 1), ("up_aruco_chi2_multipler", 1), ("use_mask", False),
)

_I3 = np.eye(3).tolist()


def _rows(T: np.ndarray) -> list[list[float]]:
    return [[float(x) + 0.0 for x in row] for row in np.asarray(T, float)]


def openvins_files(rig: Rig, label: str = "<rig>") -> Export:
    imu = targets.first_imu(rig, label, FMT)
    order = kalibr_order(rig)
    cams = [rig.camera(n) for n in order]
    targets.posed(cams, label, FMT)
    index = {n: i for i, n in enumerate(order)}
    overlaps = camera_overlaps(rig, order)
    warnings: list[str] = []
    _, w = targets.one_offset(cams, TARGET, "cam0's timeshift_cam_imu")
    warnings += w
    head = targets.header(rig, label, TARGET)
    chain: list[tuple[str, object]] = [("#", "\n".join(head + [
        f"T_imu_cam maps camera points into IMU {imu.name}'s frame (OpenVINS's R_CtoI, p_CinI), metres.",
        "timeshift_cam_imu: t_imu = t_cam + timeshift_cam_imu, seconds (OpenVINS reads cam0's).",
        "Cameras: " + ", ".join(f"cam{i} = {n}" for i, n in enumerate(order)) + "."]))]
    for i, cam in enumerate(cams):
        m = cam.intrinsics
        if m.model == "fisheye":
            dmodel, coeffs = "equidistant", targets.kb4(cam)
        else:
            dmodel = "radtan"
            coeffs, warning = targets.pinhole_coeffs(cam, 4, label, "OpenVINS's radtan model")
            warnings += [warning] if warning else []
        chain.append((f"cam{i}", {
            "T_imu_cam": _rows(T_imu_cam(imu.T_body_imu, cam.T_body_cam)),
            "cam_overlaps": sorted(index[o] for o in overlaps[cam.name]),
            "camera_model": "pinhole",
            "distortion_coeffs": list(coeffs),
            "distortion_model": dmodel,
            "intrinsics": [float(m.fx), float(m.fy), float(m.cx), float(m.cy)],
            "resolution": [int(m.width), int(m.height)],
            "rostopic": f"/{cam.name}/image_raw",
            "timeshift_cam_imu": float(cam.time_offset_s or 0.0),
            "rigcal_name": cam.name,
        }))
    imu_doc = [("#", "\n".join(head + [f"IMU {imu.name}: Kalibr's continuous-time noise densities; T_i_b identity "
                                       "(OpenVINS's body is this IMU)."])),
               ("imu0", {"T_i_b": _rows(np.eye(4)),
                         "accelerometer_noise_density": float(imu.accelerometer_noise_density),
                         "accelerometer_random_walk": float(imu.accelerometer_random_walk),
                         "gyroscope_noise_density": float(imu.gyroscope_noise_density),
                         "gyroscope_random_walk": float(imu.gyroscope_random_walk),
                         "rostopic": f"/{imu.name}", "time_offset": 0.0, "update_rate": float(imu.update_rate),
                         "model": "kalibr", "Tw": _I3, "R_IMUtoGYRO": _I3, "Ta": _I3, "R_IMUtoACC": _I3,
                         "Tg": np.zeros((3, 3)).tolist(), "rigcal_name": imu.name})]
    stereo = len(order) >= 2 and any({p.left, p.right} == {order[0], order[1]} for p in rig.stereo_pairs)
    config = [("#", "\n".join(head + ["The sensor keys come from the rig; the others are OpenVINS's EuRoC values "
                                      "(config/euroc_mav/estimator_config.yaml): tune them for your platform."])),
              ("use_stereo", stereo), ("max_cameras", len(order)), *ESTIMATOR_DEFAULTS,
              ("relative_config_imu", "kalibr_imu_chain.yaml"), ("relative_config_imucam", "kalibr_imucam_chain.yaml")]
    files = {"estimator_config.yaml": cv_yaml(config), "kalibr_imu_chain.yaml": cv_yaml(imu_doc),
             "kalibr_imucam_chain.yaml": cv_yaml(chain)}
    summary = tuple(f"cam{i} = {n}" for i, n in enumerate(order)) + (f"imu0 = {imu.name}",)
    return Export(files, tuple(warnings), summary)
