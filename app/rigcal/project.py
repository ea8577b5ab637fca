"""`rigcal project`: one ENU point through the rig at one body pose (the textbook example)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from . import geometry as geo
from .errors import InputError
from .rig import load_rig


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
    for name, v in (("--position", position), ("--point", point)):
        if not np.all(np.isfinite(v)):
            raise InputError(f"project: {name}: expected finite numbers, got {list(v)}")
    rig = load_rig(rig_path)
    T_nav_body = body_pose(position, heading, axes)
    p_nav = np.array([point], dtype=float)
    p_body = geo.transform(geo.inv_T(T_nav_body), p_nav)[0]
    lines = [f"body frame (FLU): ({_f(p_body)})"]
    seen = rig.project(p_nav, T_nav_body) if all(c.has_pose for c in rig.cameras) else None
    for cam in rig.cameras:
        if not cam.has_pose:
            lines.append(f"{cam.name}: no pose in the rig file")
            continue
        pr = cam.project_body(p_body[None])
        why = pr.reason(0)
        pc = f"camera frame ({_f(pr.p_cam[0])})"
        if why is None:
            lines.append(f"{cam.name}: {pc}  pixel ({pr.uv[0, 0]:.2f}, {pr.uv[0, 1]:.2f})")
        else:
            lines.append(f"{cam.name}: not visible ({why}); {pc}")
    del seen
    for pair in rig.stereo_pairs:
        l, r = rig.camera(pair.left), rig.camera(pair.right)
        if not (l.has_pose and r.has_pose):
            continue
        sd = rig.stereo_depth(pair, p_nav, T_nav_body)
        vis_l = l.project_body(p_body[None]).in_image[0]
        vis_r = r.project_body(p_body[None]).in_image[0]
        tag = f"stereo {pair.left}/{pair.right}"
        if not (vis_l and vis_r) or not np.isfinite(sd.depth[0]):
            lines.append(f"{tag}: not seen by both cameras; no disparity")
            continue
        from .stereo import rectify_pair

        rect = rectify_pair(l, r)
        lines.append(f"{tag}: disparity {sd.disparity[0]:.4f} px, depth {sd.depth[0]:.4g} m "
                     f"(Z = B f / d with baseline {rect.baseline_m:.4f} m, f {rect.f:.2f} px)")
    return "\n".join(lines)


def _f(v) -> str:
    return ", ".join(f"{x:.4g}" for x in v)
