"""Benchmark: systematic corner error (bias) of the refinement on oblique board views.

    python -m bench.archive.bias_detect                       # surround-6 room, 10 frames, seed 0
    python -m bench.archive.bias_detect --seeds 0 1 --modes symmetric none
    python -m bench.archive.bias_detect --dataset DIR         # an existing `rigcal simulate` folder
    python -m bench.archive.bias_detect --frames 30 --calibrate --margin-px 1 2   # before / after, with the rig's scale
    python -m bench.archive.bias_detect --rig fisheye-stereo --scene board --frames 20   # fisheye (PnP undistorts first)

Renders `rigcal simulate` datasets (or reads one), detects every board with each
refinement mode and compares each corner with its exact projection from truth.yaml.
Per corner it knows the viewing obliquity (angle between the board normal and the ray),
the radius from the principal point, the projected square size (sqrt of the local
board->image Jacobian's determinant, px per square), and the foreshortening direction
f (unit image direction in which the projected square grows, i.e. towards the near
side of the board). It reports

- the error's mean component along f ("bias_f", px; > 0 = towards the near side) and
  across it, binned by obliquity, radius and square size;
- per view, the similarity (scale, rotation, shift) that best maps the true corners onto
  the detected ones about the board's centre: its scale error in ppm (mean, spread);
- per view, the board's distance from a PnP on the detected corners with the true
  camera model, against the true distance: range error in ppm (what scales a rig);
- the per-view offset RMS as bench/noise_limit.py reports it (each view's mean error)
  against its white-noise expectation, and how many corners are gross errors;
- with --calibrate, the rig's scale error (ppm) after `calibrate_views` on the detected
  corners (bench.common.rig_scale_ppm). A board range error of e ppm moves a camera
  e x 1.5 m along its axis, i.e. ~15 e ppm of a 0.1 m rig: corner biases of 0.001 px
  show up as hundreds of ppm.

--margin-px runs the refinement with that blur margin (corner_fit.MARGIN_PX; 1.0 is the
refinement before the bias fix), in this process (jobs 1).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "app"))

from rigcal.core import geometry as geo  # noqa: E402
from rigcal.data.dataset import list_dataset  # noqa: E402
from rigcal.detect.corner_refine import REFINE_MODES  # noqa: E402
from rigcal.detect.detect import detect_dataset  # noqa: E402
from rigcal.core.rig import load_rig, rig_from_dict  # noqa: E402
from rigcal.core.target import load_target  # noqa: E402


def corner_truth(dataset: Path) -> dict:
    """Per (camera, stem, board): dict of uv (N, 2) true pixels, obliq (N,) deg, radius (N,)
    px, sq (N,) px per square, f (N, 2) unit foreshortening direction, T (4, 4) T_cam_board,
    K, D of the true camera."""
    truth = yaml.safe_load((dataset / "truth.yaml").read_text())
    rig = rig_from_dict(truth["rig"])
    target = load_target(dataset / "target.yaml")
    out = {}
    eps = 1e-3  # squares
    for cam in rig.cameras:
        m = cam.intrinsics
        for stem, fr in truth["frames"].items():
            T_cam_world = geo.inv_T(geo.make_T(np.array(fr["rotation"]), fr["position"]) @ cam.T_body_cam)
            for b in target.boards:
                pose = fr.get("boards", {}).get(b.name, truth["boards"][b.name])
                T = T_cam_world @ geo.make_T(np.array(pose["rotation"]), pose["position"])
                xy = b.corners[:, :2]
                s = b.square_length

                def proj(pts_xy):
                    p = np.column_stack([pts_xy, np.zeros(len(pts_xy))])
                    return m.project(geo.transform(T, p))[0]

                def jac(pts_xy):  # (N, 2, 2) d uv / d (board squares)
                    jx = (proj(pts_xy + [eps * s, 0]) - proj(pts_xy - [eps * s, 0])) / (2 * eps)
                    jy = (proj(pts_xy + [0, eps * s]) - proj(pts_xy - [0, eps * s])) / (2 * eps)
                    return np.stack([jx, jy], axis=-1)

                uv = proj(xy)
                J = jac(xy)
                with np.errstate(invalid="ignore"):  # corners behind the camera project to NaN
                    det = np.abs(np.linalg.det(J))
                sq = np.sqrt(det)
                # gradient of log(sq) on the board, by differences, then to the image
                h = 0.05 * s
                gx = (np.log(np.sqrt(np.abs(np.linalg.det(jac(xy + [h, 0]))))) -
                      np.log(np.sqrt(np.abs(np.linalg.det(jac(xy - [h, 0])))))) / (2 * h / s)
                gy = (np.log(np.sqrt(np.abs(np.linalg.det(jac(xy + [0, h]))))) -
                      np.log(np.sqrt(np.abs(np.linalg.det(jac(xy - [0, h])))))) / (2 * h / s)
                g_img = np.einsum("nji,nj->ni", np.linalg.inv(J), np.column_stack([gx, gy]))  # J^-T g
                f = g_img / np.maximum(np.linalg.norm(g_img, axis=1, keepdims=True), 1e-12)
                p_cam = geo.transform(T, np.column_stack([xy, np.zeros(len(xy))]))
                ray = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
                cosang = np.abs(ray @ T[:3, 2])
                obliq = np.degrees(np.arccos(np.clip(cosang, 0, 1)))
                radius = np.hypot(uv[:, 0] - m.cx, uv[:, 1] - m.cy)
                out[(cam.name, str(stem), b.name)] = dict(uv=uv, obliq=obliq, radius=radius, sq=sq, f=f,
                                                          grad=np.linalg.norm(g_img, axis=1), T=T, K=m.K,
                                                          D=m.D, obj=b.corners, model=m.model)
    return out


def similarity_scale(true_uv: np.ndarray, det_uv: np.ndarray) -> float:
    """Scale error (fraction) of the similarity det ~ c + (a + i b)(true - centre)."""
    c = true_uv.mean(0)
    z = (true_uv - c)[:, 0] + 1j * (true_uv - c)[:, 1]
    w = det_uv[:, 0] + 1j * det_uv[:, 1]
    A = np.column_stack([z, np.ones_like(z)])
    (ab, t), *_ = np.linalg.lstsq(A, w, rcond=None)
    return float(abs(ab) - 1.0)


def pnp_range(entry: dict, ids: np.ndarray, uv: np.ndarray) -> float:
    """Relative error of the board centre's distance from a PnP on uv (true camera model)."""
    obj = entry["obj"][ids].astype(np.float64)
    T = entry["T"]
    rv0, _ = cv2.Rodrigues(T[:3, :3])
    K, D, uv = entry["K"], entry["D"], uv.astype(np.float64)
    if entry["model"] == "fisheye":  # solvePnP reads D as OpenCV's pinhole distortion: undistort first
        uv = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), K, D).reshape(-1, 2)
        K, D = np.eye(3), np.zeros(4)
    ok, rv, tv = cv2.solvePnP(obj, uv, K, D, rv0.copy(), T[:3, 3].copy(),
                              useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return float("nan")
    R = cv2.Rodrigues(rv)[0]
    c = obj.mean(0)
    d_true = np.linalg.norm(T[:3, :3] @ c + T[:3, 3])
    d_est = np.linalg.norm(R @ c + tv.ravel())
    return float(d_est / d_true - 1.0)


def binned(name: str, x: np.ndarray, ef: np.ndarray, ep: np.ndarray, edges: list[float]) -> None:
    parts = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        k = (x >= lo) & (x < hi)
        if k.sum() < 20:
            continue
        parts.append(f"[{lo:g},{hi:g}) n={k.sum()}: f {ef[k].mean():+.4f} perp {ep[k].mean():+.4f} "
                     f"rms {np.sqrt((ef[k] ** 2 + ep[k] ** 2).mean()):.4f}")
    print(f"  by {name}:\n    " + "\n    ".join(parts))


def rig_scale(dataset: Path, views) -> float:
    """Rig scale error (ppm) of a calibration from these detected views."""
    sys.path.insert(0, str(ROOT))
    from bench.common import calibrate, rig_scale_ppm
    from rigcal.data.truth import load_truth
    from dataclasses import replace

    target = load_target(dataset / "target.yaml")
    cal = calibrate([replace(v, sigma=None) for v in views],
                    load_rig(dataset / "rig.yaml"), {b.name: b.corners for b in target.boards})
    return rig_scale_ppm(cal, load_truth(dataset / "truth.yaml").rig)


def analyse(dataset: Path, modes: list[str], jobs: int, label: str, calibrate: bool = False,
            brief: bool = False) -> dict:
    rig = load_rig(dataset / "rig.yaml")
    target = load_target(dataset / "target.yaml")
    truth = corner_truth(dataset)
    images = list_dataset(dataset, rig)
    results = {}
    for mode in modes:
        res = detect_dataset(images, target, jobs=jobs, progress=False, refine=mode)
        rows, scales, ranges, obl_view, offsets = [], [], [], [], []
        for v in res.views:
            t = truth[(v.camera, v.frame, v.board)]
            e = v.uv - t["uv"][v.ids]
            offsets.append((e.mean(0), len(e)))
            f = t["f"][v.ids]
            ef = (e * f).sum(1)
            ep = e[:, 0] * -f[:, 1] + e[:, 1] * f[:, 0]
            rows.append(np.column_stack([ef, ep, t["obliq"][v.ids], t["radius"][v.ids], t["sq"][v.ids],
                                         t["grad"][v.ids], e]))
            if len(v.ids) >= 6:
                scales.append(similarity_scale(t["uv"][v.ids], v.uv))
                ranges.append(pnp_range(t, v.ids, v.uv))
                obl_view.append(np.median(t["obliq"][v.ids]))
        R = np.concatenate(rows)
        ef, ep, obl, rad, sq, grad = (R[:, k] for k in range(6))
        scales, ranges, obl_view = np.array(scales), np.array(ranges), np.array(obl_view)
        print(f"{label} refine={mode}: {len(res.views)} views, {len(R)} corners, {res.seconds:.1f} s; "
              f"RMS {np.sqrt((R[:, 6:] ** 2).sum(1).mean()):.4f} px; mean along f {ef.mean():+.4f} px "
              f"(across {ep.mean():+.4f}); mean bias_f / grad {np.mean(ef * grad) / np.mean(grad ** 2):+.4f}")
        # bench.noise_limit's per-view offset: RMS per axis of each view's mean error, and
        # what white noise of this RMS would give (sigma / sqrt(corners in the view))
        sigma = np.sqrt((R[:, 6:] ** 2).mean())
        gross = (np.abs(R[:, 6:]) > 10 * np.median(np.abs(R[:, 6:]))).any(1).sum()
        print(f"  per-view offset RMS {np.sqrt(np.mean([(m ** 2).mean() for m, _ in offsets])):.4f} px (white "
              f"{np.sqrt(np.mean([sigma ** 2 / n for _, n in offsets])):.4f}); {gross} corners off by > 10x the "
              f"median component, max {np.abs(R[:, 6:]).max():.3f} px")
        if calibrate:
            print(f"  rig scale after calibration: {rig_scale(dataset, res.views):+.0f} ppm")
        print(f"  per-view similarity scale: mean {1e6 * scales.mean():+.0f} ppm, median {1e6 * np.median(scales):+.0f}, "
              f"sd {1e6 * scales.std():.0f}; PnP range: mean {1e6 * np.nanmean(ranges):+.0f} ppm, "
              f"median {1e6 * np.nanmedian(ranges):+.0f}, sd {1e6 * np.nanstd(ranges):.0f}")
        for lo, hi in ((0, 30), (30, 50), (50, 65), (65, 90)):
            k = (obl_view >= lo) & (obl_view < hi)
            if k.any():
                print(f"    views obliquity [{lo},{hi}) n={k.sum()}: scale {1e6 * scales[k].mean():+.0f} ppm, "
                      f"range {1e6 * np.nanmean(ranges[k]):+.0f} ppm")
        results[mode] = dict(scales=scales, ranges=ranges, rows=R, seconds=res.seconds)
        if brief:
            continue
        binned("obliquity (deg)", obl, ef, ep, [0, 20, 35, 50, 60, 70, 80, 90])
        binned("radius (px)", rad, ef, ep, [0, 100, 200, 300, 400, 1000])
        binned("square size (px)", sq, ef, ep, [0, 10, 15, 20, 30, 50, 1000])
        binned("foreshortening |grad log sq| (per px)", grad, ef, ep, [0, 0.002, 0.005, 0.01, 0.02, 1])
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", default="surround-6")
    ap.add_argument("--scene", default="room")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--modes", nargs="+", default=list(REFINE_MODES))
    ap.add_argument("--dataset", type=Path, help="analyse this simulate folder instead of rendering")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--calibrate", action="store_true", help="also calibrate and report the rig's scale error")
    ap.add_argument("--margin-px", type=float, nargs="+", help="refine with these blur margins (in-process)")
    ap.add_argument("--brief", action="store_true", help="no binned tables")
    args = ap.parse_args()
    t0 = time.perf_counter()

    def run(path: Path, label: str) -> None:
        if not args.margin_px:
            analyse(path, args.modes, args.jobs, label, args.calibrate, args.brief)
            return
        import rigcal.detect.corner_fit as det

        defaults = det.refine_symmetric.__defaults__
        names = det.refine_symmetric.__code__.co_varnames[det.refine_symmetric.__code__.co_argcount - len(defaults):
                                                          det.refine_symmetric.__code__.co_argcount]
        for m in args.margin_px:
            det.refine_symmetric.__defaults__ = tuple(m if n == "margin_px" else d for n, d in zip(names, defaults))
            try:
                analyse(path, args.modes, 1, f"{label} margin {m:g} px", args.calibrate, args.brief)
            finally:
                det.refine_symmetric.__defaults__ = defaults

    if args.dataset:
        run(args.dataset, str(args.dataset))
    else:
        from rigcal.sim.simulate import simulate_dataset

        for seed in args.seeds:
            out = Path(tempfile.mkdtemp(prefix="rigcal-bias-")) / "sim"
            try:
                simulate_dataset(load_rig(ROOT / "rigs" / f"{args.rig}.yaml"), out, scene=args.scene,
                                 frames=args.frames, seed=seed, jobs=args.jobs)
                run(out, f"{args.rig} {args.scene} seed {seed}")
            finally:
                shutil.rmtree(out.parent, ignore_errors=True)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
