"""The magnetometer step of `rigcal calibrate`: every magnetometer of the rig calibrated
against its IMU from the dataset's mag/ and imu/ files, the calibrated rig blocks
(the magnetometer format's `calibration`) and the console table.

A magnetic disturbance is refused before the fit: the field magnitude the start calibration
gives, averaged over each second, must stay within what noise explains plus
DISTURBANCE_SHARE of the field.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from rich.table import Table
from threadpoolctl import threadpool_limits

from rigcal.core import geometry as geo
from rigcal.core.rig import Magnetometer, Rig
from rigcal.data.imu_csv import ImuSamples
from rigcal.data.mag_csv import MagSamples, check_mag_dataset
from rigcal.errors import CalibrationError
from rigcal.mag.ellipsoid import AXIS_NAMES, COVERAGE_DEG, check_coverage, fit_ellipsoid, missing_directions
from rigcal.mag.estimator import MagInput, MagResult, estimate

DISTURBANCE_SHARE = 0.03  # a 1 s mean field magnitude this far (plus 5 sigma of noise) from the median is refused
BIN_S = 1.0
DECLARED_AXES_WARN_DEG = 10.0  # the fit is this far from the declared mount: a declaration to check
OFFSET_SIGMAS = 6.0  # a second's mean residual beyond this many standard errors is a disturbance
ADVICE = "record again away from steel, cars, cables and magnets"


@dataclass(frozen=True)
class MagStep:
    """The rig with its magnetometers calibrated, each one's result, and notes for the console."""

    rig: Rig
    results: Mapping[str, MagResult]
    notes: tuple[str, ...]
    inputs: Mapping[str, MagInput] = field(default_factory=dict)  # what each estimate was given


def mag_input(rig: Rig, mag: Magnetometer, samples: MagSamples, imu: ImuSamples, R_body_imu: np.ndarray) -> MagInput:
    """The estimator's input: times in seconds from the IMU's first sample (IMU clock); the
    readings outside the IMU's span are left out."""
    t0 = int(imu.t_ns[0])
    off = round((mag.time_offset_s or 0.0) * 1e9)
    t_imu, t_mag = (imu.t_ns - t0) * 1e-9, (samples.t_ns + off - t0) * 1e-9
    keep = (t_mag >= t_imu[0]) & (t_mag < t_imu[-1])
    return MagInput(t_imu=t_imu, gyro=imu.gyro, accel=imu.accel,
                    t_mag=t_mag[keep], m=samples.m_uT[keep], R_body_imu=R_body_imu,
                    R_body_mag_declared=mag.T_body_mag[:3, :3], sigma_uT=mag.sample_sigma_uT,
                    earth_field_uT=mag.earth_field_uT, label=str(samples.path),
                    estimate_offset=mag.time_offset_s is not None)


def check_recording(inp: MagInput) -> None:
    """CalibrationError naming the directions a recording lacks (ellipsoid.check_coverage,
    with how far the IMU turned: motion_summary), else naming when the field magnitude leaves
    what noise explains."""
    try:
        fit = fit_ellipsoid(inp.m, inp.earth_field_uT, inp.label)
        check_coverage(inp.m, fit, inp.label)
    except CalibrationError as e:
        raise CalibrationError(f"{e}; {motion_summary(inp)}") from None
    mag = np.linalg.norm((inp.m - fit.hard_iron) @ fit.soft_iron.T, axis=1)
    gain = np.linalg.det(fit.soft_iron) ** (1.0 / 3.0)
    b = np.floor((inp.t_mag - inp.t_mag[0]) / BIN_S).astype(int)
    n = np.bincount(b)
    ok = n > 0
    mean = np.bincount(b, mag)[ok] / n[ok]
    ref = float(np.median(mag))
    limit = 5.0 * inp.sigma_uT * gain / np.sqrt(n[ok]) + DISTURBANCE_SHARE * ref
    bad = np.flatnonzero(np.abs(mean - ref) > limit)
    if len(bad):
        worst = mean[bad][np.argmax(np.abs(mean[bad] - ref))]
        raise CalibrationError(f"{inp.label}: magnetic disturbance at {_spans(np.flatnonzero(ok)[bad])} of the "
                               f"recording: the field magnitude reads up to {worst:.1f} uT there against {ref:.1f} uT "
                               f"elsewhere (beyond noise and {DISTURBANCE_SHARE:.0%}); " + ADVICE)


def motion_summary(inp: MagInput) -> str:
    """How much the recording turned, from the IMU alone (no magnetometer calibration needed):
    the gyroscope's total rotation, the largest tilt of the specific force from its median
    direction, and the IMU axes the vertical came within COVERAGE_DEG of (all six for a compass
    dance; one for a level flight)."""
    f = inp.accel / np.linalg.norm(inp.accel, axis=1, keepdims=True)
    med = np.median(f, axis=0)
    tilt = np.degrees(np.arccos(np.clip(f @ (med / np.linalg.norm(med)), -1.0, 1.0))).max()
    turned = np.degrees(np.sum(np.linalg.norm(inp.gyro[1:], axis=1) * np.diff(inp.t_imu)))
    missing = missing_directions(inp.accel, np.zeros(3), np.eye(3))
    seen = [a for a in AXIS_NAMES if a not in missing]
    return (f"the IMU turned {turned:.0f} deg in all and tilted at most {tilt:.0f} deg from its median attitude; "
            f"up (the accelerometer's specific force) came within {COVERAGE_DEG:g} deg of its {', '.join(seen) or 'no'} axis "
            f"({len(seen)} of 6 directions)")


def check_residuals(inp: MagInput, r: MagResult) -> None:
    """CalibrationError naming the seconds whose mean residual is a systematic offset: beyond
    OFFSET_SIGMAS standard errors of a mean of that second's readings (with the larger of the
    declared noise and the residual RMS). A disturbance that turns the field more than it
    changes its magnitude shows here; the fit spreads part of it over the whole recording, so
    the seconds named are those above half the worst one's offset."""
    b = np.floor((inp.t_mag - inp.t_mag[0]) / BIN_S).astype(int)
    n = np.bincount(b)
    ok = n > 0
    mean = np.stack([np.bincount(b, r.residuals_uT[:, i])[ok] / n[ok] for i in range(3)], axis=1)
    sigma = max(inp.sigma_uT, r.residual_rms_uT)
    stat = np.linalg.norm(mean, axis=1) / (sigma / np.sqrt(n[ok]))
    if stat.max() > OFFSET_SIGMAS:
        bad = np.flatnonzero(stat > max(OFFSET_SIGMAS, 0.5 * stat.max()))
        worst = float(np.linalg.norm(mean, axis=1).max())
        raise CalibrationError(f"{inp.label}: magnetic disturbance at {_spans(np.flatnonzero(ok)[bad])} of the "
                               f"recording: the readings there are offset by up to {worst:.2f} uT from the fit "
                               f"(noise {sigma:.2f} uT per reading averages to {sigma / np.sqrt(n[ok].mean()):.2f} "
                               f"uT over a second); " + ADVICE)


def _spans(bins: np.ndarray) -> str:
    """'8-11 s, 20-21 s' from sorted bin indices."""
    spans, lo, hi = [], bins[0], bins[0] + 1
    for s in bins[1:]:
        if s > hi:
            spans.append((lo, hi))
            lo = s
        hi = s + 1
    spans.append((lo, hi))
    return ", ".join(f"{a * BIN_S:.0f}-{b * BIN_S:.0f} s" for a, b in spans[:5]) + (" ..." if len(spans) > 5 else "")


def calibration_block(r: MagResult, mag: Magnetometer) -> dict[str, Any]:
    """The magnetometer format's `calibration` mapping of a result (time_offset_s when estimated: the
    rig declares one)."""
    fl = lambda v: [float(x) + 0.0 for x in v]  # noqa: E731
    offset = r.sigma_time_offset_s is not None
    sigma = {"hard_iron_uT": fl(r.sigma_hard_iron), "soft_iron": [fl(row) for row in r.sigma_soft_iron],
             "rotation_deg": fl(r.sigma_rotation_deg),
             "field_uT": 0.0 if mag.earth_field_uT is not None else float(r.sigma_field_uT),
             "inclination_deg": float(r.sigma_inclination_deg)}
    return {
        "hard_iron_uT": fl(r.hard_iron),
        "soft_iron": [fl(row) for row in r.soft_iron],
        "field_uT": float(r.field_uT),
        "inclination_deg": float(r.inclination_deg),
        **({"time_offset_s": float((mag.time_offset_s or 0.0) + r.time_offset_s)} if offset else {}),
        "residual_rms_uT": float(r.residual_rms_uT),
        "residual_rms_declared_uT": float(r.residual_rms_declared_uT),
        "sigma": {**sigma, **({"time_offset_s": float(r.sigma_time_offset_s)} if offset else {})},
        "heading_sigma_deg": float(r.heading_sigma_deg),
        "sigma_basis": r.sigma_basis,
    }


def calibrate_magnetometers(rig: Rig, dataset: str | Path, imus: Mapping[str, ImuSamples], refuse: bool = True,
                            samples: Mapping[str, MagSamples] | None = None) -> MagStep:
    """Every magnetometer of `rig` calibrated against its IMU (whose T_body_imu, declared or
    calibrated, `rig` holds) from DATASET/mag/ (or `samples`, check_mag_dataset's answer when
    the caller has it already); the rig unchanged when there is no mag/.
    A recording refused (poor coverage, a disturbance) raises CalibrationError, or with
    refuse=False leaves that magnetometer's block unchanged with a warning note."""
    samples = check_mag_dataset(dataset, rig, imus) if samples is None else samples
    if not samples:
        note = (f"the rig declares magnetometer(s) {', '.join(m.name for m in rig.magnetometers)} but the dataset "
                f"has no mag/ folder: their blocks are carried through unchanged",) if rig.magnetometers else ()
        return MagStep(rig, {}, note)
    results, mags, notes, inputs = {}, [], [], {}
    for mag in rig.magnetometers:
        imu = rig.mag_imu(mag)
        inp = mag_input(rig, mag, samples[mag.name], imus[imu.name], imu.T_body_imu[:3, :3])
        try:
            with threadpool_limits(1, user_api="blas"):  # small products: more BLAS threads only spin (estimator.estimate)
                check_recording(inp)
                r = estimate(inp)
                check_residuals(inp, r)
        except CalibrationError as e:
            if refuse:
                raise
            mags.append(mag)
            notes.append(f"warning: {mag.name}: not calibrated, carried through unchanged: {e}")
            continue
        results[mag.name] = r
        inputs[mag.name] = inp
        T = mag.T_body_mag.copy()
        T[:3, :3] = r.R_body_mag
        mags.append(replace(mag, T_body_mag=T, calibration=calibration_block(r, mag)))
        turn = geo.rotation_angle_deg(r.R_body_mag @ mag.T_body_mag[:3, :3].T)
        notes.append(f"{mag.name}: calibrated against {imu.name} from {len(inp.t_mag)} readings in {r.seconds:.1f} s; "
                     f"its axes are {turn:.2f} deg from the declared ones; 1-sigma {r.sigma_basis}")
        if turn > DECLARED_AXES_WARN_DEG:
            notes.append(f"warning: {mag.name}: the calibrated axes are {turn:.1f} deg from the declared ones "
                         f"(magnetometers.{mag.name}.axes / rotation); check how the chip is mounted")
        if r.residual_rms_uT > 1.5 * r.residual_rms_declared_uT:
            notes.append(f"{mag.name}: residual RMS {r.residual_rms_uT:.2f} uT is {r.residual_rms_uT / r.residual_rms_declared_uT:.1f}x "
                         f"what noise_density predicts ({r.residual_rms_declared_uT:.2f} uT): the declared noise is "
                         f"too low, or the field was disturbed")
    return MagStep(replace(rig, magnetometers=tuple(mags)), results, tuple(notes), MappingProxyType(inputs))


def console_table(step: MagStep) -> Table:
    """One row per magnetometer: hard iron, soft iron (largest departure from identity),
    rotation from the declared axes, field, inclination, residuals, heading 1-sigma."""
    t = Table(title="magnetometers (1-sigma in brackets)")
    for col in ("magnetometer", "hard iron uT", "soft iron max |A - I|", "R_body_mag sigma deg (F/L/U)",
                "field uT", "inclination deg", "residual RMS / declared uT", "heading 1-sigma deg"):
        t.add_column(col)
    for name, r in step.results.items():
        A = r.soft_iron
        t.add_row(name, " ".join(f"{x:+.2f}" for x in r.hard_iron) + f" ({r.sigma_hard_iron.max():.3f})",
                  f"{np.abs(A - np.eye(3)).max():.4f} ({r.sigma_soft_iron.max():.4f})",
                  "/".join(f"{x:.3f}" for x in r.sigma_rotation_deg),
                  f"{r.field_uT:.2f} ({r.sigma_field_uT:.3f})",
                  f"{r.inclination_deg:.2f} ({r.sigma_inclination_deg:.3f})",
                  f"{r.residual_rms_uT:.3f} / {r.residual_rms_declared_uT:.3f}", f"{r.heading_sigma_deg:.3f}")
    return t
