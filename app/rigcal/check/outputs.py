"""What `rigcal check` hands back: the JSON object (`--json`), the console table, and the
updated rig (`--update`): only what changed re-estimated, the rest of the rig held."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from rich.console import Group
from rich.table import Table

from rigcal import __version__
from rigcal.check import decide
from rigcal.check.estimate import NewEstimate
from rigcal.check.verdict import CHANGED, INTRINSICS, OK, CameraVerdict, IntrinsicsCheck, PoseCheck, \
    ChiSquare, relative_pose_variances
from rigcal.core import geometry as geo
from rigcal.core.rig import Rig

AXES = ("F", "L", "U")


@dataclass(frozen=True)
class CheckResult:
    """The whole check: per camera its verdict (rig order), the family-wise level, the
    number of tests and the per-test level, the cameras the new rig was aligned by, and
    timings (s)."""

    rig_path: str
    dataset: str
    verdicts: list[CameraVerdict]
    level: float
    n_tests: int
    level_each: float
    aligned_by: tuple[str, ...]
    timings: dict
    notes: tuple[str, ...] = ()
    updated: dict = field(default_factory=dict)  # --update: camera -> what was done with it (update_actions)

    @property
    def changed(self) -> list[str]:
        return [v.name for v in self.verdicts if v.status in CHANGED]

    @property
    def exit_code(self) -> int:
        return 1 if self.changed else 0


def _f(x: float, nd: int = 6) -> float | None:
    return float(np.round(float(x), nd)) if np.isfinite(x) else None


def _v(a, nd: int = 6) -> list:
    return [_f(x, nd) for x in a]


def _test(t: ChiSquare) -> dict:
    return {"statistic": _f(t.statistic, 4), "dof": t.dof, "p_value": float(f"{t.p_value:.4g}"),
            "threshold": _f(t.threshold, 4), "changed": t.failed}


def _pose(p: PoseCheck) -> dict:
    return {"rotation_deg": _v(p.rotation_deg), "rotation_sigma_deg": _v(p.rotation_sigma_deg),
            "translation_mm": _v(p.translation_mm, 4), "translation_sigma_mm": _v(p.translation_sigma_mm, 4),
            "relative_to": list(p.relative_to), **_test(p.test),
            "detectable_rotation_deg": _v(p.detectable_rotation_deg),
            "detectable_translation_mm": _v(p.detectable_translation_mm, 4)}


def _intrinsics(i: IntrinsicsCheck) -> dict:
    return {"change_px": {k: _f(x, 4) for k, x in i.change.items()},
            "sigma_px": {k: _f(x, 4) for k, x in i.sigma.items()}, **_test(i.test),
            "detectable_px": {k: _f(x, 4) for k, x in i.detectable.items()},
            "displacement_px": _f(i.displacement_px, 4)}


def _imu(m) -> dict:
    """The camera-IMU part of a camera (rigcal.check.imu.ImuCheck)."""
    return {"imu": m.imu, "rotation_deg": _v(m.rotation_deg), "rotation_sigma_deg": _v(m.rotation_sigma_deg),
            "translation_mm": _v(m.translation_mm, 4), "translation_sigma_mm": _v(m.translation_sigma_mm, 4),
            **_test(m.pose_test), "detectable_rotation_deg": _v(m.detectable_rotation_deg),
            "detectable_translation_mm": _v(m.detectable_translation_mm, 4),
            "clock": {"offset_change_ms": _f(m.offset_ms, 5), "sigma_ms": _f(m.offset_sigma_ms, 5),
                      **_test(m.offset_test), "detectable_ms": _f(m.detectable_offset_ms, 5)}}


def to_json(res: CheckResult) -> dict:
    """The `--json` object (docs/check.md lists its keys)."""
    cams = {}
    for v in res.verdicts:
        d = {"status": v.status}
        if v.pose is not None:
            d["pose"] = _pose(v.pose)
        if v.intrinsics is not None:
            d["intrinsics"] = _intrinsics(v.intrinsics)
        if v.imu is not None:
            d["imu"] = _imu(v.imu)
        if v.name in res.updated:
            d["update"] = res.updated[v.name]
        if v.notes:
            d["notes"] = list(v.notes)
        cams[v.name] = d
    return {"rig": res.rig_path, "dataset": res.dataset, "status": "changed" if res.changed else "ok",
            "changed": res.changed, "level": res.level, "tests": res.n_tests, "level_per_test": _f(res.level_each, 8),
            "correction": "sidak", "aligned_by": list(res.aligned_by), "cameras": cams, "notes": list(res.notes),
            "seconds": {k: _f(x, 3) for k, x in res.timings.items()}}


def _axes(x, nd) -> str:
    return " ".join(f"{a:+.{nd}f}" for a in x)


def _sig(x, nd) -> str:
    return " ".join(f"{a:.{nd}f}" for a in x)


def _table(title: str, cols: tuple[str, ...]) -> Table:
    t = Table(title=title, show_lines=False)
    for k, col in enumerate(cols):
        t.add_column(col, justify="left" if k == 0 or col == "status" else "right")
    return t


def console_table(res: CheckResult) -> Group:
    """The tables on stdout (verdicts, pose changes, intrinsics changes) and the lines under
    them: the level, the tests, the notes."""
    t = _table("check", ("camera", "status", "pose chi2 / threshold", "intrinsics chi2 / threshold",
                         "detectable rotation deg", "detectable position mm", "detectable intrinsics px"))
    tp = _table("pose change in the rig's body frame", ("camera", "rotation deg F L U", "1-sigma",
                                                        "position mm F L U", "1-sigma", "relative to"))
    ti = _table("intrinsics change (new - rig)", ("camera", "change px", "1-sigma px", "image shift px"))
    tm = _table("camera relative to the IMU (new - rig, body frame) and clock offset",
                ("camera", "rotation deg F L U", "1-sigma", "position mm F L U", "1-sigma", "chi2 / threshold",
                 "clock offset change ms", "1-sigma", "chi2 / threshold", "detectable rot deg / pos mm / ms"))
    for v in res.verdicts:
        p, i, m = v.pose, v.intrinsics, v.imu
        if m is not None:
            tm.add_row(v.name, _axes(m.rotation_deg, 4), _sig(m.rotation_sigma_deg, 4), _axes(m.translation_mm, 3),
                       _sig(m.translation_sigma_mm, 3), f"{m.pose_test.statistic:.1f} / {m.pose_test.threshold:.1f}",
                       f"{m.offset_ms:+.3f}", f"{m.offset_sigma_ms:.3f}",
                       f"{m.offset_test.statistic:.1f} / {m.offset_test.threshold:.1f}",
                       f"{np.max(m.detectable_rotation_deg):.4f} / {np.max(m.detectable_translation_mm):.3f} / "
                       f"{m.detectable_offset_ms:.3f}")
        t.add_row(v.name, v.status, f"{p.test.statistic:.1f} / {p.test.threshold:.1f}" if p else "-",
                  f"{i.test.statistic:.1f} / {i.test.threshold:.1f}" if i else "-",
                  f"{np.max(p.detectable_rotation_deg):.4f}" if p else "-",
                  f"{np.max(p.detectable_translation_mm):.3f}" if p else "-",
                  f"{max(i.detectable.values()):.3f}" if i else "-")
        if p:
            tp.add_row(v.name, _axes(p.rotation_deg, 4), _sig(p.rotation_sigma_deg, 4), _axes(p.translation_mm, 3),
                       _sig(p.translation_sigma_mm, 3), ", ".join(p.relative_to))
        if i:
            ti.add_row(v.name, " ".join(f"{k} {x:+.3f}" for k, x in i.change.items()),
                       " ".join(f"{k} {i.sigma[k]:.3f}" for k in i.change), f"{i.displacement_px:.3f}")
    head = (f"level {res.level:g} for the whole check: {res.n_tests} tests at {res.level_each:.3g} each (Sidak); "
            f"rig aligned by {', '.join(res.aligned_by) or '-'}; detectable: the smallest change flagged in "
            f"{100 * decide.DETECT_POWER:.0f} % of recordings like this one (worst axis or parameter)")
    lines = [t] + ([tp] if any(v.pose for v in res.verdicts) else []) + [ti] + (
        [tm] if any(v.imu for v in res.verdicts) else []) + [head]
    lines += [f"note: {n}" for v in res.verdicts for n in v.notes] + [f"note: {n}" for n in res.notes]
    lines += [f"--update: {n}: {what}" for n, what in res.updated.items() if what != "kept"]
    if res.changed:
        lines.append("changed: " + ", ".join(f"{v.name} ({v.status})" for v in res.verdicts
                                             if v.status in CHANGED))
    else:
        lines.append("all cameras ok" if all(v.status == OK for v in res.verdicts)
                     else "no camera changed; some could not be checked (undetermined)")
    return Group(*lines)


# ----------------------------------------------------------------------------- --update


def updated_rig(rig: Rig, est: NewEstimate, res: CheckResult, dataset: str, imu_est=None) -> tuple[Rig, dict]:
    """(the rig with each changed camera re-estimated from the new recording, the rest held;
    per camera what was done with it, for the output). A moved camera's pose is the new one
    placed by the unchanged cameras (its sigma the new estimate's and the alignment's), or,
    checked against the IMU (imu_est: rigcal.check.imu.ImuEstimate), the new T_imu_cam placed
    by the rig's T_body_imu with the new estimate's sigma; a changed clock offset takes the
    new one and its sigma; a camera whose intrinsics changed takes the new intrinsics
    (distortion too) and sigmas. Unchanged cameras keep pose, intrinsics, sigmas; a changed
    camera the new recording could not estimate with the others is left as it was (said so)."""
    names = list(est.names)
    T_new = est.T_body_cam
    T_old = np.array([rig.camera(n).T_body_cam for n in names])
    keep = [names.index(n) for n in res.aligned_by]
    var_old = relative_pose_variances(rig, names)
    cams, actions = [], {}
    for cam in rig.cameras:
        v = next(x for x in res.verdicts if x.name == cam.name)
        if v.status not in CHANGED:
            cams.append(cam)
            actions[cam.name] = "kept" if v.status == OK else (
                "left as it was: the new recording cannot tell whether it changed (undetermined)")
            continue
        if cam.name not in names:
            cams.append(cam)
            actions[cam.name] = (f"left as it was although it changed ({v.status}): the new recording cannot connect "
                                 f"it to the other cameras, so its calibration cannot be re-estimated in the rig "
                                 f"(record the boards in view of it and of another camera)")
            continue
        c = names.index(cam.name)
        block = dict(cam.calibration)
        sigma = dict(block["sigma"])
        done = []
        if v.status == INTRINSICS:
            cam = replace(cam, intrinsics=est.model(c, cam.intrinsics))
            sd = np.sqrt(np.clip(np.diag(est.cov_intrinsics[c]), 0, None))
            sigma["intrinsics"] = {k: float(np.round(sd[j], 4)) for j, k in enumerate(("fx", "fy", "cx", "cy"))}
            done.append("intrinsics")
        if v.pose is not None and v.pose.test.failed:
            others = [j for j in keep if j != c] or [j for j in range(len(names)) if j != c]
            T_align = geo.fit_rigid_to(T_new[others], T_old[others])
            cov = decide.delta_covariance(est.state.T_cam_body, est.cov_poses, T_old, var_old, c, others)
            sd = np.sqrt(np.clip(np.diag(cov) - var_old[c], 0, None))  # without the rig's own error of this camera
            cam = replace(cam, T_body_cam=T_align @ T_new[c])
            sigma["rotation_deg"] = [float(np.round(np.degrees(x), 5)) for x in sd[:3]]
            sigma["position_mm"] = [float(np.round(1000 * x, 4)) for x in sd[3:]]
            done.append("pose")
        if v.imu is not None and imu_est is not None and cam.name in imu_est.names:
            k = imu_est.names.index(cam.name)
            if v.imu.pose_test.failed:
                cam = replace(cam, T_body_cam=rig.imu(imu_est.imu).T_body_imu @ imu_est.T_imu_cam[k])
                sp = imu_est.sigma_pose[k]
                sigma["rotation_deg"] = [float(np.round(np.degrees(x), 5)) for x in sp[:3]]
                sigma["position_mm"] = [float(np.round(1000 * x, 4)) for x in sp[3:]]
                done.append(f"pose relative to {imu_est.imu}")
            if v.imu.offset_test.failed:
                cam = replace(cam, time_offset_s=float(imu_est.time_offset_s[k]))
                sigma["time_offset_ms"] = float(np.round(1000 * imu_est.sigma_offset[k], 5))
                done.append("clock offset")
        block["sigma"] = sigma
        block["updated"] = {"tool": f"rigcal {__version__} check", "dataset": dataset, "status": v.status}
        cams.append(replace(cam, calibration=block))
        actions[cam.name] = "re-estimated from the new recording: " + ", ".join(done)
    return rig.with_cameras(cams), actions
