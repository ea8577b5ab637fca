"""`rigcal check RIG DATASET`: is the rig's calibration still good, and which camera moved?

Reads the calibrated rig and the recording (inputs), estimates the rig again from the new
views alone (estimate), tests every camera (verdict), and hands back the table or JSON,
the report and the updated rig (outputs, report), written whole or not at all.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rigcal.check import inputs
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
    vs, n_tests, level_each, keep = verdicts(rig, est, {n: structure(rig.camera(n).calibration) for n in rig.names},
                                             missing, level, solo)
    timings = {"detection_s": rec.detection_s, "estimate_s": t_est - t_det, "total_s": time.perf_counter() - t0}
    res = CheckResult(rig_path=str(rig_path), dataset=str(dataset), verdicts=vs, level=level, n_tests=n_tests,
                      level_each=level_each, aligned_by=tuple(names[i] for i in keep) if est else (),
                      timings=timings, notes=tuple(_imu_note(rig, dataset)))
    writes = []
    if update_path is not None and est is not None:
        writes.append((update_path, dump_rig(updated_rig(rig, est, res, str(dataset)))))
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


def _imu_note(rig, dataset: Path) -> list[str]:
    """What the check leaves out on a camera-IMU rig."""
    if rig.imus and (dataset / "imu").is_dir():
        return ["the recording has imu/: the cameras are checked, the camera-IMU transform and clock offsets are not"]
    return []


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
