"""OpenCV 5 as the peer: cv2.calibrateMultiview on the same detections as rigcal.

calibrateMultiview (OpenCV >= 5.0) takes one pattern per "frame", every camera's
points of that frame in the same order (NUM_CAMERAS x NUM_FRAMES x NUM_POINTS x 2),
and a detection mask; it calibrates each camera's intrinsics alone
(calibrateCamera / fisheye.calibrate), chains pairwise registerCameras along a
spanning tree, then refines the relative poses and per-frame poses (intrinsics stay
as calibrated per camera). Output: R_i, T_i with x_i = R_i x_0 + T_i.

What the adapter does with rigcal's detections, and why:

* A (frame, board) pair is one OpenCV frame: with several static boards (room
  scenes) each board gives an independent pattern pose per frame, which is exactly
  the model calibrateMultiview fits (it only loses that the boards do not move).
* OpenCV 5.0.0's partial-view support is broken in practice: marking a single
  unobserved corner (-1, -1) in one view of an otherwise perfect synthetic stereo
  set turns the result to garbage (RMS 19 px; with ChArUco-like partial views
  1e6 px). Points per frame must have one count (NUM_POINTS) but may differ
  between frames, so each frame gets the same number N of corners, taken evenly
  from the corners EVERY camera that is used in that frame detected. N is chosen to
  keep the most corner observations. rigcal gets every corner.
* Where no frame links two cameras (drone-stereo-back: the back camera never sees a
  board at the same time as a front camera), calibrateMultiview cannot run at all;
  it is called anyway and its error is reported.

    python -m bench.peer_opencv [--scenario NAME ...]
"""

from __future__ import annotations

import argparse
import re
import time

import cv2
import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel
from rigcal.core.rig import Camera

from .common import JOBS, SCENARIOS, Timer, calibrate_dataset, get_dataset, md_table, rig_errors, say, scenario, write_json

N_CHOICES = (4, 6, 8, 10, 12, 16, 20, 24, 30, 36, 42, 48, 56, 64, 80, 96, 117, 140)


def _frames_by_pattern(views) -> dict:
    """{(frame, board): {camera: (ids, uv)}}"""
    out: dict = {}
    for v in views:
        out.setdefault((v.frame, v.board), {})[v.camera] = (np.asarray(v.ids), np.asarray(v.uv, float))
    return out


def _choose(cams: dict, n: int) -> tuple[list[str], np.ndarray] | None:
    """Cameras (most corners first) whose common corners stay >= n, and those ids."""
    order = sorted(cams, key=lambda c: -len(cams[c][0]))
    common = None
    chosen = []
    for c in order:
        ids = set(cams[c][0].tolist())
        inter = ids if common is None else common & ids
        if len(inter) >= n:
            common, chosen = inter, chosen + [c]
    if not chosen:
        return None
    return chosen, np.array(sorted(common))


def multiview_inputs(views, cam_names: list[str], corners: dict) -> dict:
    """calibrateMultiview's arguments from rigcal views, with N as explained above."""
    patterns = _frames_by_pattern(views)
    best = None
    for n in N_CHOICES:
        used = [_choose(c, n) for c in patterns.values()]
        score = n * sum(len(u[0]) for u in used if u is not None)
        if best is None or score > best[0]:
            best = (score, n)
    n = best[1]
    obj, mask = [], []
    img = [[] for _ in cam_names]
    for (frame, board), cams in patterns.items():
        sel = _choose(cams, n)
        if sel is None:
            continue
        chosen, common = sel
        ids = common[np.round(np.linspace(0, len(common) - 1, n)).astype(int)]
        obj.append(corners[board][ids].astype(np.float32))
        row = []
        for ci, c in enumerate(cam_names):
            if c in chosen:
                cid, uv = cams[c]
                pos = {int(k): j for j, k in enumerate(cid)}
                img[ci].append(uv[[pos[int(k)] for k in ids]].astype(np.float32))
                row.append(1)
            else:
                img[ci].append(np.zeros((n, 2), np.float32))
                row.append(0)
        mask.append(row)
    mask = np.array(mask, np.uint8).T.copy()  # (C, F)
    used = int(mask.sum()) * n
    return {"objPoints": obj, "imagePoints": img, "detectionMask": mask, "n_points": n, "observations_used": used}


def run_multiview(views, rig, corners: dict) -> dict:
    """Call cv2.calibrateMultiview; returns its rig (body = first camera) and timings, or the error."""
    names = list(rig.names)
    inp = multiview_inputs(views, names, corners)
    sizes = [(c.intrinsics.width, c.intrinsics.height) for c in rig.cameras]
    fisheye = [c.intrinsics.model == "fisheye" for c in rig.cameras]
    models = np.array([cv2.CALIB_MODEL_FISHEYE if f else cv2.CALIB_MODEL_PINHOLE for f in fisheye], np.uint8)
    shared = int(np.sum(inp["detectionMask"].sum(0) >= 2))
    info = {"n_points_per_frame": inp["n_points"], "frames": int(inp["detectionMask"].shape[1]),
            "frames_shared": shared, "observations_used": inp["observations_used"],
            "observations_available": int(sum(len(v.ids) for v in views))}
    args = (inp["objPoints"], inp["imagePoints"], sizes, inp["detectionMask"], models)
    with Timer() as t:
        try:
            rms, Ks, Ds, Rs, Ts = cv2.calibrateMultiview(*args, None, None, None, None)
        except cv2.error as e:
            first = _cv_message(e)
            try:
                # OpenCV's own per-camera intrinsics step failed: give it the declared intrinsics
                Ks0 = [c.intrinsics.K for c in rig.cameras]
                Ds0 = [np.array(c.intrinsics.dist, float).reshape(1, -1) for c in rig.cameras]
                rms, Ks, Ds, Rs, Ts = cv2.calibrateMultiview(*args, Ks0, Ds0, None, None,
                                                             flags=cv2.CALIB_USE_INTRINSIC_GUESS)
                info["note"] = f"own intrinsics step failed ({first}); declared intrinsics given as the guess"
            except cv2.error as e2:
                return {**info, "ok": False, "error": first, "error_with_guess": _cv_message(e2)}
    cams = []
    for i, c in enumerate(rig.cameras):
        R = np.asarray(Rs[i], float)
        R = cv2.Rodrigues(R.reshape(3, 1))[0] if R.size == 3 else R.reshape(3, 3)
        T_cam_cam0 = geo.make_T(R, np.asarray(Ts[i], float).ravel())
        K = np.asarray(Ks[i], float)
        d = np.asarray(Ds[i], float).ravel()
        d = d[:4] if fisheye[i] else d[:5]
        m = CameraModel(c.intrinsics.model, c.intrinsics.width, c.intrinsics.height, K[0, 0], K[1, 1], K[0, 2],
                        K[1, 2], dist=tuple(float(x) for x in d))
        cams.append(Camera(c.name, m, geo.inv_T(T_cam_cam0)))
    return {**info, "ok": True, "rms_px": float(rms), "seconds": t.wall, "cpu_s": t.cpu,
            "rig": rig.with_cameras(cams)}


def _cv_message(e: cv2.error) -> str:
    """OpenCV's error in a few words: its detail when short, else its error class."""
    msg = str(e).strip().splitlines()[-1]
    m = re.search(r"error: \(-?\d+:([^)]*)\) (.*?)(?: in function|$)", msg)
    if not m:
        return msg[:100]
    return m.group(2).strip() if len(m.group(2)) <= 80 else m.group(1).strip()


def run_scenario(scn, seed: int = 0, rigcal_result: dict | None = None, log=say) -> dict:
    ds = get_dataset(scn, seed, keep_images=True, log=log)
    cv = run_multiview(ds.views, ds.rig, ds.corners)
    if rigcal_result is None:
        with Timer() as t:
            cal = calibrate_dataset(ds, jobs=JOBS)
        rigcal_result = {"pairs": rig_errors(cal.rig, ds.truth.rig)["pairs"], "calibration_s": t.wall,
                         "focal": {n: e["focal_rel_pct"] for n, e in rig_errors(cal.rig, ds.truth.rig)["cameras"].items()}}
    out = {"scenario": scn.name, "seed": seed, "opencv": {k: v for k, v in cv.items() if k != "rig"},
           "rigcal": rigcal_result}
    if cv["ok"]:
        e = rig_errors(cv["rig"], ds.truth.rig)
        out["opencv"]["pairs"] = e["pairs"]
        out["opencv"]["focal"] = {n: x["focal_rel_pct"] for n, x in e["cameras"].items()}
    return out


def run(names: list[str] | None = None, accuracy: list[dict] | None = None, log=say) -> list[dict]:
    acc = {r["scenario"]: r for r in (accuracy or [])}
    out = []
    for scn in (SCENARIOS if not names else [scenario(n) for n in names]):
        log(f"opencv peer: {scn.name} ...")
        a = acc.get(scn.name)
        rr = None
        if a is not None:
            rr = {"pairs": a["pairs"], "calibration_s": a["calibration_s"],
                  "focal": {n: c["focal_rel_pct"] for n, c in a["cameras_detail"].items()}}
        out.append(run_scenario(scn, rigcal_result=rr, log=log))
    return out


def tables(results: list[dict]) -> str:
    rows = []
    for r in results:
        cv = r["opencv"]
        if not cv["ok"]:
            rows.append([r["scenario"], "-", "-", "-", "-", "-", "-", "-", r["rigcal"]["calibration_s"], "-",
                         f"cannot run: {cv['error']}"])
            continue
        for k, p in cv["pairs"].items():
            rp = r["rigcal"]["pairs"][k]
            rows.append([r["scenario"], k, rp["rot_deg"], cv["pairs"][k]["rot_deg"], rp["trans_mm"],
                         cv["pairs"][k]["trans_mm"],
                         max(abs(x) for x in r["rigcal"]["focal"].values()),
                         max(abs(x) for x in cv["focal"].values()), r["rigcal"]["calibration_s"], cv["seconds"],
                         f"{cv['observations_used']}/{cv['observations_available']} corners "
                         f"({cv['n_points_per_frame']}/frame), {cv['frames_shared']} shared frames, RMS "
                         f"{cv['rms_px']:.3g} px" + (f"; {cv['note']}" if cv.get("note") else "")])
    return md_table(["scenario", "pair", "rigcal rot deg", "OpenCV rot deg", "rigcal trans mm", "OpenCV trans mm",
                     "rigcal max focal err %", "OpenCV max focal err %", "rigcal s", "OpenCV s",
                     "OpenCV input / note"], rows,
                    "OpenCV 5 cv2.calibrateMultiview on the same detections (seed 0)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", action="append")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = run(a.scenario)
    say(tables(res))
    write_json("peer_opencv", {"results": res, "seconds": time.perf_counter() - t0})


if __name__ == "__main__":
    main()
