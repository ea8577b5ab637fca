"""Real photographs: calibrated values next to their published references.

* samples/real/bumblebee2: baseline vs BoofCV's 120.05 mm (target: within 0.2 mm),
  with --distortion auto, radial2, radtan4 and radtan5 side by side.
* samples/real/opencv_stereo: baseline in squares vs 3.344 (scikit-surgeryimage's
  |T| 100.31 / 30) and 3.345 (an OpenCV 5 stereoCalibrate re-run); target 0.5 %.
* ../shared/data/real (linked into bench/out/real by samples/real/make_datasets.py):
  stereo_calib_wideangle_charuco baseline vs the author's 75.0 mm (target 0.5 mm);
  caliscope_4cam_charuco_a pairwise camera-centre distances and relative rotations
  vs caliscope's own solution (target 2.5 cm / 2 deg; caliscope is itself only that
  consistent); boofcv_trinocular_ecocheck baselines in squares vs a pairwise OpenCV
  run (no published reference: a self-consistency check); euroc_imu_april (corners
  only, corners/<camera>.csv from yac's detections; all 1,416 frames with corners)
  camera-only: baseline vs the 110.07 mm EuRoC's T_BS imply (target 0.3 mm), intrinsics
  vs EuRoC's published ones (target 0.5 %).

Detections are cached per dataset (bench/out/cache/real-*), keyed like the simulated ones.

    python -m bench.real [--set NAME ...]
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import time
try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: tomllib is 3.11+
    import tomli as tomllib
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

import rigcal
from rigcal.core import geometry as geo
from rigcal.camcal.pipeline import calibrate_views
from rigcal.core.observations import BoardView

from .common import (CACHE, JOBS, OUT, ROOT, Timer, calibrate, code_hash, folder_hook, md_table, say, view_tuples,
                     write_json)

SAMPLES = ROOT / "samples" / "real"
SHARED = ROOT.parent / "shared" / "data" / "real"
LINKED = OUT / "real"
BUMBLEBEE_REF_MM = 120.05
WIDEANGLE_REF_MM = 75.0
OPENCV_REF_SQUARES = {"scikit-surgeryimage norm(T)/30": float(np.linalg.norm([100.304, -0.813, -1.167]) / 30.0),
                      "OpenCV 5 stereoCalibrate re-run": 3.345}
TRINOCULAR_REF_SQUARES = {("left", "middle"): 4.909, ("middle", "right"): 4.749, ("left", "right"): 9.642}


def detections(dataset: Path, tag: str, log=say):
    """(rig, corners, views, n_images, detection seconds), detections cached."""
    from rigcal.data.dataset import list_dataset
    from rigcal.detect.detect import detect_dataset
    from rigcal.core.target import load_target

    rig = rigcal.load_rig(dataset / "rig.yaml")
    target = load_target(dataset / "target.yaml")
    corners = {b.name: b.corners for b in target.boards}
    cache = CACHE / f"real-{tag}-{code_hash()}.pkl"
    if cache.is_file():
        with open(cache, "rb") as f:
            meta = pickle.load(f)
    else:
        log(f"  detecting {dataset} ...")
        images = list_dataset(dataset, rig)
        det = detect_dataset(images, target, rig=rig, jobs=JOBS, progress=False)
        meta = {"views": view_tuples(det.views), "n_images": images.n_images, "det_s": det.seconds}
        cache.parent.mkdir(parents=True, exist_ok=True)
        tmp = cache.with_suffix(".tmp")
        with open(tmp, "wb") as f:
            pickle.dump(meta, f)
        os.replace(tmp, cache)
    return rig, corners, [BoardView(*v) for v in meta["views"]], meta["n_images"], meta["det_s"]


def calibrate_set(dataset: Path, rig, corners: dict, views: list, distortion: str = "auto"):
    """What `rigcal calibrate` does with a set's detections, the guided pass (--guided auto:
    fisheye cameras only, so none of the sets here) included."""
    return calibrate(views, rig, corners, distortion, rerefine=folder_hook(dataset, rig, jobs=JOBS))


def _baseline(rig, a: str, b: str) -> float:
    return float(np.linalg.norm(rig.camera(a).T_body_cam[:3, 3] - rig.camera(b).T_body_cam[:3, 3]))


def _cal_row(cal) -> dict:
    return {"rms_px": cal.rms_px, "models": {n: cal.stats[n].distortion_model for n in cal.cam_names},
            "outliers": int((~cal.inliers).sum()), "corners": int(cal.inliers.sum()),
            "flips": int(cal.flips), "notes": cal.notes}


def bumblebee2(log=say) -> dict:
    rig, corners, views, n, det_s = detections(SAMPLES / "bumblebee2", "bumblebee2", log)
    rows = {}
    for dist in ("auto", "radial2", "radtan4", "radtan5"):
        with Timer() as t:
            cal = calibrate_set(SAMPLES / "bumblebee2", rig, corners, views, dist)
        rows[dist] = {"baseline_mm": 1000 * _baseline(cal.rig, "left", "right"), "seconds": t.wall, **_cal_row(cal)}
    return {"set": "bumblebee2", "images": n, "detection_s": det_s, "reference_mm": BUMBLEBEE_REF_MM, "runs": rows}


def opencv_stereo(log=say) -> dict:
    rig, corners, views, n, det_s = detections(SAMPLES / "opencv_stereo", "opencv_stereo", log)
    with Timer() as t:
        cal = calibrate_set(SAMPLES / "opencv_stereo", rig, corners, views)
    square = 0.030  # target.yaml's square: results in squares = metres / square
    return {"set": "opencv_stereo", "images": n, "detection_s": det_s, "seconds": t.wall,
            "baseline_squares": _baseline(cal.rig, "left", "right") / square, "references": OPENCV_REF_SQUARES,
            **_cal_row(cal)}


def linked(name: str, log=say) -> Path | None:
    """bench/out/real/<name>, built by samples/real/make_datasets.py (None when the shared sets are absent)."""
    script = SAMPLES / "make_datasets.py"
    if not SHARED.is_dir() or not script.is_file():
        return None
    dst = LINKED / name
    if not (dst / "rig.yaml").is_file():
        log(f"  linking {name} into {dst} ...")
        subprocess.run([sys.executable, str(script), str(LINKED), name], check=True, capture_output=True)
    return dst


class LinkedRun(NamedTuple):
    rig: rigcal.Rig
    corners: dict
    views: list
    head: dict  # set, images, detection_s, seconds (of the auto calibration)
    cal: object  # the calibration with --distortion auto


def _linked_run(name: str, log) -> LinkedRun | None:
    """A linked set detected (cached) and calibrated with auto; None when the set is absent."""
    d = linked(name, log)
    if d is None:
        return None
    rig, corners, views, n, det_s = detections(d, name, log)
    with Timer() as t:
        cal = calibrate_set(d, rig, corners, views)
    return LinkedRun(rig, corners, views, {"set": name, "images": n, "detection_s": det_s, "seconds": t.wall}, cal)


def wideangle(log=say) -> dict | None:
    run = _linked_run("wideangle", log)
    if run is None:
        return None
    return {**run.head, "baseline_mm": 1000 * _baseline(run.cal.rig, "left", "right"),
            "reference_mm": WIDEANGLE_REF_MM, **_cal_row(run.cal)}


CALISCOPE_SETS = {"caliscope": "caliscope_4cam_charuco_a", "caliscope_b": "caliscope_4cam_charuco_b"}


def _caliscope_doc(name: str = "caliscope") -> dict:
    return tomllib.loads((SHARED / CALISCOPE_SETS[name] / "camera_array.toml").read_text())


def caliscope_reference(name: str = "caliscope") -> dict[str, np.ndarray]:
    """caliscope's T_cam_world per camera (its camera_array.toml: x_cam = R x_world + t)."""
    return {f"cam_{k}": geo.make_T(np.array(v["rotation"]), np.array(v["translation"]))
            for k, v in _caliscope_doc(name)["cameras"].items()}


def caliscope_intrinsics_rig(rig, name: str = "caliscope"):
    """The declared rig with caliscope's own intrinsics (its camera_array.toml, calibrated by
    caliscope from separate recordings that are not in the set; the same in both sets)."""
    from rigcal.core.camera import CameraModel
    from rigcal.core.rig import Camera

    doc = _caliscope_doc(name)["cameras"]
    cams = []
    for c in rig.cameras:
        v = doc[c.name.split("_")[1]]
        K = np.array(v["matrix"])
        m = CameraModel("pinhole", c.intrinsics.width, c.intrinsics.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                        tuple(float(x) for x in v["distortions"]))
        cams.append(Camera(c.name, m, c.T_body_cam))
    return rig.with_cameras(cams)


def _caliscope_pairs(cal, ref: dict) -> dict:
    pairs = {}
    names = list(cal.cam_names)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            T_a_b = geo.inv_T(cal.rig.camera(a).T_body_cam) @ cal.rig.camera(b).T_body_cam
            R_a_b = ref[a] @ geo.inv_T(ref[b])  # caliscope's camera b in camera a
            pairs[f"{a}/{b}"] = {
                "distance_m": float(np.linalg.norm(T_a_b[:3, 3])),
                "reference_distance_m": float(np.linalg.norm(R_a_b[:3, 3])),
                "translation_diff_m": float(np.linalg.norm(T_a_b[:3, 3] - R_a_b[:3, 3])),
                "rotation_diff_deg": geo.rotation_angle_deg(T_a_b[:3, :3] @ R_a_b[:3, :3].T),
            }
    return pairs


def _intrinsics_vs(cal, ref_rig) -> dict:
    out = {}
    for c in cal.rig.cameras:
        m, r = c.intrinsics, ref_rig.camera(c.name).intrinsics
        out[c.name] = {"fx": m.fx, "fy": m.fy, "cx": m.cx, "cy": m.cy, "ref_fx": r.fx, "ref_fy": r.fy,
                       "ref_cx": r.cx, "ref_cy": r.cy, "model": cal.stats[c.name].distortion_model,
                       "sigma": cal.stats[c.name].sigma_intrinsics,
                       # getattr: this bench also runs on code from before these fields (before/after tables)
                       "structure": getattr(cal.stats[c.name], "intrinsics_model", None),
                       "sigma_free": getattr(cal.stats[c.name], "sigma_intrinsics_free", None)}
    return out


def caliscope(log=say, name: str = "caliscope") -> dict | None:
    run = _linked_run(name, log)
    if run is None:
        return None
    rig, corners, views, head, cal = run
    ref = caliscope_reference(name)
    ref_rig = caliscope_intrinsics_rig(rig, name)
    # diagnostic: the same detections with caliscope's intrinsics held fixed (extrinsics only)
    fixed = calibrate_views(views, ref_rig, corners, fix_intrinsics=True)
    # and with only caliscope's principal points held (focal lengths and distortion from
    # this set): does the gap come from the principal points?
    centred = calibrate_views(views, caliscope_centre_rig(rig, ref_rig), corners, intrinsics="centred")
    return {**head, "pairs": _caliscope_pairs(cal, ref), "intrinsics": _intrinsics_vs(cal, ref_rig),
            "fixed_reference_intrinsics": {"pairs": _caliscope_pairs(fixed, ref), "rms_px": fixed.rms_px},
            "reference_centres": {"pairs": _caliscope_pairs(centred, ref),
                                  "lr": centre_lr(rig, corners, views, ref_rig)},
            **_cal_row(cal)}


def caliscope_centre_rig(rig, ref_rig):
    """The declared rig with caliscope's principal points declared (nothing else of its)."""
    return rig.with_cameras([replace(c, intrinsics=c.intrinsics.with_(cx=ref_rig.camera(c.name).intrinsics.cx,
                                                                        cy=ref_rig.camera(c.name).intrinsics.cy))
                             for c in rig.cameras])


def centre_lr(rig, corners: dict, views: list, ref_rig) -> dict:
    """Per camera, how strongly its own views reject caliscope's principal point: the
    likelihood ratio (chi-square, 2 degrees of freedom; 18.4 at rigcal's level 1e-4) of a
    one-camera bundle adjustment (radtan4) with cx, cy held at caliscope's values against
    cx, cy free, on the same corners."""
    from rigcal.camcal.initialise import one_camera_solve
    from rigcal.camcal.model_selection import refit, with_structure
    from rigcal.camcal.solve import Intrinsics

    out = {}
    for c in rig.cameras:
        vs = [v for v in views if v.camera == c.name and len(v.ids) >= 4]
        r = ref_rig.camera(c.name).intrinsics
        start = Intrinsics("pinhole", np.array([r.fx, r.fy, r.cx, r.cy, *r.dist[:4]], float))
        free = one_camera_solve([corners[v.board][v.ids] for v in vs], [v.uv for v in vs], start)
        held = refit(free, 0, with_structure(free.state.intrinsics[0], False, True, (r.cx, r.cy)))
        out[c.name] = float((np.sum(held.residuals ** 2) - np.sum(free.residuals ** 2)) / free.sigma_px ** 2)
    return out


def trinocular(log=say) -> dict | None:
    run = _linked_run("trinocular", log)
    if run is None:
        return None
    base = {f"{a}/{b}": {"squares": _baseline(run.cal.rig, a, b), "opencv_pairwise": ref}
            for (a, b), ref in TRINOCULAR_REF_SQUARES.items()}
    return {**run.head, "baselines": base, **_cal_row(run.cal)}


def caliscope_b(log=say) -> dict | None:
    return caliscope(log, "caliscope_b")



def euroc(log=say) -> dict | None:
    """EuRoC imu_april corners, camera-only, every frame: what `rigcal calibrate` does with
    its corners/ files (no images, so no detection and no guided pass)."""
    import yaml

    from rigcal.data.corners import read_corners
    from rigcal.core.target import load_target

    d = linked("euroc", log)
    if d is None:
        return None
    rig = rigcal.load_rig(d / "rig.yaml")
    target = load_target(d / "target.yaml")
    with Timer() as tr:
        views = [BoardView(cam, f, b, ids, uv) for cam in rig.names
                 for f, b, ids, uv in read_corners(d / "corners" / f"{cam}.csv", target)]
    with Timer() as t:
        cal = calibrate_views(views, rig, {b.name: b.corners for b in target.boards},
                              faces={b.name: b.print_face for b in target.boards})
    ref = yaml.safe_load((SHARED / "euroc_imu_april" / "reference.yaml").read_text())
    intr = {}
    for c in cal.rig.cameras:
        m = c.intrinsics
        intr[c.name] = {"rigcal": [m.fx, m.fy, m.cx, m.cy], "euroc": ref[c.name]["intrinsics"],
                        "model": cal.stats[c.name].distortion_model}
    return {"set": "euroc", "frames": len({v.frame for v in views}), "read_s": tr.wall, "seconds": t.wall,
            "baseline_mm": 1000 * _baseline(cal.rig, "cam0", "cam1"), "reference_mm": 110.07, "intrinsics": intr,
            **_cal_row(cal)}


SETS = {"bumblebee2": bumblebee2, "opencv_stereo": opencv_stereo, "wideangle": wideangle, "caliscope": caliscope,
        "caliscope_b": caliscope_b, "trinocular": trinocular, "euroc": euroc}


def run(names: list[str] | None = None, log=say) -> dict:
    out = {}
    for name in names or list(SETS):
        log(f"real: {name} ...")
        out[name] = SETS[name](log)
    return out


def tables(res: dict) -> str:
    rows = []
    bb = res.get("bumblebee2")
    if bb:
        for dist, r in bb["runs"].items():
            rows.append(["bumblebee2", f"--distortion {dist} ({'/'.join(sorted(set(r['models'].values())))})",
                         "baseline mm", f"{r['baseline_mm']:.3f}", f"{bb['reference_mm']:.2f}",
                         f"{r['baseline_mm'] - bb['reference_mm']:+.3f} mm", r["rms_px"], r["seconds"]])
    oc = res.get("opencv_stereo")
    if oc:
        for lab, ref in oc["references"].items():
            rows.append(["opencv_stereo", f"auto ({'/'.join(sorted(set(oc['models'].values())))}), vs {lab}",
                         "baseline squares", f"{oc['baseline_squares']:.4f}", f"{ref:.4f}",
                         f"{100 * (oc['baseline_squares'] / ref - 1):+.2f} %", oc["rms_px"], oc["seconds"]])
    wa = res.get("wideangle")
    if wa:
        rows.append(["wideangle", f"auto ({'/'.join(sorted(set(wa['models'].values())))})", "baseline mm",
                     f"{wa['baseline_mm']:.3f}", f"{wa['reference_mm']:.2f}",
                     f"{wa['baseline_mm'] - wa['reference_mm']:+.3f} mm", wa["rms_px"], wa["seconds"]])
    tri = res.get("trinocular")
    if tri:
        for k, b in tri["baselines"].items():
            rows.append(["trinocular", f"auto, {k}", "baseline squares", f"{b['squares']:.4f}",
                         f"{b['opencv_pairwise']:.3f}",
                         f"{100 * (b['squares'] / b['opencv_pairwise'] - 1):+.2f} %", tri["rms_px"], tri["seconds"]])
    eu = res.get("euroc")
    if eu:
        rows.append(["euroc", f"corners/, {eu['frames']} frames, auto ({'/'.join(sorted(set(eu['models'].values())))})",
                     "baseline mm", f"{eu['baseline_mm']:.3f}", f"{eu['reference_mm']:.2f}",
                     f"{eu['baseline_mm'] - eu['reference_mm']:+.3f} mm", eu["rms_px"], eu["seconds"]])
        for cam, c in eu["intrinsics"].items():
            for k, (a, b) in zip(("fx", "fy", "cx", "cy"), zip(c["rigcal"], c["euroc"])):
                rows.append(["euroc", f"{cam} ({c['model']})", k, f"{a:.2f}", f"{b:.3f}", f"{100 * (a / b - 1):+.2f} %",
                             eu["rms_px"], eu["seconds"]])
    parts = [md_table(["set", "run", "quantity", "rigcal", "reference", "difference", "reproj RMS px", "calib s"],
                      rows, "Real images: calibrated vs published reference")]
    for key in CALISCOPE_SETS:
        cs = res.get(key)
        if cs:
            parts.extend(_caliscope_tables(key, cs))
    missing = [k for k in SETS if k in res and res[k] is None]
    if missing:
        parts.append(f"\nnot run (no {SHARED}): {', '.join(missing)}")
    return "\n".join(parts)


def _structure(c: dict) -> str:
    st = c.get("structure")
    return "-" if not st else f"{st['focal']}; cx,cy {st['principal_point']}"


def _caliscope_tables(key: str, cs: dict) -> list[str]:
    fx = cs["fixed_reference_intrinsics"]["pairs"]
    pc = cs.get("reference_centres", {}).get("pairs", {})
    rows = [[k, f"{p['distance_m']:.3f}", f"{p['reference_distance_m']:.3f}", 100 * p["translation_diff_m"],
             p["rotation_diff_deg"], 100 * fx[k]["translation_diff_m"], fx[k]["rotation_diff_deg"],
             100 * pc[k]["translation_diff_m"] if k in pc else None, pc[k]["rotation_diff_deg"] if k in pc else None]
            for k, p in cs["pairs"].items()]
    out = [md_table(["pair", "rigcal distance m", "caliscope distance m", "rel. translation diff cm",
                     "rel. rotation diff deg", "with caliscope's intrinsics fixed: cm", "deg",
                     "only caliscope's principal points held: cm", "deg"], rows,
                    f"{key} ({CALISCOPE_SETS[key]}) vs caliscope's own solution (target 2.5 cm / 2 deg; "
                    f"reproj RMS {cs['rms_px']:.3f} px, {cs['corners']} corners, models "
                    f"{sorted(set(cs['models'].values()))})")]
    lr = cs.get("reference_centres", {}).get("lr", {})
    rows = [[n, _structure(c), f"{c['fx']:.1f} / {c['fy']:.1f}", f"{c['ref_fx']:.1f} / {c['ref_fy']:.1f}",
             f"{c['cx']:.1f} / {c['cy']:.1f}", f"{c['ref_cx']:.1f} / {c['ref_cy']:.1f}", c["model"],
             (f"{c['sigma']['cx']:.1f} / {c['sigma']['cy']:.1f}" if c.get("sigma") else "-"),
             (f"{c['sigma_free']['cx']:.1f} / {c['sigma_free']['cy']:.1f}" if c.get("sigma_free") else "-"),
             lr.get(n)]
            for n, c in cs["intrinsics"].items()]
    out.append(md_table(["camera", "intrinsics", "rigcal fx / fy", "caliscope fx / fy", "rigcal cx / cy",
                         "caliscope cx / cy", "model", "rigcal 1-sigma cx / cy", "free: 1-sigma cx / cy",
                         "own views' LR against caliscope's cx, cy (needs 18.4)"], rows,
                        f"{key}: intrinsics from this set alone"))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", action="append", choices=list(SETS))
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = run(a.set)
    say(tables(res))
    write_json("real", {"results": res, "seconds": time.perf_counter() - t0})


if __name__ == "__main__":
    main()
