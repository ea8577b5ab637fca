"""The new recording's own estimate of the rig, started from the rig under test.

estimate_rig: the camera pipeline's first stages (camcal.pipeline: usable_views,
start_cameras, resolve_flips and start_rig with the rig's intrinsics, which place every
frame and board from the new views alone), then its first_solve started from the rig's
intrinsics and estimating them as the rig's calibration did (its `intrinsics_model`: fx = fy
tied or not, principal point free or held) with every pose, and the covariance of all of
them (frames marginalised, solve.camera_covariance).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from rigcal.camcal.initialise import resolve_flips
from rigcal.camcal.pipeline import MIN_FRAMES, Setup, first_solve, start_cameras, start_rig, usable_views
from rigcal.camcal.solve import Intrinsics, Observations, State, camera_covariance, intrinsics_covariance
from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel
from rigcal.core.observations import BoardView
from rigcal.core.rig import Rig
from rigcal.errors import CalibrationError


@dataclass(frozen=True)
class NewEstimate:
    """estimate_rig's answer for the cameras it could estimate (`names`, the rig's order):
    the solve's state (T_cam_body in its own body frame, frames, boards, intrinsics), its
    inlier observations, per camera the (n, n) covariance of [fx, fy, cx, cy, dist...]
    (held values zero), the (6C, 6C) covariance of the camera poses in the solve's
    parameters (decide.delta_covariance), the residual sigma px, and seconds."""

    names: tuple[str, ...]
    state: State
    obs: Observations
    cov_intrinsics: list[np.ndarray]
    cov_poses: np.ndarray
    sigma_px: float
    seconds: float

    @property
    def T_body_cam(self) -> np.ndarray:
        """(C, 4, 4) the cameras' poses in the solve's body frame."""
        return np.array([geo.inv_T(T) for T in self.state.T_cam_body])

    def model(self, c: int, old: CameraModel) -> CameraModel:
        """Camera c's estimated intrinsics as a CameraModel (old: the rig's, for size and model)."""
        return old.with_values(self.state.intrinsics[c].values)


def frames_seen(views: list[BoardView], name: str) -> int:
    """How many frames show camera `name` a board."""
    return len({v.frame for v in views if v.camera == name})


def determined(views: list[BoardView], rig: Rig) -> tuple[list[str], dict[str, str]]:
    """(the cameras with views in at least MIN_FRAMES frames, per other camera what is missing)."""
    ok, missing = [], {}
    for n in rig.names:
        k = frames_seen(views, n)
        if k >= MIN_FRAMES:
            ok.append(n)
        else:
            missing[n] = (f"a board in {k} frame(s) of this recording; at least {MIN_FRAMES} are needed to "
                          f"estimate this camera again (record the board in view of it, tilted, in more frames)")
    return ok, missing


def structure(cam_calibration: dict | None) -> tuple[bool, bool, bool]:
    """(tie_focal, hold_centre, held) of one camera as its calibration estimated it
    (calibration.intrinsics_model; absent: fx, fy, cx, cy all estimated)."""
    model = (cam_calibration or {}).get("intrinsics_model") or {}
    if model.get("focal") == "declared":
        return False, True, True
    return model.get("focal") == "fx=fy", model.get("principal_point") == "held", False


def estimate_rig(views: list[BoardView], rig: Rig, corners: dict[str, np.ndarray],
                 faces: dict[str, float] | None = None) -> NewEstimate:
    """The rig (its cameras with enough views: `determined`) estimated from these views alone.
    CalibrationError when the views cannot place the cameras (pipeline's messages)."""
    t0 = time.perf_counter()
    names = tuple(rig.names)
    used = [v for v in views if v.camera in names]
    # the pipeline's first stages with the rig's intrinsics held: every frame and board placed
    setup = Setup(rig, corners, sorted({v.frame for v in used}), fix_intrinsics=True, faces=faces,
                  misfit_notes=False)
    starts = start_cameras(usable_views(used, list(names), True).by_cam, setup)
    flipped = resolve_flips(starts.posed, len(names), [corners[b] for b in setup.board_names])
    start, fix = [], np.zeros(len(names), bool)
    for c, n in enumerate(names):
        tie, hold, held = structure(rig.camera(n).calibration)
        m = rig.camera(n).intrinsics
        start.append(Intrinsics(m.model, np.array([m.fx, m.fy, m.cx, m.cy, *m.dist], float), tie_focal=tie,
                                hold_centre=hold))
        fix[c] = held
    first = first_solve(flipped.posed, start_rig(flipped.posed, setup), starts.inits, setup, start=start, fix=fix)
    res = first.res
    lost = [n for c, n in enumerate(names) if not np.any(first.obs.cam[res.inliers] == c)]
    if lost:
        raise CalibrationError(f"{', '.join(lost)}: every corner of the new recording was rejected as an outlier")
    try:
        cov, intr_sl, cam_sl = camera_covariance(res)
    except np.linalg.LinAlgError:
        raise CalibrationError("the new recording does not determine the rig (singular covariance); record the "
                               "boards from more directions") from None
    C = len(names)
    cov_poses = np.zeros((6 * C, 6 * C))
    rows = [(6 * c + k, s.start + k) for c, s in enumerate(cam_sl) if s is not None for k in range(6)]
    if rows:
        dst, src = (np.array(x) for x in zip(*rows))
        cov_poses[np.ix_(dst, dst)] = cov[np.ix_(src, src)]
    cov_intr = [np.zeros((len(it.values),) * 2) if C_ is None else C_
                for C_, it in zip(intrinsics_covariance(cov, intr_sl, res.state.intrinsics), res.state.intrinsics)]
    return NewEstimate(names=names, state=res.state, obs=first.obs.subset(res.inliers), cov_intrinsics=cov_intr,
                       cov_poses=cov_poses, sigma_px=res.sigma_px, seconds=time.perf_counter() - t0)


def residuals_under(est: NewEstimate, T_old_new: np.ndarray, T_body_cam_old: np.ndarray,
                    models_old: list[CameraModel]) -> np.ndarray:
    """(M, 2) px: each inlier corner of the new views minus where the rig under test puts it,
    the frames and boards as the new estimate placed them, carried into the rig's body frame
    by T_old_new (new body -> rig body). Where it no longer fits."""
    o, st = est.obs, est.state
    p_world = np.einsum("nij,nj->ni", st.T_world_board[o.board, :3, :3], o.p_board) + st.T_world_board[o.board, :3, 3]
    T_old_world = T_old_new @ st.T_body_world  # (F, 4, 4)
    p_body = np.einsum("nij,nj->ni", T_old_world[o.frame, :3, :3], p_world) + T_old_world[o.frame, :3, 3]
    out = np.full((len(o), 2), np.nan)
    for c, m in enumerate(models_old):
        sel = o.cam == c
        p_cam = geo.transform(geo.inv_T(T_body_cam_old[c]), p_body[sel])
        uv, _ = m.project(p_cam)
        out[sel] = o.uv[sel] - uv
    return out


def with_subset(rig: Rig, names: list[str]) -> Rig:
    """The rig with only these cameras (stereo pairs among them kept)."""
    keep = set(names)
    return replace(rig.with_cameras([c for c in rig.cameras if c.name in keep]),
                   stereo_pairs=tuple(p for p in rig.stereo_pairs if p.left in keep and p.right in keep))
