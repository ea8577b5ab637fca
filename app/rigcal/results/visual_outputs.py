"""What `rigcal calibrate` writes for free-running cameras without an IMU
(rigcal.imucal.visual_motion): the camera-only calibrated rig with every T_body_cam, clock
offset (`time_offset_s`, t_ref = t_cam + time_offset_s on the reference camera's clock) and,
when estimated, the intrinsics from the continuous-time estimate, their 1-sigma under each
camera's `calibration.sigma` (as the camera-IMU output: `rotation_deg`, `position_mm`,
`time_offset_ms`, `intrinsics`; `sigma_source` formal or subsets: checked on the
recording's halves as the camera-IMU step's), the stereo baselines from the new poses and a top-level
`calibration.free_running` block saying how."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rigcal.camcal.body_frame import reference_transform
from rigcal.camcal.model_selection import intrinsics_model
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
            if "intrinsics_model" in block:  # the estimate's structure (it frees what the start tied or held)
                block["intrinsics_model"] = intrinsics_model(vm.state.intrinsics[k],
                                                             block["intrinsics_model"]["distortion"], fixed=False)
        block["sigma"] = sig
        block["sigma_source"] = sigma_source(vm, k)
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
        # each spacing tried (coarsest first) with the corner RMS (px) of its first pass
        "knot_spacing_tried": [[_r(dt, 6), _r(rms, 4)] for dt, rms in vm.knots_tried],
        "smoothness_prior": {"acceleration_m_s2": _r(vm.prior_sigma[0], 4),
                             "angular_acceleration_rad_s2": _r(vm.prior_sigma[1], 4)},
        "intrinsics": "estimated" if vm.intrinsics else "held",
        "corner_rms_px": _r(vm.corner_rms_px, 4),
        "iterations": int(vm.iterations),
        "seconds": _r(vm.seconds, 2),
    }
    return replace(out_rig, cameras=tuple(cams), stereo_pairs=pairs, calibration=top)


def sigma_source(vm: VisualMotionResult, k: int) -> str:
    """Camera k's `sigma_source`, as the camera-IMU output's: `subsets` where the recording's
    halves raised any of its sigmas, else `formal` (not compared, or the formal ones cover them)."""
    check = vm.subsets
    return check.source(k) if check is not None and check.compared[k] else "formal"


def subsets_note(names: list[str], vm: VisualMotionResult) -> str:
    """calibrate's note on the halves' check of the sigmas (or that it could not be made)."""
    if vm.subsets is None:
        return ("free-running cameras without an IMU: the sigmas are the formal ones (the recording's halves could "
                "not each be estimated)")
    return "free-running cameras without an IMU: " + vm.subsets.line(names)


def summary_note(names: list[str], vm: VisualMotionResult) -> str:
    """calibrate's note on the estimate: the clock, the knots and each offset."""
    offs = ", ".join(f"{n} {1000 * vm.time_offset_s[k]:+.3f} +- {1000 * vm.sigma[k, 6]:.3f} ms"
                     for k, n in enumerate(names) if k != vm.reference)
    return (f"free-running cameras without an IMU: the rig's motion is a spline with knots every "
            f"{1000 * vm.knot_dt:.0f} ms shaped by the views alone (and a smoothness prior), every image at its own "
            f"time; poses, clock offsets and their sigmas are this estimate's, clocks relative to "
            f"{names[vm.reference]}: {offs}; corner RMS {vm.corner_rms_px:.3f} px")


def pose_warnings(names: list[str], vm: VisualMotionResult) -> list[str]:
    """outputs.warnings_for's poorly-constrained-pose warnings on this estimate's sigmas (the
    camera-only start's describe images grouped across instants, not the written poses)."""
    from rigcal.results.outputs import AXES, MOTION_HINT, SIGMA_WARN_DEG, SIGMA_WARN_MM

    out = []
    for k, n in enumerate(names):
        for i, s in enumerate(1000 * vm.sigma[k, 3:6]):
            if s > SIGMA_WARN_MM:
                out.append(f"{n}: position along body {AXES[i]} is poorly constrained (1-sigma {s:.2f} mm > "
                           f"{SIGMA_WARN_MM} mm); {MOTION_HINT[AXES[i]]}")
        for i, s in enumerate(np.degrees(vm.sigma[k, :3])):
            if s > SIGMA_WARN_DEG:
                out.append(f"{n}: rotation about body {AXES[i]} is poorly constrained (1-sigma {s:.3f} deg > "
                           f"{SIGMA_WARN_DEG} deg); rotate the rig about more than one axis and tilt the board")
    return out


def is_start_pose_warning(line: str) -> bool:
    """A warnings_for line about a camera-only pose sigma (replaced by pose_warnings)."""
    return "is poorly constrained (1-sigma" in line and (" position along body " in line
                                                         or " rotation about body " in line)


def console_table(rig: Rig, vm: VisualMotionResult, names: list[str]):
    """The written poses' sigmas and clock offsets (the cameras table above is the start's)."""
    from rich.table import Table

    ref = names[vm.reference]
    t = Table(title=f"free-running cameras without an IMU: relative to {ref} (clocks: t_{ref} = t_cam + offset)")
    for col in ("camera", "time offset ms", "1-sigma ms", "sigma pos mm (F L U)", "sigma rot deg (F L U)",
                "sigmas from"):
        t.add_column(col, justify="left" if col == "camera" else "right")
    for c in rig.cameras:
        k = names.index(c.name)
        s = vm.sigma[k]
        t.add_row(c.name + (" (reference)" if k == vm.reference else ""), f"{1000 * vm.time_offset_s[k]:+.4f}",
                  f"{1000 * s[6]:.4f}", " ".join(f"{1000 * x:.3f}" for x in s[3:6]),
                  " ".join(f"{np.degrees(x):.4f}" for x in s[:3]), "held" if k == vm.reference else sigma_source(vm, k))
    t.caption = (f"knots every {1000 * vm.knot_dt:.0f} ms, corner RMS {vm.corner_rms_px:.3f} px; the cameras table "
                 f"above describes the camera-only start (images grouped by time)")
    return t
