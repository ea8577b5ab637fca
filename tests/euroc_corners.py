"""A rigcal dataset from the EuRoC `imu_april` corners (../shared/data/real/euroc_imu_april):
corners/<camera>.csv in dataset.md's format, Kalibr's own target file as target.yaml, and
a declared stereo rig with rough intrinsics (the calibration must find EuRoC's).

The shared set's corner files (yac's: `t_ns, tag_id, corner, x_px, y_px, p_x_m, p_y_m,
p_z_m`) become `frame, board, corner_id = 4 tag_id + corner, x_px, y_px`; the p_* columns
are checked against rigcal's own Board.corners on the way (Kalibr's layout)."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import yaml

from rigcal.target import load_target

EUROC = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "euroc_imu_april"
CAMERAS = ("cam0", "cam1")
BASELINE_MM = 110.07  # implied by EuRoC's published T_BS (reference.yaml)

RIG = """rig: euroc-stereo
body_frame: FLU
cameras:
  cam0:
    model: pinhole
    resolution: [752, 480]
    intrinsics: {fx: 440.0, fy: 440.0, cx: 376.0, cy: 240.0}
    distortion: [-0.25, 0.05, 0.0, 0.0]
    position: [0.0, 0.055, 0.0]
    look: forward
  cam1:
    model: pinhole
    resolution: [752, 480]
    intrinsics: {fx: 440.0, fy: 440.0, cx: 376.0, cy: 240.0}
    distortion: [-0.25, 0.05, 0.0, 0.0]
    position: [0.0, -0.055, 0.0]
    look: forward
"""


def read_yac(path: Path) -> np.ndarray:
    """(N, 8) float rows of one camera's yac corner file."""
    with gzip.open(path, "rt") as f:
        return np.loadtxt(f, delimiter=",", comments="#", dtype=np.float64)


def build(dst: Path, every: int = 1) -> Path:
    """Write the dataset into dst (every `every`-th frame of each camera) and return dst."""
    target = load_target(EUROC / "kalibr_target.yaml")
    board = target.boards[0]
    (dst / "corners").mkdir(parents=True, exist_ok=True)
    (dst / "rig.yaml").write_text(RIG)
    (dst / "target.yaml").write_text((EUROC / "kalibr_target.yaml").read_text())
    for cam in CAMERAS:
        with gzip.open(EUROC / "corners" / f"{cam}.csv.gz", "rt") as f:
            raw = np.loadtxt(f, delimiter=",", skiprows=1, dtype=str)
        t = raw[:, 0]
        num = raw[:, 1:].astype(np.float64)
        ids = (4 * num[:, 0] + num[:, 1]).astype(np.int64)
        if not np.allclose(num[:, 4:7], board.corners[ids], atol=1e-5):
            raise ValueError(f"{cam}: yac's corner positions differ from Kalibr's layout")
        frames = np.unique(t)[::every]
        keep = np.isin(t, frames)
        lines = [f"{a},{board.name},{i},{x:.6f},{y:.6f}" for a, i, x, y in
                 zip(t[keep], ids[keep], num[keep, 2], num[keep, 3])]
        (dst / "corners" / f"{cam}.csv").write_text("#frame,board,corner_id,x_px,y_px\n" + "\n".join(lines) + "\n")
    return dst


def reference() -> dict:
    return yaml.safe_load((EUROC / "reference.yaml").read_text())
