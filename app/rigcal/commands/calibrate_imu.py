"""The camera-IMU part of `rigcal calibrate`: every declared IMU with data calibrated against
the cameras (rigcal.imucal.step.calibrate_imu), the reference IMU's result written into the
calibrated rig (rigcal.results.imu_outputs), the others placed by the cameras."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.rig import Rig
from rigcal.imucal.step import ImuCalibration, Options, calibrate_imu
from rigcal.results.imu_outputs import calibrated_imu_rig, imu_block, rounded


def calibrate_with_imu(cal, out_rig: Rig, motion, reference: str, target, options: Options
                       ) -> tuple[ImuCalibration, Rig]:
    """calibrate.run's camera-IMU step after the camera-only calibration `cal` and its rig
    `out_rig`: (the estimate against `options.imu`, the calibrated rig with its IMU blocks).
    Every other declared IMU with data is calibrated against the cameras with the same
    options and placed by them (placed_imu)."""
    imu_name = options.imu
    declared = cal.declared if cal.declared is not None else cal.rig
    faces = {b.name: float(b.print_face) for b in target.boards}

    def against(name: str) -> ImuCalibration:
        return calibrate_imu(cal, motion.imus[name], declared.imu(name), replace(options, imu=name),
                             [faces[b] for b in cal.boards], {c.name: c.line_delay_s or 0.0 for c in declared.cameras},
                             {c.name: c.time_offset_s or 0.0 for c in declared.cameras},
                             image_t_ns=getattr(motion, "frame_t_ns", None))

    res = against(imu_name)
    rig = calibrated_imu_rig(out_rig, declared, res, reference)
    warnings, notes = list(res.warnings), list(res.notes)
    for other in [i.name for i in declared.imus if i.name != imu_name and i.name in motion.imus]:
        o = against(other)
        rig = placed_imu(rig, o, res)
        warnings += [f"{other}: {w}" for w in o.warnings]
        notes.append(f"{other}: calibrated against the cameras as {imu_name} was, and placed by them (its "
                     f"T_body_imu the best rigid fit of its T_imu_cam onto the calibrated T_body_cam); clock offset "
                     f"{1000 * rig.imu(other).calibration['clock_offset_s']:+.3f} ms from {imu_name}")
    return replace(res, warnings=tuple(warnings), notes=tuple(notes)), rig


def placed_imu(rig: Rig, other: ImuCalibration, ref: ImuCalibration) -> Rig:
    """`rig` (calibrated against `ref`'s IMU) with `other`'s IMU placed by the cameras: its
    T_body_imu is the rigid fit of its own T_imu_cam onto the calibrated T_body_cam, its
    calibration block as any IMU's (pose sigma from its best camera) plus `clock_offset_s`
    (t_other = t_reference_imu + clock_offset_s: the mean over cameras of the two
    estimates' time offsets' difference) with its 1-sigma (spec addition)."""
    T_body_cam = np.stack([c.T_body_cam for c in rig.cameras])
    T_body_imu = geo.fit_rigid_to(other.result.T_imu_cam, T_body_cam)
    block = imu_block(other, placed=True)
    d = other.result.time_offset_s - ref.result.time_offset_s
    block["clock_offset_s"] = rounded(float(np.mean(d)), 9)
    block["sigma"]["clock_offset_ms"] = rounded(1000 * float(np.min(np.hypot(other.sigma["offset"], ref.sigma["offset"]))), 5)
    imus = tuple(replace(i, T_body_imu=T_body_imu, calibration=block) if i.name == other.imu.name else i
                 for i in rig.imus)
    return replace(rig, imus=imus)
