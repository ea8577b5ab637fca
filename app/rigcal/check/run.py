"""`rigcal check RIG DATASET`: is the rig's calibration still good, and which camera moved?

Reads the calibrated rig and the recording (inputs), estimates the rig again from the new
views alone (estimate), tests every camera (verdict), and hands back the table or JSON,
the report and the updated rig (outputs, report), written whole or not at all.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rigcal.check import inputs
from rigcal.check.imu import reference_imu, try_estimate
from rigcal.check.estimate import determined, estimate_rig, residuals_under, structure, with_subset
from rigcal.check.outputs import CheckResult, console_table, to_json, updated_rig
from rigcal.check.verdict import verdicts
from rigcal.core import geometry as geo
from rigcal.core.io import atomic_write_texts
from rigcal.core.rig import dump_rig
from rigcal.errors import CalibrationError, InputError, OutputError


def run(rig_path: Path, dataset: Path, report_path: Path | None = None, level: float = 0.01, as_json: bool = False,
        update_path: Path | None = None, jobs: int | None = None):
    """The check; returns (what to print on stdout: a rich renderable or the JSON text, exit code)."""
    t0 = time.perf_counter()
    rig_path, dataset = Path(rig_path), Path(dataset)
    if not (0.0 < level < 0.5):
        raise InputError(f"--level: expected a false-alarm rate between 0 and 0.5, got {level}")
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs: expected a positive number of processes, got {jobs}")
    inputs.check_output(report_path, "--report")
    inputs.check_output(update_path, "--update")
    if report_path and update_path and Path(report_path).resolve() == Path(update_path).resolve():
        raise OutputError(f"{report_path}: --report and --update name the same file; give each its own path")
    rig = inputs.load_calibrated_rig(rig_path)
    rec = inputs.read_recording(dataset, rig, rig_path, jobs)
    t_det = time.perf_counter()
    names, missing = determined(rec.views, rig.with_cameras([rig.camera(n) for n in rec.cameras]))
    for n in rig.names:
        if n not in rec.cameras:
            missing[n] = "not in this recording (no images/ folder or corners/ file)"
    est, names, solo = _estimate(rec, rig, names, missing)
    t_est = time.perf_counter()
    imu_est, imu_notes = _imu_estimate(rig, dataset, rec, names)
    t_imu = time.perf_counter()
    vs, n_tests, level_each, keep = verdicts(rig, est, {n: structure(rig.camera(n).calibration) for n in rig.names},
                                             missing, level, solo, imu_est)
    timings = {"detection_s": rec.detection_s, "estimate_s": t_est - t_det, "total_s": time.perf_counter() - t0}
    if imu_est is not None:
        timings["camera_imu_s"] = t_imu - t_est
    res = CheckResult(rig_path=str(rig_path), dataset=str(dataset), verdicts=vs, level=level, n_tests=n_tests,
                      level_each=level_each, aligned_by=tuple(names[i] for i in keep) if est else (),
                      timings=timings, notes=tuple(imu_notes))
    writes = []
    if update_path is not None and est is not None:
        new_rig, actions = updated_rig(rig, est, res, str(dataset), imu_est)
        res = replace(res, updated=actions)
        writes.append((update_path, dump_rig(new_rig)))
    if report_path is not None:
        from rigcal.check.report import build_report

        writes.append((report_path, build_report(res, rig, est, old_residuals(rig, est, keep))))
    if writes:
        atomic_write_texts(writes)
    timings["total_s"] = time.perf_counter() - t0
    text = json.dumps(to_json(res), indent=1) if as_json else console_table(res)
    return text, res.exit_code


def old_residuals(rig, est, keep: list[int]) -> np.ndarray | None:
    """(M, 2) px the new views' corners under the rig's calibration (estimate.residuals_under),
    the new rig placed on the old by the cameras `keep` (all when none stayed); None without an estimate."""
    if est is None:
        return None
    names = list(est.names)
    T_old = np.array([rig.camera(n).T_body_cam for n in names])
    use = keep or list(range(len(names)))
    T_old_new = geo.fit_rigid_to(est.T_body_cam[use], T_old[use])
    return residuals_under(est, T_old_new, T_old, [rig.camera(n).intrinsics for n in names])


def _imu_estimate(rig, dataset: Path, rec, names: list[str]):
    """(the camera-IMU estimate of the cameras `names` or None, notes): made when the recording
    has imu/ and the rig is a camera-IMU calibration (imu.reference_imu); a recording that
    cannot determine it leaves the IMU part out, with a note saying why."""
    if not (dataset / "imu").is_dir() or not rig.imus:
        return None, []
    imu_name = reference_imu(rig)
    if imu_name is None:
        return None, ["the recording has imu/ but the rig is not a camera-IMU calibration (its cameras carry no "
                      "time_offset_s with calibration.sigma.time_offset_ms): the cameras are checked against each "
                      "other only; calibrate the rig on a recording with imu/ to check them against the IMU"]
    est, why = try_estimate(dataset, rig, imu_name, rec.views, names, rec.corners, rec.faces)
    if est is None:
        return None, [f"the camera-IMU calibration could not be estimated from this recording ({why}): the cameras "
                      f"are checked against each other only (with clock offsets between them, their relative poses "
                      f"carry the motion between their instants)"]
    return est, [f"cameras checked against {imu_name} (pose relative to the IMU and clock offset, the intrinsics held "
                 f"at the rig's in the camera-IMU estimate), not against each other: the camera-only estimate takes "
                 f"images with equal stems as one instant, which the cameras' clock offsets bias on a moving rig"]


def _estimate(rec, rig, names: list[str], missing: dict[str, str]):
    """(estimate_rig of these cameras or None, the cameras estimated together, per camera
    left out its estimate alone). A camera the new views cannot connect to the others (the
    pipeline names it in its CalibrationError) is left out (`missing` says why), the rest
    estimated without it, and it alone (its intrinsics can still be tested)."""
    if not names:
        return None, names, {}
    try:
        return estimate_rig(rec.views, with_subset(rig, names), rec.corners, rec.faces), names, {}
    except CalibrationError as e:
        text = str(e)
        named = [n for n in names if text.startswith(f"{n}:") or f" {n}:" in text or f", {n}" in text]
        if not named or len(named) == len(names):
            raise
        for n in named:
            missing[n] = f"the new views cannot place it in the rig ({text})"
        rest = [n for n in names if n not in named]
        solo = {}
        for n in named:
            try:
                solo[n] = estimate_rig(rec.views, with_subset(rig, [n]), rec.corners, rec.faces)
            except CalibrationError:
                pass
        return estimate_rig(rec.views, with_subset(rig, rest), rec.corners, rec.faces), rest, solo
