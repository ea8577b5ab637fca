"""`rigcal project`: one ENU point through the rig at one body pose (the textbook example)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from rigcal.core import geometry as geo
from rigcal.errors import InputError
from rigcal.core.rig import load_rig


def body_pose(position: Sequence[float], heading: float | None, axes: Sequence[str] | None) -> np.ndarray:
    if (heading is None) == (axes is None):
        raise InputError("project: give exactly one of --heading DEG or --axes X Y Z")
    if heading is not None:
        if not np.isfinite(heading):
            raise InputError(f"project: --heading: expected a finite number of degrees, got {heading}")
        return geo.T_nav_body_from_heading(position, heading)
    try:
        return geo.T_nav_body_from_axes(position, list(axes))
    except ValueError as e:
        raise InputError(f"project: --axes: {e} (axes are E, N, U with optional '-')") from None


def run(rig_path: Path, position, point, heading=None, axes=None) -> str:
    """The report `rigcal project` prints: the point in the body frame, then per camera its
    camera-frame coordinates and pixel (or why it has none), then per stereo pair the
    rectified disparity and depth Z = B f / d."""
    for name, v in (("--position", position), ("--point", point)):
        if not np.all(np.isfinite(v)):
            raise InputError(f"project: {name}: expected finite numbers, got {list(v)}")
    rig = load_rig(rig_path)
    T_nav_body = body_pose(position, heading, axes)
    p_nav = np.array([point], dtype=float)
    p_body = geo.transform(geo.inv_T(T_nav_body), p_nav)
    lines = [f"body frame (FLU): ({_f(p_body[0])})"]
    seen: dict[str, bool] = {}
    for cam in rig.cameras:
        if not cam.has_pose:
            lines.append(f"{cam.name}: no pose in the rig file (calibrate finds it); not projected")
            continue
        pr = cam.project_body(p_body)
        seen[cam.name] = bool(pr.in_image[0])
        why = pr.reason(0)
        pc = f"camera frame ({_f(pr.p_cam[0])})"
        if why is None:
            lines.append(f"{cam.name}: {pc}  pixel ({pr.uv[0, 0]:.2f}, {pr.uv[0, 1]:.2f})")
        else:
            lines.append(f"{cam.name}: not visible ({why}); {pc}")
    for pair in rig.stereo_pairs:
        lines.append(_pair_line(rig, pair, seen, p_nav, T_nav_body))
    return "\n".join(lines)


def _pair_line(rig, pair, seen: dict[str, bool], p_nav: np.ndarray, T_nav_body: np.ndarray) -> str:
    tag = f"stereo {pair.left}/{pair.right}"
    unposed = [n for n in (pair.left, pair.right) if n not in seen]
    if unposed:
        return f"{tag}: no disparity ({', '.join(unposed)} has no pose)"
    if not (seen[pair.left] and seen[pair.right]):
        return f"{tag}: not seen by both cameras; no disparity"
    sd = rig.stereo_depth(pair, p_nav, T_nav_body)
    if not np.isfinite(sd.depth[0]):
        return (f"{tag}: disparity {sd.disparity[0]:.4f} px gives no depth "
                f"(d <= 0: is the pair declared left, right?)")
    return (f"{tag}: disparity {sd.disparity[0]:.4f} px, depth {sd.depth[0]:.4g} m "
            f"(Z = B f / d with baseline {sd.baseline_m:.4f} m, f {sd.f:.2f} px)")


def _f(v) -> str:
    return ", ".join(f"{x:.4g}" for x in v)
