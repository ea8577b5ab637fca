"""Stereo checks the way downstream stereo code uses a calibration (docs/cli.md, depth check).

Per stereo pair: rectify with the calibrated parameters (cv2.stereoRectify), take
the corners both cameras saw in the same frame, and compare the depth from their
rectified disparity, Z = B f / d, with the depth of the same corners from the
calibrated board pose (and, for a simulated dataset, from the truth). The RMS of the
rectified vertical disparity is 0 for a perfect calibration and grows with any
error in the relative pose or the distortion.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigcal.core import geometry as geo
from rigcal.errors import RigcalError
from rigcal.core.stereo import StereoRectification, rectify_pair, rectify_pixels

BANDS_M = (0.0, 1.0, 2.0, 4.0, 8.0, float("inf"))


def _band_stats(z_ref: np.ndarray, rel: np.ndarray) -> list[dict]:
    out = []
    for lo, hi in zip(BANDS_M[:-1], BANDS_M[1:]):
        m = (z_ref >= lo) & (z_ref < hi)
        if m.sum() == 0:
            continue
        out.append({"range_m": [lo, hi if np.isfinite(hi) else None], **_stats(rel[m])})
    return out


def _stats(rel: np.ndarray) -> dict:
    a = np.abs(rel) * 100.0
    return {"count": int(len(a)), "median_rel_error_pct": round(float(np.median(a)), 4),
            "p95_rel_error_pct": round(float(np.percentile(a, 95)), 4)}


def pair_correspondences(cal, left: str, right: str):
    """Inlier corners seen by both cameras in the same frame and board.
    Returns (uv_left, uv_right, p_left_cam from the calibrated poses, frame idx, board idx, p_board)."""
    obs = cal.obs.subset(cal.inliers)
    cl, cr = cal.cam_names.index(left), cal.cam_names.index(right)
    # key each corner by (frame, board, corner position); corners of one board are distinct points
    def keyed(c):
        m = obs.cam == c
        k = np.round(obs.p_board[m] * 1e6).astype(np.int64)
        keys = np.column_stack([obs.frame[m], obs.board[m], k])
        return keys, obs.uv[m], obs.frame[m], obs.board[m], obs.p_board[m]

    kl, uvl, fl, bl, pl = keyed(cl)
    kr, uvr, _, _, _ = keyed(cr)
    if len(kl) == 0 or len(kr) == 0:
        return None
    dt = np.dtype([(f"f{i}", np.int64) for i in range(kl.shape[1])])
    sl = np.ascontiguousarray(kl).view(dt).ravel()
    sr = np.ascontiguousarray(kr).view(dt).ravel()
    common, il, ir = np.intersect1d(sl, sr, return_indices=True)
    if len(common) == 0:
        return None
    st = cal.state
    T_left = st.T_cam_body[cl][None] @ st.T_body_world[fl[il]] @ st.T_world_board[bl[il]]
    p_left = np.einsum("nij,nj->ni", T_left[:, :3, :3], pl[il]) + T_left[:, :3, 3]
    return uvl[il], uvr[ir], p_left, fl[il], bl[il], pl[il]


@dataclass(frozen=True)
class DepthSamples:
    """Per shared corner inside both rectified images: depth from the calibrated board pose
    along the rectified left axis (z_pose), from disparity (z_disp), vertical disparity (px)."""

    rect: StereoRectification
    z_pose: np.ndarray
    z_disp: np.ndarray
    v_disparity: np.ndarray
    frames: np.ndarray
    boards: np.ndarray
    p_board: np.ndarray

    @property
    def rel(self) -> np.ndarray:
        return (self.z_disp - self.z_pose) / self.z_pose


def depth_samples(cal, left: str, right: str) -> DepthSamples | None:
    """The per-corner data of the depth check; None when the pair shares no usable corner."""
    corr = pair_correspondences(cal, left, right)
    if corr is None:
        return None
    rig = cal.rig
    rect = rectify_pair(rig.camera(left), rig.camera(right))
    uvl, uvr, p_left, frames, boards, p_board = corr
    rl = rectify_pixels(rect, rig.camera(left), uvl, "left")
    rr = rectify_pixels(rect, rig.camera(right), uvr, "right")
    ok = np.all(np.isfinite(rl), axis=1) & np.all(np.isfinite(rr), axis=1)
    # Only corners a rectified-stereo pipeline would see: inside both rectified images.
    # Far off-axis (fisheye) the rectified plane stretches without bound and 0.1 px of
    # corner noise becomes metres of depth there, which says nothing about the calibration.
    w, h = rect.size
    with np.errstate(invalid="ignore"):
        for q in (rl, rr):
            ok &= (q[:, 0] >= -0.5) & (q[:, 0] <= w - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= h - 0.5)
        ok &= rl[:, 0] - rr[:, 0] > 0
    if not ok.any():
        return None
    disp = rl[ok, 0] - rr[ok, 0]
    return DepthSamples(rect, (p_left[ok] @ rect.R1.T)[:, 2], rect.baseline_m * rect.f / disp,
                        rl[ok, 1] - rr[ok, 1], frames[ok], boards[ok], p_board[ok])


def depth_check(cal, left: str, right: str, truth=None) -> dict:
    """One stereo pair's entry of the calibrated YAML: baseline, the 10 m sanity figures and
    (where the cameras share corners) the depth check, against the truth too when given."""
    rig = cal.rig
    rect = rectify_pair(rig.camera(left), rig.camera(right))
    out = {"baseline_m": rect.baseline_m, "sanity_10m": sanity_10m(rig, left, right, rect)}
    ds = depth_samples(cal, left, right)
    if ds is None:
        return out
    rel = ds.rel
    dc = {
        "corners": int(len(rel)),
        "frames": int(len(np.unique(ds.frames))),
        "vertical_disparity_rms_px": round(float(np.sqrt(np.mean(ds.v_disparity**2))), 5),
        "overall": _stats(rel),
        "bands": _band_stats(ds.z_pose, rel),
    }
    if truth is not None:
        z_true = _true_rectified_depth(cal, truth, left, rect, ds.frames, ds.boards, ds.p_board)
        if z_true is not None:
            m = np.isfinite(z_true)
            if m.any():
                rel_t = (ds.z_disp[m] - z_true[m]) / z_true[m]
                dc["vs_truth"] = {"overall": _stats(rel_t), "bands": _band_stats(z_true[m], rel_t)}
    out["depth_check"] = dc
    return out


def _true_rectified_depth(cal, truth, left, rect, frames, boards, p_board):
    """True depth of each corner along the calibrated rectified left axis."""
    try:
        T_body_left = truth.rig.camera(left).T_body_cam
    except KeyError:
        return None
    z = np.full(len(frames), np.nan)
    for f in np.unique(frames):
        stem = cal.frames[f]
        if stem not in truth.T_world_body:
            continue
        for b in np.unique(boards[frames == f]):
            name = cal.boards[b]
            T_world_board = truth.board_pose(stem, name)
            if T_world_board is None:
                continue
            m = (frames == f) & (boards == b)
            T = geo.inv_T(T_body_left) @ geo.inv_T(truth.T_world_body[stem]) @ T_world_board
            p = geo.transform(T, p_board[m])
            z[m] = (p @ rect.R1.T)[:, 2]
    return z


def sanity_10m(rig, left: str, right: str, rect) -> dict:
    """The textbook figure: a point 10 m straight ahead of the pair (along the rectified
    optical axis from the left camera) -> disparity and depth through the raw cameras."""
    T_body_left = rig.camera(left).T_body_cam
    p_rect = np.array([0.0, 0.0, 10.0])
    p_left = rect.R1.T @ p_rect
    p_body = geo.transform(T_body_left, p_left)
    uv = {}
    for side in (left, right):
        pr = rig.camera(side).project_body(p_body[None])
        if not pr.valid[0]:
            return {"distance_m": 10.0, "disparity_px": None, "depth_m": None}
        uv[side] = rectify_pixels(rect, rig.camera(side), pr.uv, "left" if side == left else "right")[0]
    d = float(uv[left][0] - uv[right][0])
    return {"distance_m": 10.0, "disparity_px": round(d, 4), "depth_m": round(rect.baseline_m * rect.f / d, 4)}


def stereo_checks(cal, dataset_truth: Path | None = None) -> dict:
    """depth_check per declared stereo pair -> {(left, right): {...}}."""
    truth = None
    if dataset_truth is not None and Path(dataset_truth).is_file():
        from rigcal.data.truth import load_truth

        try:
            truth = load_truth(dataset_truth)
        except RigcalError:  # a broken truth.yaml must not stop a calibration; calibrate never needs it
            truth = None
    out = {}
    for p in cal.rig.stereo_pairs:
        out[(p.left, p.right)] = depth_check(cal, p.left, p.right, truth)
    return out
