"""A motion dataset (images/ + imu/) as the camera-IMU estimator's inputs
(rigcal.imucal.estimator) with the boards' world poses and every camera's intrinsics given (a
simulated dataset's truth.yaml): corners detected in every image, each camera's per-frame
pose by PnP, the IMU samples, one IMU. A harness that tests and benchmarks the estimator
alone, apart from `rigcal calibrate`'s camera-only step (rigcal.imucal.step builds the
estimator's inputs from that step).

Times are seconds since the IMU's first sample, on each sensor's own clock (the stems are
integer nanoseconds), so the offsets the estimator finds are the motion-dataset format's time_offset_s.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from rigcal.core import geometry as geo
from rigcal.detect.board_detectors import BoardDetector
from rigcal.imucal.estimator import CameraInput, ImuInput
from rigcal.imucal.residuals import Corners
from rigcal.camcal.initialise import pnp_views
from rigcal.data.imu_csv import read_imu_csv
from rigcal.core.rig import Rig
from rigcal.core.target import Target

MIN_PNP_CORNERS = 8


def _camera_views(paths: list[Path], detector: BoardDetector, board_index: dict[str, int]):
    """Per image with a board: (image index, board index, ids, uv); the board with most corners
    first per image (PnP takes it)."""
    out = []
    for k, path in enumerate(paths):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            continue
        found = sorted(detector.detect(gray)[0], key=lambda d: -len(d[1]))
        out += [(k, board_index[name], ids, uv) for name, ids, uv, _ in found]
    return out


def motion_inputs(dataset: str | Path, rig: Rig, target: Target, T_world_board: np.ndarray
                  ) -> tuple[list[CameraInput], Corners, ImuInput]:
    """(cameras, corners, imu) of `dataset` for imu_calib.calibrate_camera_imu. `rig` gives the
    intrinsics, declared poses, line delays and clock-offset guesses, and the IMU (its first)."""
    dataset = Path(dataset)
    imu_decl = rig.imus[0]
    samples = read_imu_csv(dataset / "imu" / f"{imu_decl.name}.csv")
    t_base = int(samples.t_ns[0])
    detector = BoardDetector(target, 6, "symmetric")
    board_index = {b.name: i for i, b in enumerate(target.boards)}
    cams, parts = [], []
    for ci, cam in enumerate(rig.cameras):
        paths = sorted((dataset / "images" / cam.name).glob("*.png"), key=lambda p: int(p.stem))
        t_img = np.array([(int(p.stem) - t_base) * 1e-9 for p in paths])
        views = _camera_views(paths, detector, board_index)
        p_world = [geo.transform(T_world_board[b], target.boards[b].corners[ids]) for _, b, ids, _ in views]
        for (k, _, _, uv), pw in zip(views, p_world):
            parts.append((np.full(len(uv), ci), np.full(len(uv), t_img[k]), uv, pw))
        first, seen = [], set()
        for v in views:  # one PnP per image, on its largest board
            if v[0] not in seen and len(v[2]) >= MIN_PNP_CORNERS:
                seen.add(v[0])
                first.append(v)
        m = cam.intrinsics
        fits = pnp_views([target.boards[b].corners[ids] for _, b, ids, _ in first], [uv for *_, uv in first],
                         np.array([m.fx, m.fy, m.cx, m.cy, *m.dist]), m.model,
                         [target.boards[b].print_face for _, b, _, _ in first])
        ok = [j for j, f in enumerate(fits) if f is not None]
        T_world_cam = np.stack([T_world_board[first[j][1]] @ geo.inv_T(fits[j][0]) for j in ok])
        cams.append(CameraInput(m, cam.T_body_cam.copy(), t_img[[first[j][0] for j in ok]], T_world_cam,
                                cam.line_delay_s or 0.0, cam.time_offset_s or 0.0))
    obs = Corners(*(np.concatenate(x) for x in zip(*parts)))
    imu = ImuInput((samples.t_ns - t_base) * 1e-9, samples.gyro, samples.accel, imu_decl.update_rate,
                   imu_decl.gyroscope_noise_density, imu_decl.gyroscope_random_walk,
                   imu_decl.accelerometer_noise_density, imu_decl.accelerometer_random_walk, imu_decl.T_body_imu.copy())
    return cams, obs, imu
