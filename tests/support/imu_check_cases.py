"""Camera-IMU recordings for `rigcal check`, fast: `simulate --scene imu`'s motion, boards,
frame timing and IMU streams (rigcal.sim.imu_scene), but the corners projected (global
shutter, at each frame's IMU-clock time) with Gaussian noise and written as corners/<camera>.csv
instead of rendered images: seconds instead of minutes. The true rig is given exactly (no
errors drawn), so a recording of a changed copy differs from the base one only by the change.
Used by tests/check/test_check_imu.py and bench/check.py.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.io import atomic_dir
from rigcal.core.rig import Rig, dump_rig, load_rig
from rigcal.core.target import dump_target
from rigcal.data.imu_csv import imu_csv
from rigcal.sim import imu_model
from rigcal.sim import imu_scene as isc
from tests.support.check_cases import changed_rig

RIG = Path(__file__).resolve().parents[2] / "rigs" / "drone-stereo-back-imu.yaml"
MIN_CORNERS = 8  # a view with fewer corners in the image is dropped (as detection would)


def true_rig(truth_seed: int = 1, time_offset_ms: float = 3.0) -> Rig:
    """drone-stereo-back-imu with simulate's mount and lens errors and clock offsets drawn for this seed."""
    pert = {"mount_error_mm": 5.0, "mount_error_deg": 1.0, "focal_error": 0.02}
    return isc.true_rig_for_motion(load_rig(RIG), truth_seed, time_offset_ms, pert)


def changed_imu_rig(rig: Rig, camera: str, rotate_deg: float = 0.0, axis: str = "U", offset_ms: float = 0.0) -> Rig:
    """The rig with one camera turned by rotate_deg about body `axis` (relative to the IMU,
    which stays) and its clock offset changed by offset_ms."""
    turned = changed_rig(rig, camera, rotate_deg=rotate_deg, axis=axis)
    return turned.with_cameras([replace(c, time_offset_s=(c.time_offset_s or 0.0) + offset_ms / 1000.0)
                                if c.name == camera else c for c in turned.cameras])


def _views(cam, T_world_body: np.ndarray, T_world_board: np.ndarray, boards, rng, sigma_px: float) -> list[str]:
    rows = []
    m = cam.intrinsics
    for bi, (b, T_wb) in enumerate(zip(boards, T_world_board)):
        T_cam_board = geo.inv_T(T_world_body @ cam.T_body_cam) @ T_wb
        if T_cam_board[2, 2] < 0.2:  # board z points into the printed face: away from a camera that sees it
            continue
        p = geo.transform(T_cam_board, b.corners)
        uv, ok = m.project(p)
        ok &= (p[:, 2] > 0.1) & (uv[:, 0] > 2) & (uv[:, 1] > 2) & (uv[:, 0] < m.width - 3) & (uv[:, 1] < m.height - 3)
        if ok.sum() < MIN_CORNERS:
            continue
        uv = uv + rng.normal(0.0, sigma_px, uv.shape)
        rows += [(b.name, int(k), float(u), float(v)) for k, (u, v) in zip(np.flatnonzero(ok), uv[ok])]
    return rows


def record(truth: Rig, out: Path, duration: float = 6.0, camera_rate: float = 10.0, seed: int = 0,
           sigma_px: float = 0.3, declared: Rig | None = None, free_running: bool = False, with_imu: bool = True,
           motion_scale: float = 1.0) -> Path:
    """A motion recording of exactly `truth`: imu/<imu>.csv, corners/<camera>.csv (stems = each
    camera's own clock, ns), target.yaml and rig.yaml (`declared`, default the truth).
    free_running: each camera on its own phase and rate (simulate --free-running's schedule);
    with_imu False: no imu/ and a rig.yaml without IMUs; motion_scale multiplies the motion's
    amplitudes (imu_model.hand_held_trajectory)."""
    traj = imu_model.hand_held_trajectory(np.random.default_rng([seed, 2]), scale=motion_scale)
    centre = geo.make_T(geo.R_from_rotvec(np.array([0.0, 0.0, traj.ypr0[0]])), traj.p0)
    target, T_world_board = isc.plan_boards(truth, centre)
    timing = isc.frame_timing(truth, duration, camera_rate, free_running=free_running, seed=seed)
    t_end = duration + 2 * isc.MARGIN_S
    rng = np.random.default_rng([seed, 7])
    with atomic_dir(Path(out), force=True) as tmp:
        if with_imu:
            (tmp / "imu").mkdir()
        (tmp / "corners").mkdir()
        for ii, imu in enumerate(truth.imus if with_imu else ()):
            t = np.arange(int(np.floor(t_end * imu.update_rate)) + 1) / imu.update_rate
            s = imu_model.synthesize(traj.at(t), imu, np.random.default_rng([seed, 4, ii]), noise=True)
            t_ns = isc.EPOCH_NS + np.rint(s.t * 1e9).astype(np.int64)
            (tmp / "imu" / f"{imu.name}.csv").write_text(imu_csv(t_ns, s.gyro, s.accel), encoding="utf-8")
        for cam, stems, t in zip(truth.cameras, timing.stems_ns, timing.t_imu_s):
            T_wb = traj.at(t).T_world_body
            lines = ["#frame,board,corner_id,x_px,y_px"]
            for stem, T in zip(stems, T_wb):
                lines += [f"{stem},{b},{k},{u:.4f},{v:.4f}"
                          for b, k, u, v in _views(cam, T, T_world_board, target.boards, rng, sigma_px)]
            (tmp / "corners" / f"{cam.name}.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
        written = declared or truth
        (tmp / "rig.yaml").write_text(dump_rig(written if with_imu else replace(written, imus=())), encoding="utf-8")
        (tmp / "target.yaml").write_text(dump_target(target), encoding="utf-8")
    return Path(out)


def calibrated_rig(truth: Rig, work: Path, duration: float = 10.0, seed: int = 1000, camera_rate: float = 10.0
                   ) -> Path:
    """The rig YAML `rigcal calibrate` writes (camera-only, then camera-IMU) from a recording
    of `truth`, declared as the golden camera-IMU rig's nominal file."""
    from rigcal.commands.calibrate import CalibrateOptions, run

    base = record(truth, work / "imu_base", duration, camera_rate, seed, declared=load_rig(RIG))
    out = work / "imu_calibrated.yaml"
    run(base, out, CalibrateOptions(jobs=1))
    return out
