"""Benchmark: `rigcal simulate rigs/drone-stereo-back-imu.yaml --scene imu` at the issue's size,
3 cameras x 30 s x 20 Hz (1,800 images at 640x480) + a 200 Hz IMU. Target: <= 2 min on 2 cores.

    python -m bench.simulate_imu [--duration S] [--camera-rate HZ] [--rig rigs/X.yaml] [--jobs N]

Prints the wall and CPU time, the motion's excitation (peak rates and accelerations), the
sub-exposure renders per image, and writes two figures of the recording:
bench/out/simulate_imu.html (plotly: the trajectory in 3D with the boards' centres, and
the IMU's gyroscope and accelerometer streams) and bench/out/simulate_imu.png (the same
curves drawn with OpenCV, for the README).
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from rigcal.core.rig import load_rig
from rigcal.sim.imu_scene import simulate_motion_dataset

from .common import JOBS, OUT, RIGS, md_table, write_json

RIG = RIGS / "drone-stereo-back-imu.yaml"
PLOT_SECONDS = 10.0


def run(duration: float = 30.0, camera_rate: float = 20.0, rig_path: Path = RIG, jobs: int = JOBS,
        figures: bool = True) -> dict:
    """Simulate once into a temporary folder; returns timings, sizes and the excitation."""
    rig = load_rig(rig_path)
    tmp = Path(tempfile.mkdtemp(prefix="rigcal-bench-imu-"))
    try:
        t0 = time.perf_counter()
        res = simulate_motion_dataset(rig, tmp / "sim", duration=duration, camera_rate=camera_rate, jobs=jobs)
        wall = time.perf_counter() - t0
        n_img = sum(len(v) for v in res.image_paths.values())
        size = sum(p.stat().st_size for p in (tmp / "sim").rglob("*") if p.is_file())
        out = {"rig": rig_path.name, "duration_s": duration, "camera_rate_hz": camera_rate, "jobs": jobs,
               "images": n_img, "imu_samples": {k: len(s.t) for k, s in res.streams.items()},
               "wall_s": wall, "image_cpu_s": res.image_cpu_seconds, "dataset_mb": size / 1e6,
               "excitation": res.excitation, "load_avg": os.getloadavg()[0]}
        if figures:
            OUT.mkdir(parents=True, exist_ok=True)
            html_figure(res, OUT / "simulate_imu.html")
            png_figure(res, OUT / "simulate_imu.png")
        return out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def tables(r: dict) -> str:
    ex = r["excitation"]
    fmt = lambda v, d: " / ".join(f"{x:.{d}f}" for x in v)  # noqa: E731
    rows = [[r["rig"], f"{r['duration_s']:g} s x {r['camera_rate_hz']:g} Hz", r["images"],
             ", ".join(f"{k} {v}" for k, v in r["imu_samples"].items()), f"{r['wall_s']:.1f}",
             f"{r['image_cpu_s']:.1f}", r["jobs"], f"{r['dataset_mb']:.0f}"]]
    t = md_table(["rig", "recording", "images", "IMU samples", "wall s", "image CPU s", "jobs", "MB"], rows,
                 title="simulate --scene imu (target: 1,800 images + 200 Hz IMU in <= 120 s on 2 cores)")
    return (t + f"\nmotion: peak angular rate {fmt(ex['peak_rate_deg_s'], 0)} deg/s (body x/y/z), peak acceleration "
            f"{fmt(ex['peak_accel_m_s2'], 1)} m/s^2 (world x/y/z), position range {fmt(ex['position_range_m'], 2)} m\n")


def _first_seconds(res, seconds: float):
    s = next(iter(res.streams.values()))
    keep = s.t <= s.t[0] + seconds
    return s, keep, res.trajectory.at(s.t[keep])


def html_figure(res, path: Path) -> None:
    """A self-contained plotly page: the trajectory (3D) and the IMU streams over time."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    s, keep, m = _first_seconds(res, np.inf)
    fig = make_subplots(rows=3, cols=1, specs=[[{"type": "scene"}], [{}], [{}]], row_heights=[0.5, 0.25, 0.25],
                        subplot_titles=("T_world_body: body origin (ENU, m) and the boards' centres",
                                        "gyroscope (rad/s)", "accelerometer (m/s^2)"))
    p = m.p_world
    fig.add_trace(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines", name="body origin",
                               line={"color": s.t[keep], "colorscale": "Viridis", "width": 4}), row=1, col=1)
    c = np.array([T[:3, 3] for T in res.T_world_board])
    fig.add_trace(go.Scatter3d(x=c[:, 0], y=c[:, 1], z=c[:, 2], mode="markers+text", name="boards",
                               text=[b.name for b in res.target.boards]), row=1, col=1)
    for row, data, unit in ((2, s.gyro, "gyro"), (3, s.accel, "accel")):
        for i, (axis, colour) in enumerate(zip("xyz", ("red", "green", "blue"))):
            fig.add_trace(go.Scatter(x=s.t, y=data[:, i], name=f"{unit} {axis}", line={"color": colour, "width": 1}),
                          row=row, col=1)
    fig.update_layout(height=1200, title="rigcal simulate --scene imu: the recording", scene={"aspectmode": "data"})
    path.write_text(fig.to_html(include_plotlyjs=True, full_html=True), encoding="utf-8")


def _panel(h: int, w: int, t: np.ndarray, ys: np.ndarray, title: str) -> np.ndarray:
    """One white panel with the three columns of ys (N, 3) against t as red, green, blue lines."""
    img = np.full((h, w, 3), 255, np.uint8)
    lo, hi = float(ys.min()), float(ys.max())
    span = hi - lo or 1.0
    x = 50 + (t - t[0]) / (t[-1] - t[0]) * (w - 60)
    for i, colour in enumerate(((0, 0, 220), (0, 160, 0), (220, 0, 0))):  # BGR: x red, y green, z blue
        y = h - 20 - (ys[:, i] - lo) / span * (h - 45)
        cv2.polylines(img, [np.column_stack([x, y]).round().astype(np.int32)], False, colour, 1, cv2.LINE_AA)
    cv2.putText(img, title, (50, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for v in (lo, hi):
        cv2.putText(img, f"{v:.2f}", (2, int(h - 20 - (v - lo) / span * (h - 45)) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                    (80, 80, 80), 1, cv2.LINE_AA)
    return img


def _top_view(size: int, p: np.ndarray, heading: np.ndarray, title: str) -> np.ndarray:
    """The body origin's path seen from above (east right, north up), equal scale, with the
    body's forward axis drawn every 50th sample."""
    img = np.full((size, size, 3), 255, np.uint8)
    xy = p[:, :2] - p[:, :2].mean(axis=0)
    scale = (size - 60) / max(float(np.abs(xy).max()) * 2, 1e-6)
    uv = np.column_stack([size / 2 + xy[:, 0] * scale, size / 2 + 10 - xy[:, 1] * scale])
    cv2.polylines(img, [uv.round().astype(np.int32)], False, (120, 60, 0), 1, cv2.LINE_AA)
    for i in range(0, len(uv), 50):
        tip = uv[i] + np.array([heading[i, 0], -heading[i, 1]]) * 25
        cv2.arrowedLine(img, tuple(int(v) for v in uv[i]), tuple(int(v) for v in tip), (0, 0, 200), 1, cv2.LINE_AA,
                        tipLength=0.25)
    cv2.putText(img, title, (8, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"{20 / scale * 100:.1f} cm / 20 px", (8, size - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                (80, 80, 80), 1, cv2.LINE_AA)
    return img


def png_figure(res, path: Path, seconds: float = PLOT_SECONDS) -> None:
    """Position, gyroscope and accelerometer over the first `seconds`, and the path from
    above, drawn with OpenCV."""
    s, keep, m = _first_seconds(res, seconds)
    t = s.t[keep]
    panels = [_panel(170, 900, t, m.p_world - m.p_world.mean(axis=0),
                     f"body position about its mean (m), world x red / y green / z blue, first {seconds:g} s"),
              _panel(170, 900, t, s.gyro[keep], "gyroscope (rad/s), IMU x red / y green / z blue"),
              _panel(170, 900, t, s.accel[keep], "accelerometer (m/s^2): specific force, gravity on +z")]
    top = _top_view(510, m.p_world, m.R_world_body[:, :, 0], f"path from above (E right, N up), first {seconds:g} s")
    cv2.imwrite(str(path), np.hstack([np.vstack(panels), top]))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--camera-rate", type=float, default=20.0)
    ap.add_argument("--rig", type=Path, default=RIG)
    ap.add_argument("--jobs", type=int, default=JOBS)
    a = ap.parse_args(argv)
    r = run(a.duration, a.camera_rate, a.rig, a.jobs)
    write_json("simulate_imu", r)
    print(tables(r))


if __name__ == "__main__":
    main()
