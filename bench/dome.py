"""Dome: 60 cameras on a sphere around a capture volume, `rigcal calibrate` on
synthetic detections written as corners/<camera>.csv files, 100 / 300 / 1,000 frames.
Targets at 300 frames: solve < 3 min, peak memory < 4 GB.

The dome: 60 pinhole cameras (1024x768, f = 1100 px, mild radial-tangential distortion)
spread evenly (a Fibonacci lattice) over the band of a 3.5 m sphere from 5 deg below to
65 deg above the horizon, all looking at its centre; the declared rig is perturbed
(rigcal.sim.simulate.perturb_rig, seed 0) into the truth. The target: five ChArUco boards
(8 x 6 squares of 8 cm, 35 corners each) fixed on the four sides and the top of a box,
printed faces out, carried through the volume: per frame a random heading, tilt +-25 deg,
offset +-1.2 m across and +-0.5 m up. A camera keeps a board only from its printed side,
with >= 8 corners inside the image and not seen grazing (rigcal.sim.synthetic.board_view);
corners are the exact projections plus 0.1 px Gaussian noise.

Each size is written as a dataset (rig.yaml, target.yaml, corners/<camera>.csv,
dataset.md) under bench/out/cache/dome-<frames> and calibrated by `rigcal calibrate` in
its own process, so the peak resident memory (the command's ru_maxrss) is that
calibration's alone; its own "time:" line gives the solve seconds.

    python -m bench.dome [--frames 100 300 1000]
    python -m bench.dome --one 300          # one size, JSON on stdout
"""

from __future__ import annotations

import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

import rigcal
from rigcal.core import geometry as geo
from rigcal.core.io import atomic_write_texts
from rigcal.sim.synthetic import board_view, with_noise
from rigcal.core.observations import BoardView
from rigcal.core.target import parse_target

from .common import CACHE, OUT, Timer, md_table, perturbed_truth, rig_errors, run_sizes, say, sizes_main

FRAMES = (100, 300, 1000)
N_CAMERAS = 60
RADIUS_M = 3.5
ELEVATION_DEG = (-5.0, 65.0)
SIGMA_PX = 0.1
MIN_CORNERS = 8
BOX_HALF_M = 0.4  # the side boards' centres are this far from the box's centre
TARGET_YAML = "boards:\n" + "".join(
    f"  - {{name: {n}, type: charuco, dictionary: DICT_5X5_1000, squares: [8, 6], square_length: 0.08, "
    f"marker_length: 0.06, first_marker_id: {24 * k}}}\n" for k, n in enumerate(("east", "north", "west", "south", "top")))
BIN = Path(sys.executable).parent / "rigcal"


def dome_rig_dict(n: int = N_CAMERAS) -> dict:
    """The declared dome as a rig.yaml document: cameras on a Fibonacci lattice over the
    elevation band, each looking at the centre with its image upright (body frame FLU,
    z up)."""
    k = np.arange(n) + 0.5
    z = np.sin(np.radians(ELEVATION_DEG[0])) + k / n * (np.sin(np.radians(ELEVATION_DEG[1])) -
                                                         np.sin(np.radians(ELEVATION_DEG[0])))
    az = np.pi * (3.0 - np.sqrt(5.0)) * k  # golden angle
    pos = RADIUS_M * np.column_stack([np.sqrt(1 - z**2) * np.cos(az), np.sqrt(1 - z**2) * np.sin(az), z])
    cams = {}
    for i, p in enumerate(pos):
        fwd = -p / np.linalg.norm(p)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        cams[f"cam{i:02d}"] = {"model": "pinhole", "resolution": [1024, 768],
                               "intrinsics": {"fx": 1100.0, "fy": 1100.0, "cx": 512.0, "cy": 384.0},
                               "distortion": [-0.05, 0.02, 0.0, 0.0], "position": [float(v) for v in p],
                               "axes": [[float(v) for v in a] for a in (right, down, fwd)]}
    return {"rig": f"dome-{n}", "body_frame": "FLU", "cameras": cams}


def box_boards(p_board: np.ndarray) -> dict[str, np.ndarray]:
    """T_world_board of the five boards in the box's frame (world = the box): four sides
    facing out along +x, +y, -x, -y and one on top facing up. A board's z points into its
    printed face (dataset.md), so z is the inward normal; y runs down a side board."""
    centre = p_board.mean(0)
    out = {}
    for k, name in enumerate(("east", "north", "west", "south")):
        yaw = np.pi / 2 * k
        n = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        y, z = np.array([0.0, 0.0, -1.0]), -n
        R = np.column_stack([np.cross(y, z), y, z])
        out[name] = geo.make_T(R, BOX_HALF_M * n - R @ centre)
    R_top = np.column_stack([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    out["top"] = geo.make_T(R_top, np.array([0.0, 0.0, 0.25]) - R_top @ centre)
    return out


def box_pose(rng: np.random.Generator) -> np.ndarray:
    """(4, 4) T_body_box: a random heading, tilt +-25 deg about x and y, offset +-1.2 m
    across and +-0.5 m up."""
    yaw = rng.uniform(-np.pi, np.pi)
    tilt = np.radians(rng.uniform(-25.0, 25.0, 2))
    R = geo.R_from_rotvec([0, 0, yaw]) @ geo.R_from_rotvec([tilt[0], 0, 0]) @ geo.R_from_rotvec([0, tilt[1], 0])
    return geo.make_T(R, rng.uniform([-1.2, -1.2, -0.5], [1.2, 1.2, 0.5]))


def printed_side(T_cam_board: np.ndarray) -> bool:
    """The camera is in front of the board's printed face: its centre has z < 0 in the
    board frame (z points into the print, dataset.md). A detector sees nothing from behind."""
    return bool(geo.inv_T(T_cam_board)[2, 3] < 0)


def dome_views(truth: rigcal.Rig, p_board: np.ndarray, frames: int, rng: np.random.Generator) -> list[BoardView]:
    """Noise-free views of the box's boards through the true dome in `frames` box poses."""
    boards = box_boards(p_board)
    T_cam_body = {c.name: geo.inv_T(c.T_body_cam) for c in truth.cameras}
    views = []
    for f in range(frames):
        T_body_box = box_pose(rng)
        for cam in truth.cameras:
            for name, T_box_board in boards.items():
                T_cam_board = T_cam_body[cam.name] @ T_body_box @ T_box_board
                if not printed_side(T_cam_board):
                    continue
                seen = board_view(cam, T_cam_board, p_board, MIN_CORNERS)
                if seen is not None:
                    views.append(BoardView(cam.name, f"{f:06d}", name, *seen))
    return views


def corners_csv(views: list[BoardView]) -> str:
    """One camera's views as corners/<camera>.csv text (dataset.md)."""
    lines = ["#frame,board,corner_id,x_px,y_px"]
    for v in views:
        lines += [f"{v.frame},{v.board},{i},{x:.4f},{y:.4f}" for i, (x, y) in zip(v.ids, v.uv)]
    return "\n".join(lines) + "\n"


def make_dataset(frames: int, n_cameras: int = N_CAMERAS, root: Path = CACHE, log=say) -> tuple[Path, rigcal.Rig]:
    """Write (once) the dome dataset of `frames` frames under root; returns its folder and
    the truth."""
    d = root / f"dome-{n_cameras}x{frames}"
    rig_text = yaml.safe_dump(dome_rig_dict(n_cameras), sort_keys=False)
    truth = perturbed_truth(rigcal.core.rig.parse_rig(rig_text, "dome"), 0)
    if (d / "corners").is_dir() and (d / "rig.yaml").is_file():
        return d, truth
    log(f"dome: writing {n_cameras} cameras x {frames} frames of corners ...")
    p_board = parse_target(TARGET_YAML).boards[0].corners
    views = with_noise(dome_views(truth, p_board, frames, np.random.default_rng([frames, 21])), SIGMA_PX,
                       np.random.default_rng([frames, 22]))
    by_cam: dict[str, list[BoardView]] = {c.name: [] for c in truth.cameras}
    for v in views:
        by_cam[v.camera].append(v)
    (d / "corners").mkdir(parents=True, exist_ok=True)
    atomic_write_texts([(d / "rig.yaml", rig_text), (d / "target.yaml", TARGET_YAML)] +
                       [(d / "corners" / f"{n}.csv", corners_csv(vs)) for n, vs in by_cam.items()])
    return d, truth


def one(frames: int) -> dict:
    d, truth = make_dataset(frames, log=lambda s: print(s, file=sys.stderr))
    out = OUT / f"dome-{frames}.yaml"
    cmd = [str(BIN) if BIN.exists() else "rigcal", "calibrate", str(d), "--out", str(out), "--jobs", "1"]
    load0 = os.getloadavg()
    with Timer() as t:
        p = subprocess.run(cmd, capture_output=True, text=True)
    text = p.stdout + p.stderr
    if p.returncode != 0:
        return {"frames": frames, "ok": False, "error": text.strip().splitlines()[-1] if text.strip() else "?"}
    m = re.search(r"time: detection ([\d.]+) s, intrinsics ([\d.]+) s, solve ([\d.]+) s, total ([\d.]+) s", text)
    _, intr, solve, total = (float(x) for x in m.groups())
    corners = sum(sum(1 for line in open(f) if not line.startswith("#")) for f in (d / "corners").glob("*.csv"))
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    e = rig_errors(rigcal.load_rig(out), truth)
    return {"frames": frames, "ok": True, "cameras": N_CAMERAS, "corners": corners, "intrinsics_s": intr,
            "solver_s": solve, "total_s": total, "wall_s": t.wall, "cpu_s": t.cpu, "peak_rss_mb": peak_mb,
            "bytes_per_corner": peak_mb * 2**20 / corners, "load_avg": [load0, os.getloadavg()],
            "max_pair_trans_err_mm": max(p["trans_mm"] for p in e["pairs"].values()),
            "max_pair_rot_err_deg": max(p["rot_deg"] for p in e["pairs"].values()),
            "date": time.strftime("%Y-%m-%d %H:%M")}


def run(frames=FRAMES, log=say) -> list[dict]:
    return run_sizes("bench.dome", frames, log, f"dome: {N_CAMERAS} cameras")


def tables(res: list[dict]) -> str:
    rows = []
    ok = [r for r in res if r.get("ok")]
    for r in res:
        if not r.get("ok"):
            rows.append([r["frames"], "failed: " + r.get("error", "?")] + [""] * 10)
            continue
        rows.append([r["frames"], r["corners"], r["intrinsics_s"], r["solver_s"], r["total_s"], r.get("cpu_s"),
                     r["solver_s"] / ok[0]["solver_s"] / (r["corners"] / ok[0]["corners"]), r["peak_rss_mb"],
                     r["bytes_per_corner"], r["max_pair_trans_err_mm"], r["max_pair_rot_err_deg"],
                     " / ".join(f"{x:.1f}" for x in r["load_avg"][0])])
    return md_table(["frames", "corners", "init s", "solver s", "calibrate total s", "calibrate CPU s",
                     "solver s per corner vs first",
                     "peak RSS MB", "peak bytes per corner", "max pair trans err mm", "max pair rot err deg",
                     "load avg 1/5/15"], rows,
                    f"Dome: {N_CAMERAS} cameras, 5 boards on a moved box, synthetic corners (0.1 px) as corners/ "
                    "files, `rigcal calibrate --jobs 1`; targets at 300 frames: solve < 3 min, peak < 4 GB")


def main(argv=None) -> None:
    sizes_main(argv, __doc__, FRAMES, one, run, tables, "dome")


if __name__ == "__main__":
    main()
