"""Why AprilGrid corners through the fisheye in the room scene are worse than ChArUco's,
and what the long-arm pass (corner_refine._aprilgrid_mapped) does about it.

    python -m bench.aprilgrid_excess [--frames 3] [--seed 1]

The four rendered cases of tests/detect/test_aprilgrid_render.py (same 6x6 targets, same seed and
frames), each noise-free and at noise 2, with the AprilGrid and with the ChArUco board.
Every detected AprilGrid corner is measured against the render's truth three ways, from
the same OpenCV tags: the corner square's box pass alone ("box"), today's detector (box,
then the affine cross with the lattice's bends: "detector") and the long-arm pass
(april.LONG_ARMS_BELOW_PX raised above every tag: "long arms"); with the true lens and
pose placing the pairs ("exact geometry": symmetric cross alone, then with the long arms)
for the information limit of each pattern. Split by tag size (px), by k and by whether the
corner was restarted from its neighbours. Then the real EuRoC frames: PnP with EuRoC's
intrinsics, the residual of a smooth map of the board fitted to the corners (truth-free
roughness), and how far the long arms move each corner towards its own tag's inside (the
signature of a print whose edges are not where its junctions put them; the long arms
estimate that offset per view, april.FIT_EDGE_SHIFT); also on the real frames averaged down
1.5x and 2x, whose tags are then as small as the fisheye room's (EUROC_SCALES).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np
import yaml

from rigcal.detect import april
from rigcal.core import geometry as geo
from rigcal.detect.board_detectors import BoardDetector
from rigcal.data.truth import load_truth
from rigcal.detect.corner_fit import STEP_PX, cell_px, cross_offsets, image_gradients, refine_pairs
from rigcal.detect.corner_refine import MAX_PAIRS_PER_TAG_EDGE, aprilgrid_box_passes, refine_corners
from rigcal.data.image_read import read_gray
from rigcal.core.rig import load_rig
from rigcal.sim.simulate import simulate_dataset
from rigcal.core.target import load_target, parse_target

from .common import RIGS, md_table, say, write_json

ROOT = Path(__file__).resolve().parents[1]
EUROC = ROOT.parent / "shared" / "data" / "real" / "euroc_imu_april"
GRID = "boards:\n  - {name: grid, type: aprilgrid, tags: [6, 6], tag_size: 0.088, tag_spacing: 0.3}\n"
CHARUCO = ("boards:\n  - {name: grid, type: charuco, dictionary: DICT_5X5_1000, squares: [6, 6], "
           "square_length: 0.1188, marker_length: 0.0891}\n")
CASES = (("stereo-forward", "board"), ("stereo-forward", "room"), ("fisheye-stereo", "board"),
         ("fisheye-stereo", "room"))
SIZE_BINS = (0.0, 30.0, 45.0, 80.0, np.inf)


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e)))) if len(e) else float("nan")


def _views(ds: Path):
    """(gray, camera, board, T_cam_board) per image of a rendered dataset."""
    truth = load_truth(ds / "truth.yaml")
    target = load_target(ds / "target.yaml")
    board = target.boards[0]
    for cam in truth.rig.cameras:
        for p in sorted((ds / "images" / cam.name).glob("*.png")):
            T = geo.inv_T(truth.T_world_body[p.stem] @ cam.T_body_cam) @ truth.board_pose(p.stem, board.name)
            yield read_gray(p)[0], cam, target, board, T


def _project(cam, T: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return cam.intrinsics.project(geo.transform(T, np.column_stack([xy, np.zeros(len(xy))])))[0]


def _exact_pass(stack, cam, T, board, ids, start, long_arms: bool):
    """The long-arm fit (or the symmetric cross alone) with the pairs placed by the true lens
    and pose: what the pattern itself allows."""
    xy = board.corners[ids, :2]
    c0 = _project(cam, T, xy)
    h = 1e-3 * board.tag_size
    ax, ay = ((_project(cam, T, xy + s) - c0) / 1e-3 for s in ([h, 0.0], [0.0, h]))
    size = cell_px(ax, ay)
    delta = max(STEP_PX / float(np.median(size)), 1.0 / MAX_PAIRS_PER_TAG_EDGE)
    cross = cross_offsets(min(april.BORDER_FRACTION, board.tag_spacing), 1.0, delta)
    w, anti = april.junction_pattern(ids, board, cross, size)
    if not long_arms:
        w &= ~anti
        anti[:] = False
    off = cross * board.tag_size
    n, k = len(ids), len(cross)
    ends = _project(cam, T, np.concatenate([(xy[:, None] + off).reshape(-1, 2), (xy[:, None] - off).reshape(-1, 2)]))
    Dp, Dm = ends.reshape(2, n, k, 2) - c0[None, :, None]
    sign = np.where(anti, -1.0, 1.0).astype(np.float32)
    q, ok, _ = refine_pairs(stack, start, cross, np.nan_to_num(Dp), np.nan_to_num(Dm), w.astype(np.float32), sign)
    return q, ok & np.isfinite(Dp).all((1, 2))


def _box_only(gray, board, ids, uv):
    """The box passes of corner_refine.refine_aprilgrid (with the neighbours' restart), on the
    whole image: corners, ok, restarted, and the gradient stack."""
    ax, ay = april.corner_axes(ids, uv)
    stack = image_gradients(gray)
    q, ok, _, restarted = aprilgrid_box_passes(gray, stack, board, ids, uv, ax, ay,
                                               april.symmetric_box(board, ax, ay))
    return q, ok, restarted, stack


def _refine_with(gray, board, ids, uv, long_arms: bool):
    return refine_corners(gray, board, ids, uv, "long-arms" if long_arms else "symmetric")


def aprilgrid_errors(ds: Path) -> dict[str, np.ndarray]:
    """Per-corner errors (px) of every method, and each corner's tag size, k, restart flag."""
    cols: dict[str, list] = {k: [] for k in ("box", "detector", "long arms", "exact symmetric", "exact long arms",
                                             "size", "k", "restarted")}
    for gray, cam, target, board, T in _views(ds):
        for b, ids, uv, _ in BoardDetector(target).raw(gray):
            order = np.argsort(ids, kind="stable")
            ids, uv = ids[order], uv[order]
            if len(ids) < 6:
                continue
            truth = _project(cam, T, board.corners[ids, :2])
            qb, ok, restarted, stack = _box_only(gray, board, ids, uv)
            qd, okd, _ = _refine_with(gray, board, ids, uv, False)
            ql, okl, _ = _refine_with(gray, board, ids, uv, True)
            keep = ok & okd & okl
            if not keep.any():
                continue
            qs, oks = _exact_pass(stack, cam, T, board, ids[keep], qb[keep], False)
            qx, okx = _exact_pass(stack, cam, T, board, ids[keep], qb[keep], True)
            ax, ay = april.corner_axes(ids, qb)
            size = cell_px(ax, ay)
            for name, q in (("box", qb), ("detector", qd), ("long arms", ql)):
                cols[name].append(np.linalg.norm(q - truth, axis=1)[keep])
            cols["exact symmetric"].append(np.where(oks, np.linalg.norm(qs - truth[keep], axis=1), np.nan))
            cols["exact long arms"].append(np.where(okx, np.linalg.norm(qx - truth[keep], axis=1), np.nan))
            cols["size"].append(size[keep])
            cols["k"].append(ids[keep] % 4)
            cols["restarted"].append(restarted[keep])
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}


def charuco_errors(ds: Path) -> np.ndarray:
    out = []
    for gray, cam, target, board, T in _views(ds):
        for name, ids, uv, _ in BoardDetector(target).detect(gray)[0]:
            out.append(np.linalg.norm(uv - _project(cam, T, board.corners[ids, :2]), axis=1))
    return np.concatenate(out) if out else np.zeros(0)


# The real print made small: EuRoC's frames averaged down (cv2.INTER_AREA) by these factors,
# so its 28-34 px tags become 14-17 px ones (the fisheye room's third frame) with the print's
# own edges and junctions; EuRoC's intrinsics are scaled with the pixel centres.
EUROC_SCALES = (1.0, 1.5, 2.0)


def euroc(scales=EUROC_SCALES) -> list[dict]:
    """PnP RMS with EuRoC's intrinsics, detector against long arms, and the long arms' move
    towards each corner's own tag (px per board axis, mean and spread), per camera and per
    downscaling of the real frames (px in the downscaled image's own pixels)."""
    if not (EUROC / "kalibr_target.yaml").exists():
        return []
    target = load_target(EUROC / "kalibr_target.yaml")
    board = target.boards[0]
    ref = yaml.safe_load((EUROC / "reference.yaml").read_text())
    rows = []
    for scale in scales:
        for cam in (0, 1):
            full = cv2.imread(str(EUROC / "images" / f"cam{cam}_1403709395937837056.png"), cv2.IMREAD_GRAYSCALE)
            gray = full if scale == 1.0 else cv2.resize(full, None, fx=1 / scale, fy=1 / scale,
                                                          interpolation=cv2.INTER_AREA)
            found = BoardDetector(target).raw(gray)
            if not found:
                rows.append({"camera": f"cam{cam}", "scale": scale})
                continue
            (_, ids, uv, _), = found
            order = np.argsort(ids, kind="stable")
            ids, uv = ids[order], uv[order]
            fx, fy, cx, cy = ref[f"cam{cam}"]["intrinsics"]
            # cv2.resize's pixel centres: x' = (x + 0.5) / scale - 0.5
            K = np.array([[fx / scale, 0, (cx + 0.5) / scale - 0.5], [0, fy / scale, (cy + 0.5) / scale - 0.5],
                          [0, 0, 1.0]])
            D = np.array(ref[f"cam{cam}"]["distortion"], float)
            row = {"camera": f"cam{cam}", "scale": scale}
            got = {}
            for name, long_arms in (("detector", False), ("long arms", True)):
                q, ok, _ = _refine_with(gray, board, ids, uv, long_arms)
                obj = board.corners[ids[ok]]
                _, r, t = cv2.solvePnP(obj, q[ok], K, D)
                r, t = cv2.solvePnPRefineLM(obj, q[ok], K, D, r, t)
                e = np.linalg.norm(cv2.projectPoints(obj, r, t, K, D)[0].reshape(-1, 2) - q[ok], axis=1)
                row[f"{name} corners"], row[f"{name} PnP px"] = int(ok.sum()), _rms(e)
                # truth-free roughness: what a smooth map of the board (homography + quartic) leaves
                m = april.view_map(ids[ok], q[ok], board)
                row[f"{name} map residual px"] = (_rms(np.linalg.norm(m(obj[:, :2]) - q[ok], axis=1)) if m
                                                  else float("nan"))
                got[name] = (q, ok)
            (qd, okd), (ql, okl) = got["detector"], got["long arms"]
            both = okd & okl
            ax, ay = april.corner_axes(ids, qd)
            s = np.linalg.solve(np.stack([ax, ay], -1)[both], (ql - qd)[both][..., None])[..., 0]  # tag sizes
            size = cell_px(ax[both], ay[both])
            inwards = s * april.TOWARDS_TAG[ids[both] % 4] * size[:, None]  # px along each board axis
            row["move towards own tag px (mean)"] = float(inwards.mean())
            row["move towards own tag px (std)"] = float(inwards.std())
            row["tag size px"] = float(np.median(size))
            rows.append(row)
    return rows


def run(frames: int = 3, seed: int = 1, cases=CASES, noises=(0.0, 2.0), with_euroc: bool = True) -> dict:
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for rig_name, scene in cases:
            rig = load_rig(RIGS / f"{rig_name}.yaml")
            for noise in noises:
                dirs = {}
                for name, text in (("aprilgrid", GRID), ("charuco", CHARUCO)):
                    dirs[name] = Path(tmp) / f"{rig_name}-{scene}-{noise:g}-{name}"
                    simulate_dataset(rig, dirs[name], scene=scene, frames=frames, seed=seed, noise=noise,
                                     target=parse_target(text), jobs=1)
                e = aprilgrid_errors(dirs["aprilgrid"])
                res = {"case": f"{rig_name} {scene}", "noise": noise, "charuco": _rms(charuco_errors(dirs["charuco"])),
                       "n": int(len(e["size"]))}
                methods = ("box", "detector", "long arms", "exact symmetric", "exact long arms")
                res.update({m: _rms(e[m][np.isfinite(e[m])]) for m in methods})
                res["by size"] = [{"size px": f"{lo:g}-{hi:g}", "n": int(m.sum()),
                                   **{k: _rms(e[k][m & np.isfinite(e[k])]) for k in methods}}
                                  for lo, hi in zip(SIZE_BINS[:-1], SIZE_BINS[1:])
                                  if (m := (e["size"] >= lo) & (e["size"] < hi)).any()]
                res["by k"] = [{"k": k, **{m: _rms(e[m][(e["k"] == k) & np.isfinite(e[m])]) for m in methods[:3]}}
                               for k in range(4)]
                res["restarted"] = {"n": int(e["restarted"].sum()),
                                    "detector": _rms(e["detector"][e["restarted"]]),
                                    "detector (others)": _rms(e["detector"][~e["restarted"]])}
                results.append(res)
    return {"rendered": results, "euroc": euroc() if with_euroc else []}


def tables(r: dict) -> str:
    head = ["case", "noise", "corners", "box", "detector", "long arms", "exact symmetric", "exact long arms", "ChArUco"]
    rows = [[x["case"], x["noise"], x["n"], x["box"], x["detector"], x["long arms"], x["exact symmetric"],
             x["exact long arms"], x["charuco"]] for x in r["rendered"]]
    out = [md_table(head, rows, "AprilGrid corner error vs truth (px RMS), same corners per row; ChArUco on the same scene")]
    size_rows = [[x["case"], x["noise"], s["size px"], s["n"], s["box"], s["detector"], s["long arms"],
                  s["exact symmetric"], s["exact long arms"]] for x in r["rendered"] for s in x["by size"]]
    out.append(md_table(["case", "noise", "tag px", "n", "box", "detector", "long arms", "exact symmetric",
                         "exact long arms"], size_rows, "by tag size"))
    if r["euroc"]:
        keys = list(max(r["euroc"], key=len))
        out.append(md_table(keys, [[row.get(k, "-") for k in keys] for row in r["euroc"]],
                            "real EuRoC frames: PnP with EuRoC's intrinsics; the long arms' move towards each corner's tag"))
    return "\n\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    r = run(a.frames, a.seed)
    write_json("aprilgrid_excess", r)
    say(tables(r))


if __name__ == "__main__":
    main()
