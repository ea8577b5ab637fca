"""The output body frame and the cameras' pose covariance in it (the last stage of the pipeline).

The solver's body is its gauge camera; the user's is the declared rig's (--reference
aligned: the best rigid fit to every declared camera pose) or one camera's
(--reference camera:NAME). reference_transform maps one onto the other, and
extrinsic_covariance propagates the joint solve's covariance through that map, so each
camera's sigma is in the frame the user receives.
"""

from __future__ import annotations

import numpy as np

from rigcal.core import geometry as geo
from rigcal.errors import InputError
from rigcal.camcal.model_selection import intrinsic_sigmas
from rigcal.core.rig import Rig
from rigcal.camcal.solve import intrinsics_covariance


# ----------------------------------------------------------------------------- body frame


def check_reference(reference: str, rig: Rig) -> None:
    """InputError unless `reference` is 'aligned' or 'camera:NAME' with NAME in the rig."""
    if reference == "aligned":
        return
    if reference.startswith("camera:"):
        name = reference.split(":", 1)[1]
        if name not in rig.names:
            raise InputError(f"--reference: camera {name!r} is not in the rig ({', '.join(rig.names)})")
        return
    raise InputError(f"--reference: expected 'aligned' or 'camera:NAME', got {reference!r}")


def reference_transform(T_body_cam_solve: np.ndarray, rig: Rig, reference: str) -> np.ndarray:
    """T_out_solve: the rigid transform that places the solved rig in the output body frame.

    aligned: least-squares fit of all declared cameras' orientations and positions
    (rotation by the polar decomposition of sum R_decl R_solve^T + sum of centred
    position outer products; translation from the centroids). camera:NAME: that
    camera keeps its declared pose exactly. No declared pose at all: the first camera's
    frame is the body frame (docs/formats.md#rig-yaml)."""
    declared = {c.name: c.T_body_cam for c in rig.cameras if c.T_body_cam is not None}
    names = list(rig.names)
    if reference.startswith("camera:"):
        n = reference.split(":", 1)[1]
        T_decl = declared.get(n, np.eye(4))
        return T_decl @ geo.inv_T(T_body_cam_solve[names.index(n)])
    if not declared:
        return geo.inv_T(T_body_cam_solve[0])
    idx = [names.index(n) for n in declared]
    return geo.fit_rigid_to(T_body_cam_solve[idx], np.array([declared[names[i]] for i in idx]))


# ----------------------------------------------------------------------------- uncertainty


def _pose_error_vector(T_body_cam: np.ndarray, T_ref: np.ndarray) -> np.ndarray:
    """6-vector of a camera pose relative to a reference pose: rotation about body axes (rad), position (m)."""
    return np.concatenate([geo.rotvec_from_R(T_body_cam[:3, :3] @ T_ref[:3, :3].T), T_body_cam[:3, 3]])


def extrinsic_covariance(res, rig: Rig, reference: str, T_body_cam_solve: np.ndarray, covariance: tuple | None):
    """Covariance of every camera's output pose, propagated from the solver's gauge.

    The solver fixes one camera; the output frame is a function of all cameras (aligned)
    or of one (camera:NAME). Propagating the joint covariance through that function
    (numerically, over the extrinsic parameters only) gives each camera's sigma in the
    frame the user actually receives, so no camera gets a spurious zero. covariance:
    solve_covariance(res)."""
    if covariance is None:
        return None
    cov, intr_sl, cam_sl = covariance
    C = len(cam_sl)
    T_out = reference_transform(T_body_cam_solve, rig, reference)
    ref_poses = [T_out @ T for T in T_body_cam_solve]

    def outputs(T_cam_body: np.ndarray) -> np.ndarray:
        Tbc = np.array([geo.inv_T(T) for T in T_cam_body])
        To = reference_transform(Tbc, rig, reference)
        return np.concatenate([_pose_error_vector(To @ Tbc[c], ref_poses[c]) for c in range(C)])

    # parameters: delta (left perturbation of R_cam_body) and t_cam_body per non-gauge camera
    free = [c for c in range(C) if cam_sl[c] is not None]
    base_T = res.state.T_cam_body
    G = np.zeros((6 * C, 6 * len(free)))
    h = 1e-7
    for j, c in enumerate(free):
        for k in range(6):
            Tp, Tm = base_T.copy(), base_T.copy()
            d = np.zeros(6)
            d[k] = h
            for T, s in ((Tp, 1), (Tm, -1)):
                if k < 3:
                    T[c, :3, :3] = geo.R_from_rotvec(s * d[:3]) @ base_T[c, :3, :3]
                else:
                    T[c, :3, 3] = base_T[c, :3, 3] + s * d[3:]
            G[:, 6 * j + k] = (outputs(Tp) - outputs(Tm)) / (2 * h)
    idx = np.concatenate([np.arange(cam_sl[c].start, cam_sl[c].stop) for c in free]) if free else np.zeros(0, int)
    Ce = cov[np.ix_(idx, idx)] if len(idx) else np.zeros((0, 0))
    ext = G @ Ce @ G.T if len(idx) else np.zeros((6 * C, 6 * C))
    intr = [None if C is None else intrinsic_sigmas(C)
            for C in intrinsics_covariance(cov, intr_sl, res.state.intrinsics)]
    return {"extrinsics": ext, "intrinsics": intr}
