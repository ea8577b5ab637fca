"""Recordings for `rigcal check`: a rig calibrated from one simulated recording, and new
recordings of the same true rig, unchanged or with one camera turned, shifted or its lens
changed. Used by tests/check/ and bench/check.py.

The true rig is drawn once (simulate's mount and lens errors, seed `truth_seed`); the new
recordings render that true rig (or a changed copy) exactly: simulate's own scene planner and
renderer without its perturbation (which draws principal-point and distortion errors even
at zero mount and focal error).
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.io import atomic_dir
from rigcal.core.rig import Rig, dump_rig, load_rig
from rigcal.core.target import dump_target
from rigcal.sim import simulate as sim

RIG = Path(__file__).resolve().parents[2] / "rigs" / "drone-stereo-back.yaml"
AXIS = {"F": 0, "L": 1, "U": 2}


def changed_rig(rig: Rig, camera: str, rotate_deg: float = 0.0, axis: str = "U", shift_mm: float = 0.0,
                shift_axis: str = "L", focal_rel: float = 0.0, pp_px: tuple[float, float] = (0.0, 0.0)) -> Rig:
    """The rig with one camera turned by rotate_deg about body `axis`, shifted by shift_mm
    along body `shift_axis`, its fx and fy scaled by 1 + focal_rel and its principal point
    moved by pp_px."""
    cams = []
    for c in rig.cameras:
        if c.name == camera:
            T = c.T_body_cam.copy()
            r = np.zeros(3)
            r[AXIS[axis]] = np.radians(rotate_deg)
            T[:3, :3] = geo.R_from_rotvec(r) @ T[:3, :3]
            T[AXIS[shift_axis], 3] += shift_mm / 1000.0
            m = c.intrinsics
            m = m.with_(fx=m.fx * (1 + focal_rel), fy=m.fy * (1 + focal_rel), cx=m.cx + pp_px[0], cy=m.cy + pp_px[1])
            c = replace(c, T_body_cam=T, intrinsics=m)
        cams.append(c)
    return rig.with_cameras(cams)


def record(true_rig: Rig, out: Path, frames: int, seed: int, jobs: int = 1, noise: float = 2.0) -> Path:
    """A room recording of exactly this rig (simulate_dataset's steps, no errors drawn):
    images/, rig.yaml (this rig) and target.yaml."""
    target = sim.make_target_for_rig(true_rig, "room")
    plan = sim.plan_room_scene(true_rig, target, frames, np.random.default_rng([seed, 2]))
    with atomic_dir(out, force=True) as tmp:
        sim.render_all(true_rig, plan, sim.RenderSettings(seed=seed, noise=noise, blur=0.0), tmp, jobs, False)
        (tmp / "rig.yaml").write_text(dump_rig(true_rig), encoding="utf-8")
        (tmp / "target.yaml").write_text(dump_target(target), encoding="utf-8")
    return out


def true_rig(truth_seed: int = 1) -> Rig:
    """The golden rig with simulate's mount and lens errors drawn for this seed."""
    return sim.perturb_rig(load_rig(RIG), np.random.default_rng([truth_seed, 1]))


def calibrated_rig(truth: Rig, work: Path, frames: int = 30, seed: int = 1000, jobs: int = 1) -> Path:
    """The rig YAML `rigcal calibrate` writes from a `frames`-frame recording of `truth`
    (declared as the golden rig's nominal file)."""
    from rigcal.commands.calibrate import CalibrateOptions, run

    base = record(truth, work / "base", frames, seed, jobs)
    (base / "rig.yaml").write_text(RIG.read_text(encoding="utf-8"), encoding="utf-8")
    out = work / "calibrated.yaml"
    run(base, out, CalibrateOptions(jobs=jobs))
    return out


def documented_keys() -> set[str]:
    """The JSON keys docs/check.md's two tables list (first cell of each row, backticked)."""
    text = (RIG.parents[1] / "docs" / "check.md").read_text(encoding="utf-8").split("## `--json`")[1].split("## ")[0]
    keys = set()
    for line in text.splitlines():
        if line.startswith("| `"):
            first = line.split("|")[1]
            found = re.findall(r"`([a-z_.]+)`", first)
            prefix = found[0].split(".")[0] + "." if "." in found[0] else ""
            keys |= {k if "." in k or not prefix else prefix + k for k in found}
    return keys


def json_keys(d: dict) -> set[str]:
    """Top-level keys, and per camera its keys and its pose./intrinsics./imu./imu.clock. keys, of one check's JSON."""
    keys = set(d)
    for c in d["cameras"].values():
        keys |= set(c) | {f"{part}.{k}" for part in ("pose", "intrinsics", "imu") if part in c for k in c[part]}
        keys |= {f"imu.clock.{k}" for k in c.get("imu", {}).get("clock", {})}
    return keys
