"""The statistics of `rigcal check`: chi-square tests of a camera's pose and intrinsics
against the rig, the family-wise level, the smallest detectable change, and which camera
moved when the rig's relative poses carry a gauge.

Pose changes are 6-vectors [rotation about body F, L, U (rad), position change along body
F, L, U (m)]: delta = [rotvec(R_new R_old^T), t_new - t_old] of T_body_cam, the new pose
placed in the rig's body frame by the other cameras (`aligned_delta`). Pure functions over
numpy arrays; no files, no solver.
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np
from scipy import stats

from rigcal.core import geometry as geo

# power at which the smallest detectable change is quoted: a change this large is flagged
# in 80 % of recordings like this one (the usual "minimal detectable bias")
DETECT_POWER = 0.8


def sidak_level(level: float, n_tests: int) -> float:
    """The per-test level whose n_tests independent tests make a family-wise false alarm
    rate of `level`: 1 - (1 - level)^(1/n) (Sidak; at most Bonferroni's level / n)."""
    return 1.0 - (1.0 - level) ** (1.0 / max(n_tests, 1))


def chi2_threshold(dof: int, level: float) -> float:
    """The statistic beyond which a chi-square(dof) variable lies with probability `level`."""
    return float(stats.chi2.isf(level, dof))


def chi2_test(delta: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """(statistic delta^T cov^-1 delta, p-value) of a k-vector change with covariance (k, k).
    A pseudo-inverse: a direction with no variance at all (a parameter held by both
    calibrations) carries no information and drops out of the statistic and the dof."""
    cov = 0.5 * (cov + cov.T)
    dof = int(np.linalg.matrix_rank(cov, tol=1e-12 * max(float(np.trace(cov)), 1e-300)))
    if dof == 0:
        return 0.0, 1.0
    stat = float(delta @ np.linalg.pinv(cov, rcond=1e-12, hermitian=True) @ delta)
    return stat, float(stats.chi2.sf(stat, dof))


@functools.lru_cache(maxsize=64)
def noncentrality(dof: int, level: float, power: float = DETECT_POWER) -> float:
    """lambda with P(chi2(dof, lambda) > threshold(dof, level)) = power."""
    crit = chi2_threshold(dof, level)
    lo, hi = 0.0, 1.0
    while stats.ncx2.sf(crit, dof, hi) < power:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stats.ncx2.sf(crit, dof, mid) < power else (lo, mid)
    return 0.5 * (lo + hi)


def detectable(cov: np.ndarray, level: float, power: float = DETECT_POWER) -> np.ndarray:
    """(k,) the smallest change of each component alone (the others zero) that the
    chi-square test of this covariance flags with probability `power` at `level`:
    sqrt(lambda / (cov^-1)_aa)."""
    cov = 0.5 * (cov + cov.T)
    k = cov.shape[0]
    info = np.linalg.pinv(cov, rcond=1e-12, hermitian=True)
    lam = noncentrality(k, level, power)
    d = np.diag(info)
    with np.errstate(divide="ignore"):
        return np.where(d > 0, np.sqrt(lam / np.where(d > 0, d, 1.0)), np.inf)


# ----------------------------------------------------------------------------- poses


def pose_change(T_body_cam: np.ndarray, T_ref: np.ndarray) -> np.ndarray:
    """6-vector [rotvec(R R_ref^T) about body axes (rad), t - t_ref (m)] of a pose (4, 4) from a reference."""
    return np.concatenate([geo.rotvec_from_R(T_body_cam[:3, :3] @ T_ref[:3, :3].T),
                           T_body_cam[:3, 3] - T_ref[:3, 3]])


def aligned_delta(T_new: np.ndarray, T_old: np.ndarray, i: int, others: list[int]) -> np.ndarray:
    """Camera i's pose change (6,) with the new rig placed onto the old one by the cameras
    `others` alone (the rigid fit of geometry.fit_rigid_to; one camera: its pose exactly).
    T_new, T_old: (C, 4, 4) T_body_cam, the new ones in any body frame of their own.
    Relative poses only: the answer does not depend on either rig's body frame."""
    T_align = geo.fit_rigid_to(T_new[others], T_old[others])
    return pose_change(T_align @ T_new[i], T_old[i])


def perturbed(T: np.ndarray, c: int, k: int, h: float) -> np.ndarray:
    """Poses (C, 4, 4) with camera c's pose moved by h along parameter k: k < 3 a rotation
    about body axis k (left), k >= 3 a position change along body axis k - 3."""
    out = T.copy()
    if k < 3:
        d = np.zeros(3)
        d[k] = h
        out[c, :3, :3] = geo.R_from_rotvec(d) @ T[c, :3, :3]
    else:
        out[c, k - 3, 3] += h
    return out


def numeric_jacobian(f: Callable[[np.ndarray], np.ndarray], T: np.ndarray, cams: list[int],
                     h: float = 1e-7) -> np.ndarray:
    """(m, 6 len(cams)) derivative of f(poses) by central differences over each listed
    camera's 6 pose parameters (perturbed)."""
    cols = []
    for c in cams:
        for k in range(6):
            cols.append((f(perturbed(T, c, k, h)) - f(perturbed(T, c, k, -h))) / (2 * h))
    return np.array(cols).T if cols else np.zeros((len(f(T)), 0))


def inverse_poses(T: np.ndarray) -> np.ndarray:
    """(C, 4, 4) the inverse of each pose."""
    return np.array([geo.inv_T(x) for x in T])


def delta_covariance(T_cam_body_new: np.ndarray, cov_new: np.ndarray, T_old: np.ndarray, var_old: np.ndarray,
                     i: int, others: list[int]) -> np.ndarray:
    """(6, 6) covariance of aligned_delta(inverse_poses(T_cam_body_new), T_old, i, others).

    cov_new: (6C, 6C) covariance of the new solve's camera poses in its own parameters
    (perturbed() applied to T_cam_body, solve.RigParameters; the gauge camera's rows zero);
    var_old: (C, 6) the rig's variances of its poses (its 1-sigmas squared, perturbed()
    applied to T_body_cam, treated as independent: the rig file keeps no correlations)."""
    C = len(T_cam_body_new)
    cams = [i] + list(others)
    T_new = inverse_poses(T_cam_body_new)
    J_new = numeric_jacobian(lambda T: aligned_delta(inverse_poses(T), T_old, i, others), T_cam_body_new,
                             list(range(C)))
    J_old = numeric_jacobian(lambda T: aligned_delta(T_new, T, i, others), T_old, cams)
    v_old = np.concatenate([var_old[c] for c in cams])
    return J_new @ cov_new @ J_new.T + (J_old * v_old) @ J_old.T


def gauge_free_variances(T: np.ndarray, var: np.ndarray) -> np.ndarray:
    """(C, 6) per camera pose variances [rotation about, position along body F, L, U] of
    independent errors e0 whose projection through a rigid re-fit of the whole rig onto its
    poses (geometry.fit_rigid_to, the `aligned` body frame: e = e0 - the fit's motion of each
    camera) has the variances `var` (C, 6).

    A rig calibrated with `--reference aligned` reports each camera's sigma in a body frame
    fitted to every camera, so the reported errors are negatively correlated: their sum is
    held near zero. Relative poses do not depend on the body frame, so their variance is that
    of e0, which the reported sigmas understate (three like cameras: by sqrt(1.5) in
    position). Solved linearly: diag(M diag(d) M^T) = var with M the fit's Jacobian, each
    d at least the reported variance (the fit only removes variance; bounded least squares,
    for reported sigmas that no independent errors explain exactly)."""
    from scipy.optimize import lsq_linear

    C = len(T)
    if C < 2:
        return var

    def refit(Tp: np.ndarray) -> np.ndarray:
        A = geo.fit_rigid_to(Tp, T)
        return np.concatenate([pose_change(A @ Tp[c], T[c]) for c in range(C)])

    M = numeric_jacobian(refit, T, list(range(C)), h=1e-6)
    scale = np.where(var.ravel() > 0, var.ravel(), 1.0)  # each equation in units of its own variance
    v = var.ravel()
    fit = lsq_linear((M ** 2) / scale[:, None], v / scale, bounds=(v, np.full(v.shape, np.inf)))
    return np.maximum(fit.x, v).reshape(C, 6)


def locate_moved(stat_of: Callable[[int, list[int]], float], cams: list[int], threshold: float
                 ) -> tuple[list[int], dict[int, list[int]]]:
    """Which cameras moved, when only relative poses can be tested.

    stat_of(i, others): camera i's test statistic with the rig aligned by `others`.
    Start with every camera in the aligning set; test each against the rest of the set
    (leave one out). While some camera fails, drop the worst from the set and test again;
    a camera outside the set is tested against the whole set. A moved camera biases the
    alignment of the others only through the set, so it is dropped first and the others
    then pass. Two cameras that disagree with each other cannot be told apart: both are
    dropped. Returns (the cameras that stay in the aligning set, per camera the set it
    was finally tested against)."""
    keep = list(cams)
    while True:
        against = {i: [j for j in keep if j != i] for i in cams}
        failing = {i: stat_of(i, against[i]) for i in keep if against[i]}
        failing = {i: s for i, s in failing.items() if s > threshold}
        if not failing:
            return keep, against
        if len(keep) <= 2:
            return [], against
        keep.remove(max(failing, key=failing.get))
