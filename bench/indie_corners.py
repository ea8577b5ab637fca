"""Detected corners against the exact ones on a recording of tests/support/indie_motion.py,
by where they lie relative to the other boards' sheets: what a board partly in front of
another does to the corners behind it, with and without detect.overlap.

Per image (every --every'th of each camera): rigcal's detector finds the boards; the true
pixel of every detected corner is the projection of the board's corner (truth.yaml's
boards, frames and true cameras; OpenCV's projection, as the renderer's). Each corner is
put in a row by its image distance, in its own board's squares, to the nearest other
board's sheet outline (the pattern plus indie_render's paper margin) and by whether that
sheet is nearer the camera than the corner (the corner is behind: the outline it sees is
an occluding edge) or further (the outline lies behind the corner's board).

    python -m bench.indie_corners DATASET [--every 10] [--cameras front_left,front_right]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import yaml

import rigcal.detect.board_detectors as board_detectors
from rigcal.core.target import load_target
from rigcal.data.image_read import read_gray
from rigcal.detect.overlap import pattern_rect

from .common import md_table

from tests.support import indie_render as ir

BINS = (0.0, 0.25, 0.5, 1.0, np.inf)  # distance to the other sheet's outline, squares


def _T(d: dict) -> np.ndarray:
    return ir.pose(np.asarray(d["rotation"], float), np.asarray(d["position"], float))


def _project(p: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of camera-frame points (N, 3), OpenCV's pinhole + radtan."""
    p = np.ascontiguousarray(p, np.float64).reshape(-1, 1, 3)
    return cv2.projectPoints(p, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)


def sheet_outline(board) -> np.ndarray:
    """(4, 2) board-frame corners of the printed sheet (pattern + indie_render's margin)."""
    return pattern_rect(board, ir.PAPER_MARGIN_SQUARES * board.square_length)


def corner_rows(ds: Path, every: int, cameras: list[str], overlap: bool) -> list[dict]:
    """One dict per detected corner: error (px), own sigma, distance (squares) to the nearest
    other sheet's outline and whether that sheet is in front."""
    truth = yaml.safe_load((ds / "truth.yaml").read_text())
    target = load_target(ds / "target.yaml")
    boards = {b.name: b for b in target.boards}
    T_world_board = {n: _T(d) for n, d in truth["boards"].items()}
    keep = board_detectors.near_other_boards
    if not overlap:
        board_detectors.near_other_boards = lambda views, size: [np.zeros(len(v[1]), bool) for v in views]
    try:
        det = board_detectors.BoardDetector(target)
        rows = []
        for cam in cameras:
            c = truth["rig"]["cameras"][cam]
            it = c["intrinsics"]
            K = np.array([[it["fx"], 0, it["cx"]], [0, it["fy"], it["cy"]], [0, 0, 1.0]])
            D = np.asarray(c["distortion"], float)
            for f in sorted((ds / "images" / cam).glob("*.png"))[::every]:
                T_cam_world = ir.inv(_T(truth["frames"][f.stem]) @ _T(c))
                T_cam = {n: T_cam_world @ T for n, T in T_world_board.items()}
                outlines = {}
                for n, b in boards.items():
                    s = sheet_outline(b)
                    t = np.linspace(0, 1, 100, endpoint=False)[:, None]
                    pts = np.concatenate([s[k] + t * (s[(k + 1) % 4] - s[k]) for k in range(4)])
                    p = np.column_stack([pts, np.zeros(len(pts)), np.ones(len(pts))]) @ T_cam[n].T
                    p = p[p[:, 2] > 0.05, :3]
                    outlines[n] = _project(p, K, D) if len(p) else np.zeros((0, 2))
                for name, ids, uv, _, sigma in det.detect_with_sigma(read_gray(str(f))[0])[0]:
                    b = boards[name]
                    P = (np.column_stack([b.corners[ids], np.ones(len(ids))]) @ T_cam[name].T)[:, :3]
                    true = _project(P, K, D)
                    err = np.linalg.norm(uv - true, axis=1)
                    sq = b.square_length * it["fx"] / P[:, 2]
                    for j in range(len(ids)):
                        best, front = np.inf, False
                        for n2, o in outlines.items():
                            if n2 == name or not len(o):
                                continue
                            d = float(np.min(np.linalg.norm(o - true[j], axis=1)))
                            if d < best:
                                # the other sheet's plane along this corner's ray: nearer than the corner?
                                nrm, org = T_cam[n2][:3, 2], T_cam[n2][:3, 3]
                                ray = P[j] / np.linalg.norm(P[j])
                                s = float(nrm @ org) / float(nrm @ ray)
                                best, front = d, bool(0 < s < np.linalg.norm(P[j]))
                        rows.append({"err": float(err[j]), "sigma": float(sigma[j]), "dist_sq": best / sq[j],
                                     "behind": front})
        return rows
    finally:
        board_detectors.near_other_boards = keep


def table(rows: list[dict], title: str) -> str:
    e = np.array([r["err"] for r in rows])
    s = np.array([r["sigma"] for r in rows])
    d = np.array([r["dist_sq"] for r in rows])
    behind = np.array([r["behind"] for r in rows])
    out = []
    for label, m in (("behind the other sheet (its edge occludes)", behind), ("in front of the other sheet", ~behind)):
        for lo, hi in zip(BINS[:-1], BINS[1:]):
            k = m & (d >= lo) & (d < hi)
            if k.any():
                out.append([label, f"{lo:g}-{hi:g}", int(k.sum()), f"{np.sqrt(np.mean(e[k] ** 2)):.3f}",
                            f"{e[k].max():.2f}", f"{100 * np.mean(e[k] > 0.1):.0f} %",
                            f"{np.median(e[k] / s[k]):.1f}"])
    return md_table(["corner", "distance to the other sheet's outline (squares)", "corners", "RMS error px",
                     "max px", "> 0.1 px", "median error / own sigma"], out, title=title)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--every", type=int, default=10, help="every n-th image of each camera")
    ap.add_argument("--cameras", default="front_left,front_right")
    a = ap.parse_args(argv)
    cams = a.cameras.split(",")
    for overlap in (False, True):
        rows = corner_rows(a.dataset, a.every, cams, overlap)
        print(table(rows, f"{a.dataset.name}: {len(rows)} corners of {', '.join(cams)} (every {a.every}th image), "
                          f"detect.overlap {'on' if overlap else 'off'}"))
        print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
