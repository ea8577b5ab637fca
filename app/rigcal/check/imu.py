"""The camera-IMU part of `rigcal check`: every camera's pose relative to the IMU and its
clock offset, re-estimated from the new recording and tested against the rig.

The re-estimate is `rigcal calibrate`'s camera-IMU step (rigcal.imucal.step.calibrate_imu)
on the new recording, after its camera-only step, with the intrinsics held at the rig's
(its `--imu-intrinsics auto` on a camera calibration): each camera's T_imu_cam and
time_offset_s with their 1-sigma (the estimator's, raised where the recording's halves
disagree more). Per camera two chi-square tests with the same machinery as the camera part
(decide.chi2_test, the check's Sidak level, decide.detectable):

* pose relative to the IMU: delta = [rotvec(R_new R_old^T), t_new - t_old] of T_body_cam with
  the new camera placed by the rig's own T_body_imu (the IMU stays the reference), 6 dof,
  covariance = the rig's variances + the new estimate's, both per axis (neither keeps the
  correlations) and turned from the IMU's axes into the body's;
* clock offset: the change of time_offset_s (t_imu = t_cam + time_offset_s), 1 dof,
  variance = the rig's + the new estimate's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigcal.check import decide
from rigcal.check.estimate import with_subset
from rigcal.check.verdict import ChiSquare, decide_test
from rigcal.core.rig import Rig
from rigcal.errors import CalibrationError, DatasetError


@dataclass(frozen=True)
class ImuEstimate:
    """The new recording's camera-IMU estimate: the IMU's name, the cameras (rig order of
    those estimated), per camera T_imu_cam (C, 4, 4), time_offset_s (C,), the 1-sigma of
    the pose (C, 6: rotation rad about the IMU's axes, position m) and of the offset (C,) s,
    and seconds."""

    imu: str
    names: tuple[str, ...]
    T_imu_cam: np.ndarray
    time_offset_s: np.ndarray
    sigma_pose: np.ndarray
    sigma_offset: np.ndarray
    seconds: float


def reference_imu(rig: Rig) -> str | None:
    """The IMU the rig's cameras were calibrated against (calibration.camera_imu.imu) when
    every camera carries a clock offset and its sigma (calibration.sigma.time_offset_ms);
    None when the rig is not a camera-IMU calibration."""
    name = ((rig.calibration or {}).get("camera_imu") or {}).get("imu")
    if not name or name not in [i.name for i in rig.imus]:
        return None
    for c in rig.cameras:
        sig = (c.calibration or {}).get("sigma") or {}
        if c.time_offset_s is None or not isinstance(sig.get("time_offset_ms"), (int, float)):
            return None
    return name


def estimate_camera_imu(dataset: Path, rig: Rig, imu_name: str, views: list, names: list[str], corners: dict,
                        faces: dict) -> ImuEstimate:
    """The camera-IMU estimate of the cameras `names` from the recording (its imu/ read and
    checked as calibrate does), the intrinsics held at the rig's. DatasetError for a
    recording whose IMU data do not fit; CalibrationError when it cannot determine them."""
    from rigcal.camcal.pipeline import calibrate_views
    from rigcal.data.dataset import list_dataset
    from rigcal.data.imu_csv import check_motion_dataset
    from rigcal.imucal.estimator import Settings
    from rigcal.imucal.step import MIN_KNOTS, Options, calibrate_imu

    t0 = time.perf_counter()
    sub = with_subset(rig, names)
    motion = check_motion_dataset(dataset, sub, list_dataset(dataset, names), MIN_KNOTS * Settings().knot_dt)
    if imu_name not in motion.imus:
        raise DatasetError(f"{dataset / 'imu'}: no {imu_name}.csv, the IMU the rig's cameras were calibrated against")
    used = [v for v in views if v.camera in names]
    cal = calibrate_views(used, sub, corners, fix_intrinsics=True, reference="aligned", faces=faces)
    opts = Options(imu=imu_name, imu_intrinsics="held", intrinsics_from_rig=True)
    res = calibrate_imu(cal, motion.imus[imu_name], rig.imu(imu_name), opts, [float(faces[b]) for b in cal.boards],
                        {n: rig.camera(n).line_delay_s or 0.0 for n in names},
                        {n: rig.camera(n).time_offset_s or 0.0 for n in names},
                        image_t_ns=getattr(motion, "frame_t_ns", None))
    order = [list(cal.cam_names).index(n) for n in names]
    est = res.result
    return ImuEstimate(imu=imu_name, names=tuple(names), T_imu_cam=np.asarray(est.T_imu_cam)[order],
                       time_offset_s=np.asarray(est.time_offset_s, float)[order],
                       sigma_pose=np.asarray(res.sigma["pose"], float)[order],
                       sigma_offset=np.asarray(res.sigma["offset"], float)[order], seconds=time.perf_counter() - t0)


@dataclass(frozen=True)
class ImuCheck:
    """One camera against the IMU: its pose change in the rig's body frame with 1-sigma
    (rotation about body F, L, U deg; position along F, L, U mm), the pose test and its
    smallest detectable change per axis (deg, mm); the clock offset's change (ms, new - rig),
    its 1-sigma, its test and smallest detectable change (ms)."""

    imu: str
    rotation_deg: np.ndarray
    rotation_sigma_deg: np.ndarray
    translation_mm: np.ndarray
    translation_sigma_mm: np.ndarray
    pose_test: ChiSquare
    detectable_rotation_deg: np.ndarray
    detectable_translation_mm: np.ndarray
    offset_ms: float
    offset_sigma_ms: float
    offset_test: ChiSquare
    detectable_offset_ms: float


def body_covariance(R_body_imu: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """(6, 6) covariance in body axes of a pose change whose 1-sigma sd (6,) [rotation about,
    position along the IMU's axes] are independent: R diag R^T per 3-block."""
    cov = np.zeros((6, 6))
    for k in (0, 3):
        cov[k:k + 3, k:k + 3] = R_body_imu @ np.diag(sd[k:k + 3] ** 2) @ R_body_imu.T
    return cov


def rig_sigmas(rig: Rig, name: str) -> tuple[np.ndarray, float]:
    """(the rig's 1-sigma of a camera's pose (6,) [rad, m] relative to its IMU, of its clock offset s)."""
    s = rig.camera(name).calibration["sigma"]
    return (np.concatenate([np.radians(s["rotation_deg"]), np.asarray(s["position_mm"], float) / 1000.0]),
            float(s["time_offset_ms"]) / 1000.0)


def check_camera(rig: Rig, est: ImuEstimate, name: str, level_each: float) -> ImuCheck:
    """Camera `name`'s pose relative to the IMU and clock offset tested against the rig (module text)."""
    k = est.names.index(name)
    cam = rig.camera(name)
    T_body_imu = rig.imu(est.imu).T_body_imu
    R = T_body_imu[:3, :3]
    delta = decide.pose_change(T_body_imu @ est.T_imu_cam[k], cam.T_body_cam)
    sd_old, so_old = rig_sigmas(rig, name)
    cov = body_covariance(R, sd_old) + body_covariance(R, est.sigma_pose[k])
    stat, p = decide.chi2_test(delta, cov)
    det = decide.detectable(cov, level_each)
    sd = np.sqrt(np.diag(cov))
    d_off = float(est.time_offset_s[k] - (cam.time_offset_s or 0.0))
    var_off = so_old ** 2 + float(est.sigma_offset[k]) ** 2
    o_stat, o_p = decide.chi2_test(np.array([d_off]), np.array([[var_off]]))
    o_det = decide.detectable(np.array([[var_off]]), level_each)[0]
    return ImuCheck(imu=est.imu, rotation_deg=np.degrees(delta[:3]), rotation_sigma_deg=np.degrees(sd[:3]),
                    translation_mm=1000 * delta[3:], translation_sigma_mm=1000 * sd[3:],
                    pose_test=decide_test(stat, 6, p, level_each),
                    detectable_rotation_deg=np.degrees(det[:3]), detectable_translation_mm=1000 * det[3:],
                    offset_ms=1000 * d_off, offset_sigma_ms=1000 * np.sqrt(var_off),
                    offset_test=decide_test(o_stat, 1, o_p, level_each), detectable_offset_ms=1000 * float(o_det))


def try_estimate(dataset: Path, rig: Rig, imu_name: str, views: list, names: list[str], corners: dict,
                 faces: dict) -> tuple[ImuEstimate | None, str | None]:
    """(estimate_camera_imu or None, why not): a recording that cannot determine the
    camera-IMU calibration leaves the cameras' IMU part undetermined, not an error."""
    if not names:
        return None, "no camera has enough views"
    try:
        return estimate_camera_imu(dataset, rig, imu_name, views, names, corners, faces), None
    except CalibrationError as e:
        return None, str(e)
