"""What `rigcal calibrate` writes for free-running cameras without an IMU
(rigcal.imucal.visual_motion): the camera-only calibrated rig with every T_body_cam, clock
offset (`time_offset_s`, t_ref = t_cam + time_offset_s on the reference camera's clock) and,
when estimated, the intrinsics from the continuous-time estimate, their 1-sigma under each
camera's `calibration.sigma` (as the camera-IMU output: `rotation_deg`, `position_mm`,
`time_offset_ms`, `intrinsics`), the stereo baselines from the new poses and a top-level
`calibration.free_running` block saying how."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rigcal.camcal.body_frame import reference_transform
from rigcal.core.rig import Rig
from rigcal.imucal.visual_motion import VisualMotionResult


def _r(x: float, nd: int) -> float:
    return float(np.round(float(x), nd))


def visual_motion_rig(out_rig: Rig, cal, vm: VisualMotionResult) -> Rig:
    """The calibrated rig of `cal` (the camera-only start) with the continuous-time
    estimate `vm`, in the body frame of the rig's reference convention (the camera-only
    step's `aligned` or `camera:NAME`, reference_transform on the new poses)."""
    names = list(cal.cam_names)
    declared = cal.declared if cal.declared is not None else cal.rig
    X = reference_transform(vm.T_body_cam, declared, cal.reference)
    T_body_cam = X[None] @ vm.T_body_cam
    cams = []
    for c in out_rig.cameras:
        k = names.index(c.name)
        block = dict(c.calibration or {})
        sig = dict(block.get("sigma", {}))
        s = vm.sigma[k]
        sig["rotation_deg"] = [_r(np.degrees(x), 5) for x in s[:3]]
        sig["position_mm"] = [_r(1000 * x, 4) for x in s[3:6]]
        sig["time_offset_ms"] = _r(1000 * s[6], 5)
        lens = c.intrinsics
        if vm.intrinsics:
            lens = c.intrinsics.with_values(vm.intrinsics[k].values)
            sig["intrinsics"] = {key: _r(x, 4) for key, x in zip(("fx", "fy", "cx", "cy"), vm.sigma_intrinsics[k])}
        block["sigma"] = sig
        block["sigma_source"] = "formal"
        cams.append(replace(c, T_body_cam=T_body_cam[k], time_offset_s=float(vm.time_offset_s[k]), intrinsics=lens,
                            calibration=block))
    by_name = {c.name: c for c in cams}
    pairs = tuple(replace(p, baseline_m=_r(np.linalg.norm(by_name[p.left].T_body_cam[:3, 3]
                                                         - by_name[p.right].T_body_cam[:3, 3]), 7))
                  if p.baseline_m is not None else p for p in out_rig.stereo_pairs)
    top = dict(out_rig.calibration or {})
    top["reprojection_rms_px"] = _r(vm.corner_rms_px, 4)
    top["free_running"] = {
        "model": "continuous-time trajectory from the views alone (no IMU)",
        "clock": f"camera:{names[vm.reference]}",
        "knot_spacing_s": _r(vm.knot_dt, 6),
        "smoothness_prior": {"acceleration_m_s2": _r(vm.prior_sigma[0], 4),
                             "angular_acceleration_rad_s2": _r(vm.prior_sigma[1], 4)},
        "intrinsics": "estimated" if vm.intrinsics else "held",
        "corner_rms_px": _r(vm.corner_rms_px, 4),
        "iterations": int(vm.iterations),
        "seconds": _r(vm.seconds, 2),
    }
    return replace(out_rig, cameras=tuple(cams), stereo_pairs=pairs, calibration=top)


def summary_note(names: list[str], vm: VisualMotionResult) -> str:
    """calibrate's note on the estimate: the clock, the knots and each offset."""
    offs = ", ".join(f"{n} {1000 * vm.time_offset_s[k]:+.3f} +- {1000 * vm.sigma[k, 6]:.3f} ms"
                     for k, n in enumerate(names) if k != vm.reference)
    return (f"free-running cameras without an IMU: the rig's motion is a spline with knots every "
            f"{1000 * vm.knot_dt:.0f} ms shaped by the views alone (and a smoothness prior), every image at its own "
            f"time; poses, clock offsets and their sigmas are this estimate's, clocks relative to "
            f"{names[vm.reference]}: {offs}; corner RMS {vm.corner_rms_px:.3f} px")
