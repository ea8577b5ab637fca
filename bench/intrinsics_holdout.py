"""Held-out views decide between two sets of intrinsics (the caliscope gap).

On caliscope's webcams rigcal's principal points land 10-35 px from caliscope's, and the
pairs' rotations follow them. A likelihood ratio on the same corners (bench.real) says
these images reject caliscope's principal points, but it trusts the noise model. This
asks the question that does not: two-fold cross-validation over frames. Each camera's
intrinsics are fitted on the even frames (then the odd), by

* rigcal auto:   `rigcal calibrate`'s default (--intrinsics auto),
* rigcal free:   every intrinsic estimated (--intrinsics free),
* caliscope pp:  caliscope's principal points held, the rest fitted here,
* caliscope:     caliscope's own intrinsics (its camera_array.toml, fitted on other recordings),

and each is scored on the other half's views: a PnP per held-out view (IPPE, then
Levenberg-Marquardt) with the intrinsics held, and the RMS of those reprojections. The
intrinsics that better predict views they were not fitted to are the better-supported.

    python -m bench.intrinsics_holdout [--set caliscope ...]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import cv2
import numpy as np

from rigcal.core import geometry as geo
from rigcal.camcal.pipeline import calibrate_views

from .common import md_table, say, write_json
from .real import caliscope_centre_rig, caliscope_intrinsics_rig, caliscope_reference, detections, linked

SETS = ("caliscope", "caliscope_b")
VARIANTS = ("rigcal auto", "rigcal free", "caliscope pp", "caliscope")


def pnp_rms(model, obj: list[np.ndarray], img: list[np.ndarray]) -> tuple[float, int]:
    """(RMS px, corners) of per-view PnP with `model`'s intrinsics held."""
    K, D = model.K, np.asarray(model.dist, float)
    sq, n = 0.0, 0
    for o, i in zip(obj, img):
        o64, i64 = np.ascontiguousarray(o, np.float64), np.ascontiguousarray(i, np.float64)
        ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(o64, i64, K, D, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            continue
        best = None
        for r, t in zip(rvecs, tvecs):
            r, t = cv2.solvePnPRefineLM(o64, i64, K, D, r.copy(), t.copy())
            e = cv2.projectPoints(o64, r, t, K, D)[0].reshape(-1, 2) - i64
            s = float(np.sum(e ** 2))
            best = s if best is None or s < best else best
        sq += best
        n += len(o)
    return (float(np.sqrt(sq / n)) if n else float("nan")), n


def cross_errors(rig, views: list, corners: dict) -> list[tuple[float, int]]:
    """(RMS px, corners) per predicted view, predicting camera b's held-out view of a board from camera a's:
    the board's pose by PnP in a (a's intrinsics), carried to b by the rig's T_a_b, projected
    with b's intrinsics; over every ordered pair of cameras that saw the same board in the
    same frame. This scores the extrinsics and intrinsics together: a principal point off by
    p px turns the camera by about p / f rad, which moves b's prediction by p px."""
    by_key = {}
    for v in views:
        by_key.setdefault((v.frame, v.board), {})[v.camera] = v
    out = []
    for (frame, board), per in by_key.items():
        for a, va in per.items():
            ma = rig.camera(a).intrinsics
            o = np.ascontiguousarray(corners[board][np.asarray(va.ids)], np.float64)
            ok, rvecs, tvecs, errs = cv2.solvePnPGeneric(o, np.asarray(va.uv, np.float64), ma.K,
                                                         np.asarray(ma.dist, float), flags=cv2.SOLVEPNP_IPPE)
            if not ok:
                continue
            r, t = cv2.solvePnPRefineLM(o, np.asarray(va.uv, np.float64), ma.K, np.asarray(ma.dist, float),
                                        rvecs[0].copy(), tvecs[0].copy())
            T_a_board = geo.make_T(cv2.Rodrigues(r)[0], t.ravel())
            for b, vb in per.items():
                if b == a:
                    continue
                mb = rig.camera(b).intrinsics
                T_b_board = geo.inv_T(rig.camera(b).T_body_cam) @ rig.camera(a).T_body_cam @ T_a_board
                ob = corners[board][np.asarray(vb.ids)].astype(np.float64)
                rb, _ = cv2.Rodrigues(T_b_board[:3, :3])
                uv = cv2.projectPoints(ob, rb, T_b_board[:3, 3], mb.K, np.asarray(mb.dist, float))[0].reshape(-1, 2)
                out.append((float(np.sqrt(np.mean(np.sum((uv - np.asarray(vb.uv, float)) ** 2, 1)))), len(ob)))
    return out


def caliscope_rig(rig, name: str):
    """caliscope's whole solution as a rig: its intrinsics and its T_cam_world (world = body)."""
    ref = caliscope_reference(name)
    return caliscope_intrinsics_rig(rig, name).with_cameras(
        [replace(c, T_body_cam=geo.inv_T(ref[c.name])) for c in caliscope_intrinsics_rig(rig, name).cameras])


def _fits(train: list, rig, corners: dict, ref_rig) -> dict:
    """Intrinsics per variant (rig with the fitted cameras) from the training views."""
    return {"rigcal auto": calibrate_views(train, rig, corners).rig,
            "rigcal free": calibrate_views(train, rig, corners, intrinsics="free").rig,
            "caliscope pp": calibrate_views(train, caliscope_centre_rig(rig, ref_rig), corners,
                                            intrinsics="centred").rig,
            "caliscope": ref_rig}


def _cross_fits(fits: dict, name: str, rig) -> dict:
    """The rigs whose camera-to-camera predictions are scored: rigcal's (fitted on the
    training half) and caliscope's whole solution."""
    return {"rigcal auto": fits["rigcal auto"], "rigcal free": fits["rigcal free"],
            "caliscope pp": fits["caliscope pp"], "caliscope": caliscope_rig(rig, name)}


def run_set(name: str, log=say) -> dict | None:
    d = linked(name, log)
    if d is None:
        return None
    rig, corners, views, _, _ = detections(d, name, log)
    ref_rig = caliscope_intrinsics_rig(rig, name)
    scores = {c: {v: [0.0, 0] for v in VARIANTS} for c in rig.names}
    cross = {v: [] for v in VARIANTS}
    parity = {f: i % 2 for i, f in enumerate(sorted({v.frame for v in views}))}  # frames are names
    for fold in (0, 1):
        train = [v for v in views if parity[v.frame] == fold]
        test = [v for v in views if parity[v.frame] != fold and len(v.ids) >= 6]
        log(f"  {name}: fold {fold}, {len(train)} training views, {len(test)} held out ...")
        fits = _fits(train, rig, corners, ref_rig)
        for c in rig.names:
            mine = [v for v in test if v.camera == c]
            obj = [corners[v.board][np.asarray(v.ids)] for v in mine]
            img = [np.asarray(v.uv, float) for v in mine]
            for variant, fitted in fits.items():
                rms, n = pnp_rms(fitted.camera(c).intrinsics, obj, img)
                scores[c][variant][0] += rms ** 2 * n
                scores[c][variant][1] += n
        for variant, fitted in _cross_fits(fits, name, rig).items():
            cross[variant] += cross_errors(fitted, test, corners)
    score = lambda s, n: {"rms_px": float(np.sqrt(s / n)) if n else None, "corners": n}  # noqa: E731
    return {"cameras": {c: {v: score(*sn) for v, sn in per.items()} for c, per in scores.items()},
            "cross": {v: _cross_score(e) for v, e in cross.items()}}


def _cross_score(errors: list[tuple[float, int]]) -> dict:
    """RMS over all predicted corners, and the median view's RMS (the cameras' software sync
    leaves some views of a moving board far off whatever the rig; the median shows the rest)."""
    rms = np.array([e[0] for e in errors])
    n = np.array([e[1] for e in errors])
    return {"rms_px": float(np.sqrt(np.sum(rms ** 2 * n) / n.sum())), "median_view_px": float(np.median(rms)),
            "corners": int(n.sum()), "views": len(errors)}


def run(names: list[str] | None = None, log=say) -> dict:
    return {n: run_set(n, log) for n in names or SETS}


def tables(res: dict) -> str:
    rows, cross = [], []
    for name, r in res.items():
        if r is None:
            continue
        for cam, v in r["cameras"].items():
            rms = [v[k]["rms_px"] for k in VARIANTS]
            rows.append([name, cam, v[VARIANTS[0]]["corners"], *rms, VARIANTS[int(np.argmin(rms))]])
        med = [r["cross"][k]["median_view_px"] for k in VARIANTS]
        cross.append([name, r["cross"][VARIANTS[0]]["views"],
                      *[f"{r['cross'][k]['rms_px']:.2f} / {m:.2f}" for k, m in zip(VARIANTS, med)],
                      VARIANTS[int(np.argmin(med))]])
    heads = [f"{k} px" for k in VARIANTS]
    return "\n\n".join([
        md_table(["set", "camera", "held-out corners", *heads, "best"], rows,
                 title="Intrinsics scored on held-out frames (2-fold, per-view PnP RMS)"),
        md_table(["set", "predicted views", *[f"{k}: RMS / median px" for k in VARIANTS], "best (median)"], cross,
                 title="Whole rigs on held-out frames: camera b's view predicted from camera a's (2-fold)")])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", action="append", choices=SETS)
    a = ap.parse_args(argv)
    res = run(a.set)
    write_json("intrinsics_holdout", res)
    print(tables(res))


if __name__ == "__main__":
    main()
