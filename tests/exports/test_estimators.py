"""The estimator and autopilot exports (openvins, vins, orbslam3, basalt, px4, ardupilot):
read back by their consumers' parsers (cv2.FileStorage, json, pymavlink), golden against
the EuRoC files those projects ship, round trips to 1e-9, fisheye pairs, rigs without an
IMU, and the bad-input paths (exit 2, one line, nothing written).

EuRoC numbers below are copied as printed in (commit where the index named one):
* OpenVINS  rpng/open_vins config/euroc_mav/kalibr_imucam_chain.yaml (14211e2a),
  kalibr_imu_chain.yaml and estimator_config.yaml (69488123);
* VINS-Fusion  HKUST-Aerial-Robotics/VINS-Fusion config/euroc/euroc_stereo_imu_config.yaml
  and cam0_pinhole.yaml (939f0128);
* ORB-SLAM3  UZ-SLAMLab/ORB_SLAM3 Examples/Stereo-Inertial/EuRoC.yaml of release v1.0
  (File.version "1.0"; Stereo.T_c1_c2 as printed there, the same digits appear in the
  forks indexed; the key list and types from src/Settings.cc at 1464d8fe);
* basalt  VladyslavUsenko/basalt data/t265_kb4_calib.json (796d3a58) for the layout.
All three estimators' EuRoC files copy EuRoC's own calibration (tests/golden/euroc-reference.yaml).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.commands import export as export_command
from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel
from rigcal.core.rig import Rig, load_rig, parse_rig
from rigcal.exports import frames
from rigcal.exports.autopilot import VISO_ORIENTS, ardupilot_params, px4_params, viso_orient
from rigcal.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "tests" / "golden"
EUROC = GOLDEN / "euroc-reference.yaml"
IMU_RIG = GOLDEN / "drone-stereo-back-imu-calibrated.yaml"  # 3 cameras, clock offsets, an IMU
NO_IMU_RIG = GOLDEN / "drone-stereo-back-calibrated.yaml"

# EuRoC's T_BS (camera -> IMU), as OpenVINS (T_imu_cam), VINS-Fusion (body_T_cam0/1) and
# ORB-SLAM3 (IMU.T_b_c1) print it.
EUROC_T_IMU_CAM0 = [[0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
                    [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
                    [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
                    [0.0, 0.0, 0.0, 1.0]]
EUROC_T_IMU_CAM1 = [[0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556],
                    [0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024],
                    [-0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038],
                    [0.0, 0.0, 0.0, 1.0]]
EUROC_INTRINSICS = {0: [458.654, 457.296, 367.215, 248.375], 1: [457.587, 456.134, 379.999, 255.238]}
EUROC_DISTORTION = {0: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
                    1: [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]}
# ORB-SLAM3 v1.0 Examples/Stereo-Inertial/EuRoC.yaml: Stereo.T_c1_c2 (camera 2 -> camera 1).
ORB_T_C1_C2 = [[0.999997256477797, -0.002317135723275, -0.000343393120620, 0.110074137800478],
               [0.002312067192432, 0.999898048507103, -0.014090668452683, -0.000156612054392],
               [0.000376008102320, 0.014089835846691, 0.999900662638082, 0.000889382785432],
               [0.0, 0.0, 0.0, 1.0]]
ORB_IMU = {"IMU.NoiseGyro": (1.7e-4, 2), "IMU.NoiseAcc": (2.0000e-3, 5), "IMU.GyroWalk": (1.9393e-05, 5),
           "IMU.AccWalk": (3.0000e-03, 5), "IMU.Frequency": (200.0, 3)}  # value as printed, significant digits
# The EuRoC T_BS are printed to 12 significant digits: products of them agree to ~1e-12.
PRINTED = 1e-12
# ORB-SLAM3 stores its transforms as float32 (dt: f): 2^-24 relative, ~6e-8 on unit entries.
FLOAT32 = 1.2e-7

# Keys each consumer's reader requires, with the kind of cv::FileNode it demands.
OPENVINS_CAM_KEYS = {"T_imu_cam", "cam_overlaps", "camera_model", "distortion_coeffs", "distortion_model",
                     "intrinsics", "resolution", "rostopic"}
OPENVINS_IMU_KEYS = {"T_i_b", "accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                     "gyroscope_random_walk", "rostopic", "time_offset", "update_rate", "model", "Tw", "R_IMUtoGYRO",
                     "Ta", "R_IMUtoACC", "Tg"}
OPENVINS_ESTIMATOR_KEYS = {  # every key of config/euroc_mav/estimator_config.yaml at 69488123
    "verbosity", "use_fej", "integration", "use_stereo", "max_cameras", "calib_cam_extrinsics", "calib_cam_intrinsics",
    "calib_cam_timeoffset", "calib_imu_intrinsics", "calib_imu_g_sensitivity", "max_clones", "max_slam",
    "max_slam_in_update", "max_msckf_in_update", "dt_slam_delay", "gravity_mag", "feat_rep_msckf", "feat_rep_slam",
    "feat_rep_aruco", "try_zupt", "zupt_chi2_multipler", "zupt_max_velocity", "zupt_noise_multiplier",
    "zupt_max_disparity", "zupt_only_at_beginning", "init_window_time", "init_imu_thresh", "init_max_disparity",
    "init_max_features", "init_dyn_use", "init_dyn_mle_opt_calib", "init_dyn_mle_max_iter", "init_dyn_mle_max_time",
    "init_dyn_mle_max_threads", "init_dyn_num_pose", "init_dyn_min_deg", "init_dyn_inflation_ori",
    "init_dyn_inflation_vel", "init_dyn_inflation_bg", "init_dyn_inflation_ba", "init_dyn_min_rec_cond",
    "init_dyn_bias_g", "init_dyn_bias_a", "record_timing_information", "record_timing_filepath", "save_total_state",
    "filepath_est", "filepath_std", "filepath_gt", "use_klt", "num_pts", "fast_threshold", "grid_x", "grid_y",
    "min_px_dist", "knn_ratio", "track_frequency", "downsample_cameras", "num_opencv_threads", "histogram_method",
    "use_aruco", "num_aruco", "downsize_aruco", "up_msckf_sigma_px", "up_msckf_chi2_multipler", "up_slam_sigma_px",
    "up_slam_chi2_multipler", "up_aruco_sigma_px", "up_aruco_chi2_multipler", "use_mask", "relative_config_imu",
    "relative_config_imucam"}
# VINS-Fusion's readParameters (vins_estimator/src/estimator/parameters.cpp) for a stereo-IMU config.
VINS_INT_KEYS = ("imu", "num_of_cam", "max_cnt", "min_dist", "show_track", "flow_back", "multiple_thread",
                 "max_num_iterations", "estimate_extrinsic", "estimate_td", "image_width", "image_height", "fisheye")
VINS_REAL_KEYS = ("F_threshold", "acc_n", "acc_w", "gyr_n", "gyr_w", "g_norm", "max_solver_time", "keyframe_parallax",
                  "td")
VINS_STRING_KEYS = ("image0_topic", "image1_topic", "imu_topic", "output_path", "cam0_calib", "cam1_calib")
# ORB-SLAM3's Settings (src/Settings.cc) for IMU_STEREO with a PinHole pair: readParameter<int> refuses a real.
ORB_INT_KEYS = ("Camera.width", "Camera.height", "Camera.fps", "Camera.RGB", "ORBextractor.nFeatures",
                "ORBextractor.nLevels", "ORBextractor.iniThFAST", "ORBextractor.minThFAST")
ORB_REAL_KEYS = tuple(f"Camera{i}.{k}" for i in (1, 2) for k in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")) + (
    "Stereo.ThDepth", "IMU.NoiseGyro", "IMU.NoiseAcc", "IMU.GyroWalk", "IMU.AccWalk", "IMU.Frequency",
    "ORBextractor.scaleFactor")
ORB_STRING_KEYS = ("File.version", "Camera.type")
# basalt data/t265_kb4_calib.json: value0's members and their JSON shape.
BASALT_LAYOUT = {"T_imu_cam": "poses", "intrinsics": "cameras", "resolution": "sizes", "calib_accel_bias": 9,
                 "calib_gyro_bias": 12, "imu_update_rate": "number", "accel_noise_std": 3, "gyro_noise_std": 3,
                 "accel_bias_std": 3, "gyro_bias_std": 3, "cam_time_offset_ns": "int", "vignette": "list"}
BASALT_POSE_KEYS = {"px", "py", "pz", "qx", "qy", "qz", "qw"}
BASALT_KB4_KEYS = {"fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"}
BASALT_RADTAN8_KEYS = {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "rpmax"}

# A forward fisheye pair (equidistant k1..k4) with an IMU turned off the body axes.
FISHEYE_IMU_RIG = """
rig: fisheye-imu
imus:
  imu0:
    position: [0.01, -0.004, 0.02]
    quaternion: [0.9999904807, 0.0021, -0.0034, 0.0017]
    update_rate: 400.0
    gyroscope_noise_density: 1.0e-4
    gyroscope_random_walk: 2.0e-5
    accelerometer_noise_density: 1.5e-3
    accelerometer_random_walk: 4.0e-4
cameras:
  fe_left:
    model: fisheye
    resolution: [800, 600]
    intrinsics: {fx: 279.0, fy: 280.5, cx: 399.0, cy: 301.0}
    distortion: [0.018, -0.004, 0.001, -0.0001]
    position: [0.12, 0.06, 0.0]
    axes: [-L, -U, F]
    time_offset_s: -0.0031
  fe_right:
    model: fisheye
    resolution: [800, 600]
    intrinsics: {fx: 280.0, fy: 281.0, cx: 401.0, cy: 298.0}
    distortion: [0.021, -0.006, 0.0012, -0.0002]
    position: [0.12, -0.06, 0.0]
    quaternion: [0.5031377884128648, -0.4999089374684695, 0.4979018139084399, -0.49903627505106535]
    time_offset_s: -0.0031
stereo_pairs:
  - [fe_left, fe_right]
"""


def cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def one_line_exit2(r) -> str:
    assert r.exit_code == 2, (r.exit_code, r.output)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rigcal: "), r.stderr
    assert "Traceback" not in r.output
    return lines[0]


@pytest.fixture(scope="module")
def euroc() -> Rig:
    return load_rig(EUROC)


@pytest.fixture(scope="module")
def fisheye() -> Rig:
    return parse_rig(FISHEYE_IMU_RIG, "fisheye-imu.yaml")


def export(rig_path: Path, fmt: str, out: Path, *extra) -> Path:
    r = cli("export", rig_path, "--format", fmt, "--out", out, *extra)
    assert r.exit_code == 0, r.output
    return out


def write_rig(rig_text: str, tmp_path: Path, name: str = "rig.yaml") -> Path:
    p = tmp_path / name
    p.write_text(rig_text)
    return p


# ----------------------------------------------------------------------------- cv::FileStorage reading


def fs_open(path: Path) -> cv2.FileStorage:
    text = path.read_text()
    assert text.startswith("%YAML:1.0\n"), f"{path.name}: cv::FileStorage needs %YAML:1.0 on the first line"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    return fs


def node_value(n: cv2.FileNode):
    """A FileNode as plain Python: mappings -> dict, sequences -> list, matrices -> ndarray."""
    if n.isMap():
        if "data" in n.keys() and "dt" in n.keys():
            return n.mat()
        return {k: node_value(n.getNode(k)) for k in n.keys()}
    if n.isSeq():
        return [node_value(n.at(i)) for i in range(n.size())]
    if n.isString():
        return n.string()
    if n.isInt():
        return int(n.real())
    if n.isReal():
        return n.real()
    if n.empty():
        return None
    return n.mat()


def fs_dict(path: Path) -> dict:
    fs = fs_open(path)
    root = fs.root()
    return {k: node_value(root.getNode(k)) for k in root.keys()}


def kinds_ok(fs: cv2.FileStorage, ints=(), reals=(), strings=()) -> None:
    for k in ints:
        assert fs.getNode(k).isInt(), f"{k}: the reader wants an integer"
    for k in reals:
        n = fs.getNode(k)
        assert n.isReal() or n.isInt(), f"{k}: missing or not a number"
    for k in strings:
        assert fs.getNode(k).isString(), f"{k}: the reader wants a string"


# ----------------------------------------------------------------------------- rebuilding rigs from the files


def model_from(kind: str, w: int, h: int, fx, fy, cx, cy, dist) -> CameraModel:
    return CameraModel(model=kind, width=int(w), height=int(h), fx=float(fx), fy=float(fy), cx=float(cx),
                       cy=float(cy), dist=tuple(float(x) for x in dist))


def assert_same_cameras(orig: Rig, back: dict, tol_T: float = 1e-9, tol_px: float = 1e-9, seed: int = 0) -> None:
    """back: name -> (CameraModel, T_body_cam); poses to tol_T, pixels of random seen points to tol_px."""
    rng = np.random.default_rng(seed)
    for name, (m, T) in back.items():
        cam = orig.camera(name)
        assert m.model == cam.intrinsics.model and m.resolution == cam.intrinsics.resolution, name
        assert np.abs(T - cam.T_body_cam).max() < tol_T, (name, np.abs(T - cam.T_body_cam).max())
        o = cam.intrinsics
        uv = rng.uniform([0, 0], [o.width - 1, o.height - 1], size=(500, 2))
        p_cam = o.unproject(uv) * rng.uniform(0.5, 20.0, size=(500, 1))
        uv_back, valid = m.project(p_cam)
        assert valid.all()
        assert np.abs(uv_back - uv).max() < tol_px, (name, np.abs(uv_back - uv).max())


def openvins_back(folder: Path, orig: Rig) -> dict:
    chain = fs_dict(folder / "kalibr_imucam_chain.yaml")
    T_body_imu = orig.imus[0].T_body_imu
    out = {}
    for key, c in chain.items():
        kind = "fisheye" if c["distortion_model"] == "equidistant" else "pinhole"
        m = model_from(kind, *c["resolution"], *c["intrinsics"], c["distortion_coeffs"])
        out[c["rigcal_name"]] = (m, T_body_imu @ np.array(c["T_imu_cam"], float))
    return out


def vins_back(folder: Path, orig: Rig) -> dict:
    (config,) = folder.glob("*_config.yaml")
    cfg = fs_dict(config)
    T_body_imu = orig.imus[0].T_body_imu if cfg["imu"] == 1 else np.eye(4)
    out = {}
    for i in range(cfg["num_of_cam"]):
        cam = fs_dict(folder / cfg[f"cam{i}_calib"])
        p = cam["projection_parameters"]
        if cam["model_type"] == "KANNALA_BRANDT":
            m = model_from("fisheye", cam["image_width"], cam["image_height"], p["mu"], p["mv"], p["u0"], p["v0"],
                           [p["k2"], p["k3"], p["k4"], p["k5"]])
        else:
            d = cam["distortion_parameters"]
            m = model_from("pinhole", cam["image_width"], cam["image_height"], p["fx"], p["fy"], p["cx"], p["cy"],
                           [d["k1"], d["k2"], d["p1"], d["p2"]])
        out[cam["camera_name"]] = (m, T_body_imu @ np.asarray(cfg[f"body_T_cam{i}"], float))
    return out


def basalt_back(path: Path, orig: Rig, names: list[str]) -> dict:
    v = json.loads(path.read_text())["value0"]
    T_body_imu = orig.imus[0].T_body_imu
    out = {}
    for name, pose, cam, (w, h) in zip(names, v["T_imu_cam"], v["intrinsics"], v["resolution"]):
        i = cam["intrinsics"]
        if cam["camera_type"] == "kb4":
            m = model_from("fisheye", w, h, i["fx"], i["fy"], i["cx"], i["cy"], [i["k1"], i["k2"], i["k3"], i["k4"]])
        else:
            d = [i[k] for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")]
            m = model_from("pinhole", w, h, i["fx"], i["fy"], i["cx"], i["cy"], d)
        out[name] = (m, T_body_imu @ frames.T_from_pose_xyzw(pose))
    return out


# ----------------------------------------------------------------------------- frames: known answers


def test_flu_frd_known_answers():
    assert np.array_equal(frames.p_frd([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
    assert np.array_equal(frames.p_frd([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    # A camera looking forward in FLU has its z axis along FRD's x and its x axis (image right) along FRD's y.
    R = frames.R_frd(geo.R_from_look("forward"))
    assert np.allclose(R, [[0, 0, 1], [1, 0, 0], [0, 1, 0]])
    assert np.allclose(frames.R_FRD_FLU @ frames.R_FRD_FLU, np.eye(3))


def test_quaternion_order_known_answers_and_round_trip():
    s = np.sqrt(0.5)
    Rz90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.allclose(frames.quat_xyzw(Rz90), [0.0, 0.0, s, s])
    assert np.allclose(frames.R_from_quat_xyzw([0.0, 0.0, s, s]), Rz90)
    rng = np.random.default_rng(3)
    for _ in range(20):
        T = geo.make_T(geo.R_from_rotvec(rng.normal(size=3)), rng.normal(size=3))
        back = frames.T_from_pose_xyzw(frames.pose_xyzw(T))
        assert np.abs(back - T).max() < 1e-14


def test_transform_directions_known_answers():
    # IMU 10 cm ahead of the body origin, turned 90 deg about z; a camera 10 cm left of the origin.
    T_body_imu = geo.make_T(geo.R_from_rotvec([0.0, 0.0, np.pi / 2]), [0.1, 0.0, 0.0])
    T_body_cam = geo.make_T(geo.R_from_look("forward"), [0.0, 0.1, 0.0])
    T = frames.T_imu_cam(T_body_imu, T_body_cam)
    # The camera's origin, seen from the IMU: body offset (-0.1, 0.1, 0) turned by -90 deg about z.
    assert np.allclose(T[:3, 3], [0.1, 0.1, 0.0])
    # Its optical axis (camera z) is body forward = the IMU's -y.
    assert np.allclose(T[:3, 2], [0.0, -1.0, 0.0])
    T12 = frames.T_cam_cam(T_body_cam, geo.make_T(geo.R_from_look("forward"), [0.0, -0.1, 0.0]))
    assert np.allclose(T12[:3, 3], [0.2, 0.0, 0.0])  # the right camera sits +x (image right) of the left


def test_clock_conventions_known_answers():
    assert frames.delay_ms(-0.00412) == pytest.approx(4.12, abs=1e-12)
    assert frames.delay_ms(0.005) == pytest.approx(-5.0, abs=1e-12)
    assert frames.offset_ns(-0.00412) == -4120000
    assert frames.offset_ns(0.0073101) == 7310100


@pytest.mark.parametrize("look, value", [("forward", 0), ("right", 2), ("backward", 4), ("left", 6), ("down", 25)])
def test_viso_orient_of_the_looks(look, value):
    orient, name, off = viso_orient(geo.make_T(geo.R_from_look(look), [0.0, 0.0, 0.0]))
    assert orient == value and off < 1e-9
    assert VISO_ORIENTS[value][0] == name


def test_viso_orient_up_is_pitch_90_with_the_image_top_backward():
    # ArduPilot's ROTATION_PITCH_90 turns the sensor's x (viewing) up and its z (image down) forward:
    # a camera with axes [-L, F, U]. rigcal's `look: up` has the image top forward instead, 180 deg away.
    orient, name, off = viso_orient(geo.make_T(geo.R_from_axes(["-L", "F", "U"]), [0.0, 0.0, 0.0]))
    assert (orient, name) == (24, "up") and off < 1e-9
    R_up = geo.R_from_look("up")
    assert geo.rotation_angle_deg(frames.R_frd(R_up) @ np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
                                  @ VISO_ORIENTS[24][1].T) > 179.0


# ----------------------------------------------------------------------------- EuRoC golden


def test_openvins_euroc_golden(tmp_path):
    out = export(EUROC, "openvins", tmp_path / "ov")
    chain = fs_dict(out / "kalibr_imucam_chain.yaml")
    assert list(chain) == ["cam0", "cam1"]
    for i, T_ref in ((0, EUROC_T_IMU_CAM0), (1, EUROC_T_IMU_CAM1)):
        c = chain[f"cam{i}"]
        assert OPENVINS_CAM_KEYS <= set(c)
        assert np.abs(np.array(c["T_imu_cam"]) - T_ref).max() < PRINTED
        assert c["intrinsics"] == pytest.approx(EUROC_INTRINSICS[i], abs=1e-12)
        assert c["distortion_coeffs"] == pytest.approx(EUROC_DISTORTION[i], abs=1e-15)
        assert (c["camera_model"], c["distortion_model"], c["resolution"]) == ("pinhole", "radtan", [752, 480])
        assert c["cam_overlaps"] == [1 - i]
        assert c["timeshift_cam_imu"] == 0.0
    imu = fs_dict(out / "kalibr_imu_chain.yaml")["imu0"]
    assert OPENVINS_IMU_KEYS <= set(imu)
    assert (imu["accelerometer_noise_density"], imu["accelerometer_random_walk"], imu["gyroscope_noise_density"],
            imu["gyroscope_random_walk"], imu["update_rate"]) == pytest.approx((2.0e-3, 3.0e-3, 1.6968e-4, 1.9393e-5,
                                                                               200.0), rel=1e-15)
    assert imu["model"] == "kalibr" and np.array_equal(np.array(imu["Tg"]), np.zeros((3, 3)))
    for k in ("Tw", "Ta", "R_IMUtoGYRO", "R_IMUtoACC", "T_i_b"):
        assert np.array_equal(np.array(imu[k]), np.eye(len(imu[k])))
    config = fs_dict(out / "estimator_config.yaml")
    assert OPENVINS_ESTIMATOR_KEYS <= set(config)
    assert (config["max_cameras"], config["use_stereo"]) == (2, 1)
    assert (config["relative_config_imu"], config["relative_config_imucam"]) == ("kalibr_imu_chain.yaml",
                                                                                  "kalibr_imucam_chain.yaml")


def test_vins_euroc_golden(tmp_path):
    out = export(EUROC, "vins", tmp_path / "vins")
    config = out / "euroc-mav_config.yaml"
    fs = fs_open(config)
    kinds_ok(fs, VINS_INT_KEYS, VINS_REAL_KEYS, VINS_STRING_KEYS)
    cfg = fs_dict(config)
    assert (cfg["imu"], cfg["num_of_cam"], cfg["image_width"], cfg["image_height"]) == (1, 2, 752, 480)
    assert np.abs(cfg["body_T_cam0"] - np.array(EUROC_T_IMU_CAM0)).max() < PRINTED
    assert np.abs(cfg["body_T_cam1"] - np.array(EUROC_T_IMU_CAM1)).max() < PRINTED
    assert cfg["body_T_cam0"].dtype == np.float64  # dt: d, as VINS-Fusion's file
    # VINS-Fusion's own cam0_pinhole.yaml holds its re-calibration (fx 461.70...), not EuRoC's: only its
    # layout is compared; the numbers are EuRoC's.
    for i in (0, 1):
        cam = fs_dict(out / cfg[f"cam{i}_calib"])
        assert set(cam) == {"model_type", "camera_name", "image_width", "image_height", "distortion_parameters",
                            "projection_parameters"}
        assert cam["model_type"] == "PINHOLE" and (cam["image_width"], cam["image_height"]) == (752, 480)
        p, d = cam["projection_parameters"], cam["distortion_parameters"]
        assert [p["fx"], p["fy"], p["cx"], p["cy"]] == pytest.approx(EUROC_INTRINSICS[i], abs=1e-12)
        assert [d["k1"], d["k2"], d["p1"], d["p2"]] == pytest.approx(EUROC_DISTORTION[i], abs=1e-15)
    assert (cfg["acc_n"], cfg["gyr_n"], cfg["acc_w"], cfg["gyr_w"]) == pytest.approx((2.0e-3, 1.6968e-4, 3.0e-3,
                                                                                     1.9393e-5), rel=1e-15)
    assert cfg["td"] == 0.0


def test_orbslam3_euroc_golden(tmp_path):
    out = export(EUROC, "orbslam3", tmp_path / "EuRoC.yaml")
    fs = fs_open(out)
    kinds_ok(fs, ORB_INT_KEYS, ORB_REAL_KEYS, ORB_STRING_KEYS)
    d = fs_dict(out)
    assert (d["File.version"], d["Camera.type"], d["Camera.width"], d["Camera.height"]) == ("1.0", "PinHole", 752, 480)
    for i in (0, 1):
        got = [d[f"Camera{i + 1}.{k}"] for k in ("fx", "fy", "cx", "cy")]
        assert got == pytest.approx(EUROC_INTRINSICS[i], abs=1e-12)
        got = [d[f"Camera{i + 1}.{k}"] for k in ("k1", "k2", "p1", "p2")]
        assert got == pytest.approx(EUROC_DISTORTION[i], abs=1e-15)
    assert "Camera1.k3" not in d  # EuRoC's cameras are radtan4; ORB-SLAM3 reads k3 only when present
    for key, ref in (("Stereo.T_c1_c2", ORB_T_C1_C2), ("IMU.T_b_c1", EUROC_T_IMU_CAM0)):
        M = d[key]
        assert M.dtype == np.float32, f"{key}: ORB-SLAM3 reads its transforms as float (dt: f)"
        assert np.abs(M - np.array(ref)).max() < FLOAT32, key
    for key, (printed, digits) in ORB_IMU.items():
        # to the printed precision: ORB-SLAM3 rounds EuRoC's gyroscope density 1.6968e-04 to 1.7e-04
        assert float(f"{d[key]:.{digits - 1}e}") == printed, key


def test_orbslam3_stereo_transform_is_exact_before_float32(euroc):
    # The double-precision T_c1_c2 agrees with ORB-SLAM3's 15 printed digits to the inputs' precision.
    T = frames.T_cam_cam(euroc.camera("cam0").T_body_cam, euroc.camera("cam1").T_body_cam)
    assert np.abs(T - np.array(ORB_T_C1_C2)).max() < PRINTED


def test_basalt_layout_is_the_shipped_one(tmp_path, fisheye):
    p = write_rig(FISHEYE_IMU_RIG, tmp_path)
    doc = json.loads(export(p, "basalt", tmp_path / "calib.json").read_text())
    assert list(doc)[0] == "value0"  # basalt's reader takes the first member
    v = doc["value0"]
    assert set(v) == set(BASALT_LAYOUT)
    for key, shape in BASALT_LAYOUT.items():
        if isinstance(shape, int):
            assert len(v[key]) == shape and all(isinstance(x, float) for x in v[key]), key
    assert isinstance(v["cam_time_offset_ns"], int) and isinstance(v["imu_update_rate"], float)
    assert v["cam_time_offset_ns"] == -3100000
    assert all(set(pose) == BASALT_POSE_KEYS for pose in v["T_imu_cam"])
    assert [c["camera_type"] for c in v["intrinsics"]] == ["kb4", "kb4"]
    assert all(set(c["intrinsics"]) == BASALT_KB4_KEYS for c in v["intrinsics"])
    assert v["resolution"] == [[800, 600], [800, 600]]
    assert v["accel_noise_std"] == [1.5e-3] * 3 and v["gyro_bias_std"] == [2.0e-5] * 3


def test_basalt_euroc_transforms_and_radtan8(tmp_path):
    v = json.loads(export(EUROC, "basalt", tmp_path / "calib.json").read_text())["value0"]
    for pose, ref in zip(v["T_imu_cam"], (EUROC_T_IMU_CAM0, EUROC_T_IMU_CAM1)):
        assert np.abs(frames.T_from_pose_xyzw(pose) - np.array(ref)).max() < PRINTED
    for i, c in enumerate(v["intrinsics"]):
        assert c["camera_type"] == "pinhole-radtan8" and set(c["intrinsics"]) == BASALT_RADTAN8_KEYS
        k = c["intrinsics"]
        assert [k["k1"], k["k2"], k["p1"], k["p2"]] == pytest.approx(EUROC_DISTORTION[i], abs=1e-15)
        assert [k["k3"], k["k4"], k["k5"], k["k6"]] == [0.0] * 4
        # EuRoC's k1, k2 keep r (1 + k1 r^2 + k2 r^4) increasing for every r: rigcal's limit, 20
        assert k["rpmax"] == 20.0


def test_basalt_rpmax_is_where_the_distortion_folds_back(tmp_path):
    # r (1 - 0.5 r^2) stops increasing at r = sqrt(2/3) = 0.8165; rigcal's search steps inwards of it.
    text = THINPRISM.replace("[-0.3, 0.1, 0.001, -0.001, -0.02, 0.01, 0.002, -0.001, 0.004, -0.002, 0.003, 0.001]",
                             "[-0.5, 0.0]")
    v = json.loads(export(write_rig(text, tmp_path), "basalt", tmp_path / "c.json").read_text())["value0"]
    assert 0.81 < v["intrinsics"][0]["intrinsics"]["rpmax"] <= np.sqrt(2.0 / 3.0)


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("rig_path", [IMU_RIG, EUROC, "fisheye"])
def test_openvins_round_trip(rig_path, tmp_path, fisheye):
    orig = fisheye if rig_path == "fisheye" else load_rig(rig_path)
    src = write_rig(FISHEYE_IMU_RIG, tmp_path) if rig_path == "fisheye" else rig_path
    out = export(src, "openvins", tmp_path / "ov")
    back = openvins_back(out, orig)
    assert set(back) == set(orig.names)
    assert_same_cameras(orig, back)


@pytest.mark.parametrize("rig_path", [IMU_RIG, EUROC, "fisheye", NO_IMU_RIG])
def test_vins_round_trip(rig_path, tmp_path, fisheye):
    orig = fisheye if rig_path == "fisheye" else load_rig(rig_path)
    src = write_rig(FISHEYE_IMU_RIG, tmp_path) if rig_path == "fisheye" else rig_path
    back = vins_back(export(src, "vins", tmp_path / "vins"), orig)
    pair = orig.stereo_pairs[0]
    assert list(back) == [pair.left, pair.right]
    assert_same_cameras(orig, back)


@pytest.mark.parametrize("rig_path", [IMU_RIG, EUROC, "fisheye"])
def test_basalt_round_trip(rig_path, tmp_path, fisheye):
    orig = fisheye if rig_path == "fisheye" else load_rig(rig_path)
    src = write_rig(FISHEYE_IMU_RIG, tmp_path) if rig_path == "fisheye" else rig_path
    from rigcal.exports.formats import kalibr_order

    back = basalt_back(export(src, "basalt", tmp_path / "c.json"), orig, kalibr_order(orig))
    assert set(back) == set(orig.names)
    assert_same_cameras(orig, back)


@pytest.mark.parametrize("rig_path", [IMU_RIG, "fisheye", NO_IMU_RIG])
def test_orbslam3_round_trip(rig_path, tmp_path, fisheye):
    """Intrinsics to 1e-9 px; transforms to float32 precision, which is all ORB-SLAM3 keeps."""
    orig = fisheye if rig_path == "fisheye" else load_rig(rig_path)
    src = write_rig(FISHEYE_IMU_RIG, tmp_path) if rig_path == "fisheye" else rig_path
    d = fs_dict(export(src, "orbslam3", tmp_path / "s.yaml"))
    pair = orig.stereo_pairs[0]
    left, right = orig.camera(pair.left), orig.camera(pair.right)
    kind = "fisheye" if d["Camera.type"] == "KannalaBrandt8" else "pinhole"
    names = ("k1", "k2", "k3", "k4") if kind == "fisheye" else ("k1", "k2", "p1", "p2", "k3")
    back = {}
    T_c1_c2 = np.asarray(d["Stereo.T_c1_c2"], float)
    for i, cam in enumerate((left, right), start=1):
        m = model_from(kind, d["Camera.width"], d["Camera.height"], *[d[f"Camera{i}.{k}"] for k in
                       ("fx", "fy", "cx", "cy")], [d[f"Camera{i}.{k}"] for k in names if f"Camera{i}.{k}" in d])
        T = left.T_body_cam if i == 1 else left.T_body_cam @ T_c1_c2
        back[cam.name] = (m, T)
    assert_same_cameras(orig, back, tol_T=FLOAT32)
    if orig.imus:
        T_body_c1 = orig.imus[0].T_body_imu @ np.asarray(d["IMU.T_b_c1"], float)
        assert np.abs(T_body_c1 - left.T_body_cam).max() < FLOAT32
    else:
        assert "IMU.T_b_c1" not in d and "IMU.NoiseGyro" not in d


def test_float32_tolerance_would_catch_a_wrong_direction(euroc):
    # The round-trip tolerances are far below what an inverted transform or a swapped camera changes.
    T = frames.T_cam_cam(euroc.camera("cam0").T_body_cam, euroc.camera("cam1").T_body_cam)
    assert np.abs(geo.inv_T(T) - T).max() > 1e4 * FLOAT32


# ----------------------------------------------------------------------------- autopilots


def read_qgc_params(path: Path) -> dict[str, tuple[float, int]]:
    out = {}
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        vehicle, comp, name, value, kind = line.split("\t")
        assert (vehicle, comp) == ("1", "1")
        out[name] = (float(value), int(kind))
    return out


def test_px4_positions_in_frd_and_delay_from_the_offset(tmp_path):
    rig = load_rig(IMU_RIG)
    p = read_qgc_params(export(IMU_RIG, "px4", tmp_path / "v.params", "--camera", "back"))
    t = rig.camera("back").T_body_cam[:3, 3]  # FLU (-0.1008, 0.0011, 0.0107)
    assert p["EKF2_EV_POS_X"] == (pytest.approx(t[0], abs=1e-15), 9)
    assert p["EKF2_EV_POS_Y"] == (pytest.approx(-t[1], abs=1e-15), 9)
    assert p["EKF2_EV_POS_Z"] == (pytest.approx(-t[2], abs=1e-15), 9)
    assert p["EKF2_EV_DELAY"] == (pytest.approx(4.12, abs=1e-12), 9)  # time_offset_s -0.00412
    p = read_qgc_params(export(NO_IMU_RIG, "px4", tmp_path / "n.params"))
    assert "EKF2_EV_DELAY" not in p  # no calibrated offset: the vehicle keeps its own value


def test_ardupilot_file_through_pymavlink(tmp_path):
    from pymavlink import mavparm  # the test extra installs it
    rig = load_rig(IMU_RIG)
    out = export(IMU_RIG, "ardupilot", tmp_path / "v.param", "--camera", "back")
    params = mavparm.MAVParmDict()
    assert params.load(str(out))
    t = rig.camera("back").T_body_cam[:3, 3]
    assert params["VISO_POS_X"] == pytest.approx(t[0], abs=1e-15)
    assert params["VISO_POS_Y"] == pytest.approx(-t[1], abs=1e-15)
    assert params["VISO_POS_Z"] == pytest.approx(-t[2], abs=1e-15)
    assert params["VISO_ORIENT"] == 4  # the back camera looks backward
    assert params["VISO_DELAY_MS"] == 4
    assert set(params) == {"VISO_POS_X", "VISO_POS_Y", "VISO_POS_Z", "VISO_ORIENT", "VISO_DELAY_MS"}
    down = mavparm.MAVParmDict()
    assert down.load(str(export(ROOT / "rigs" / "down-nav.yaml", "ardupilot", tmp_path / "d.param")))
    assert down["VISO_ORIENT"] == 25 and down["VISO_POS_Z"] == pytest.approx(0.05, abs=1e-15)
    assert "VISO_DELAY_MS" not in down


def test_autopilot_extra_parameters_hook():
    rig = load_rig(IMU_RIG)
    text = px4_params(rig, "r.yaml", extra={"CAL_MAG0_XOFF": 0.25, "CAL_MAG0_ID": 7}).files["rigcal.params"]
    assert "1\t1\tCAL_MAG0_XOFF\t0.25\t9" in text.splitlines()
    assert "1\t1\tCAL_MAG0_ID\t7\t6" in text.splitlines()
    text = ardupilot_params(rig, "r.yaml", extra={"COMPASS_OFS_X": -12.5}).files["rigcal.param"]
    assert text.splitlines()[-1] == "COMPASS_OFS_X,-12.5"
    with pytest.raises(InputError, match="VISO_POS_X"):
        ardupilot_params(rig, "r.yaml", extra={"VISO_POS_X": 1.0})
    with pytest.raises(InputError, match="compass_lower"):
        ardupilot_params(rig, "r.yaml", extra={"compass_lower": 1.0})


# ----------------------------------------------------------------------------- every file states its frames


@pytest.mark.parametrize("fmt", export_command.TARGET_FORMATS)
def test_every_file_states_frames_version_and_rig(fmt, tmp_path):
    from rigcal import __version__

    result = export_command.build(load_rig(IMU_RIG), fmt, "drone.yaml")
    for name, text in result.files.items():
        if name.endswith(".json"):
            comment = json.loads(text)["comment"]
        else:
            comment = "\n".join(line for line in text.splitlines() if line.startswith("#"))
        assert f"rigcal {__version__}" in comment and "'drone-stereo-back' (drone.yaml)" in comment, name
        assert "FLU" in comment and "maps" in comment or "FRD" in comment, name


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("fmt", ["openvins", "basalt"])
def test_formats_needing_an_imu_refuse_a_rig_without_one(fmt, tmp_path):
    out = tmp_path / "out"
    msg = one_line_exit2(cli("export", NO_IMU_RIG, "--format", fmt, "--out", out))
    assert "imus" in msg and f"--format {fmt} needs a rig with an IMU" in msg
    assert not out.exists()


@pytest.mark.parametrize("fmt", ["vins", "orbslam3", "px4", "ardupilot"])
def test_formats_without_an_imu_still_export(fmt, tmp_path):
    assert cli("export", NO_IMU_RIG, "--format", fmt, "--out", tmp_path / "out").exit_code == 0


THINPRISM = """
rig: thin
imus:
  imu0: {position: [0, 0, 0], axes: [F, L, U], update_rate: 200, gyroscope_noise_density: 1.0e-4,
         gyroscope_random_walk: 1.0e-5, accelerometer_noise_density: 1.0e-3, accelerometer_random_walk: 1.0e-4}
cameras:
  wide:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}
    distortion: [-0.3, 0.1, 0.001, -0.001, -0.02, 0.01, 0.002, -0.001, 0.004, -0.002, 0.003, 0.001]
    position: [0.1, 0.0, 0.0]
    look: forward
"""


@pytest.mark.parametrize("fmt", ["openvins", "vins", "orbslam3", "basalt"])
def test_a_model_the_target_cannot_hold_is_refused(fmt, tmp_path):
    src = write_rig(THINPRISM, tmp_path)
    out = tmp_path / "out"
    msg = one_line_exit2(cli("export", src, "--format", fmt, "--out", out))
    assert "cameras.wide.distortion" in msg and "thinprism12" in msg and "px" in msg
    assert not out.exists()


def test_orbslam3_refuses_a_mixed_pair(tmp_path):
    text = FISHEYE_IMU_RIG.replace("""  fe_right:
    model: fisheye""", """  fe_right:
    model: pinhole""").replace("distortion: [0.021, -0.006, 0.0012, -0.0002]", "distortion: [0.021, -0.006]")
    out = tmp_path / "s.yaml"
    msg = one_line_exit2(cli("export", write_rig(text, tmp_path), "--format", "orbslam3", "--out", out))
    assert "fe_right" in msg and "Camera.type" in msg and "fisheye" in msg and "pinhole" in msg
    assert not out.exists()


def test_ardupilot_refuses_a_camera_between_the_six_directions(tmp_path):
    R = geo.R_from_look("forward") @ geo.R_from_rotvec([np.radians(30.0), 0.0, 0.0])  # 30 deg down-tilted
    rows = "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in r) + "]" for r in R) + "]"
    text = f"""
rig: tilted
cameras:
  cam:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {{fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}}
    distortion: [0.0, 0.0]
    position: [0.1, 0.0, 0.0]
    rotation: {rows}
"""
    out = tmp_path / "v.param"
    msg = one_line_exit2(cli("export", write_rig(text, tmp_path), "--format", "ardupilot", "--out", out))
    assert "VISO_ORIENT" in msg and "30.0 deg" in msg and "cameras.cam" in msg
    assert not out.exists()
    assert cli("export", tmp_path / "rig.yaml", "--format", "px4", "--out", tmp_path / "p.params").exit_code == 0


def test_camera_option_errors(tmp_path):
    msg = one_line_exit2(cli("export", IMU_RIG, "--format", "px4", "--out", tmp_path / "a", "--camera", "nope"))
    assert "--camera" in msg and "front_left" in msg
    msg = one_line_exit2(cli("export", IMU_RIG, "--format", "openvins", "--out", tmp_path / "b", "--camera", "back"))
    assert "--camera applies to" in msg
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_vins_camera_option_picks_a_single_camera(tmp_path):
    cfg = fs_dict(export(IMU_RIG, "vins", tmp_path / "v", "--camera", "back") / "drone-stereo-back_config.yaml")
    assert cfg["num_of_cam"] == 1 and cfg["cam0_calib"] == "back_pinhole.yaml" and "body_T_cam1" not in cfg
    assert cfg["td"] == pytest.approx(-0.00412, abs=1e-15)


def test_a_camera_without_a_pose_is_refused(tmp_path):
    text = """
rig: unposed
cameras:
  cam:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}
    distortion: [0.0, 0.0]
"""
    for fmt in ("px4", "ardupilot", "vins", "orbslam3"):
        out = tmp_path / f"out-{fmt}"
        msg = one_line_exit2(cli("export", write_rig(text, tmp_path), "--format", fmt, "--out", out))
        assert "cameras.cam: no pose" in msg and fmt in msg
        assert not out.exists()


def test_orbslam3_warns_about_its_camera2_fisheye_coefficients(fisheye):
    from rigcal.exports.orbslam3 import orbslam3_file

    result = orbslam3_file(fisheye, "fisheye-imu.yaml")
    assert any("Camera1.k1..k4" in w and "fe_right" in w for w in result.warnings)
    d = {}
    fs = cv2.FileStorage(result.files["orbslam3.yaml"], cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    for i in (1, 2):
        d[i] = [fs.getNode(f"Camera{i}.k{j}").real() for j in range(1, 5)]
    assert d[1] == [0.018, -0.004, 0.001, -0.0001] and d[2] == [0.021, -0.006, 0.0012, -0.0002]
    assert fs.getNode("Camera2.overlappingEnd").isInt() and int(fs.getNode("Camera2.overlappingEnd").real()) == 799
