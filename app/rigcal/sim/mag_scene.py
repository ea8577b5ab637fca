"""`rigcal simulate --scene mag`: the compass "dance" (docs/magnetometer.md).

The rig is turned by hand through every orientation (yaw, pitch and roll each a sum of two
slow sines of large amplitude: upside down, nose down, on each side), moving a few
centimetres; no images. The dataset holds rig.yaml (as declared), imu/<imu>.csv (imu_model:
noise and bias walks as declared), mag/<mag>.csv and truth.yaml.

Each magnetometer reads m = inv(A) R_body_mag.T b_body + h + noise (model.py) with, per seed:
a hard iron h of random direction and magnitude up to --hard-iron-ut; a soft iron A whose
eigenvalues lie within +-soft_iron of 1 along random axes, normalised to determinant 1 unless
the rig declares the site field (earth_field_uT), whose magnitude it then keeps; the true
R_body_mag the declared one turned by --misalignment-deg (uniform in [1/3, 1] of it) about a
random axis; white noise of the declared density. The local field: magnitude the declared
earth_field_uT or 50 uT, inclination uniform in 50-70 deg, declination uniform in +-20 deg.
Magnetometer clocks (t_imu = t_mag + time_offset_s) carry the declared offset plus uniform
+-CLOCK_ERROR_S where the rig declares one, none otherwise.

Randomness: streams [seed, 21] trajectory, [seed, 22] field, [seed, 23, i] magnetometer i's
errors, [seed, 24, i] its noise, [seed, 4, i] IMU i's noise (as in --scene imu).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.core.io import atomic_dir
from rigcal.core.rig import Magnetometer, Rig, load_rig, rig_to_dict
from rigcal.data.imu_csv import imu_csv
from rigcal.data.mag_csv import mag_csv
from rigcal.errors import InputError
from rigcal.mag import model
from rigcal.sim import imu_model

EPOCH_NS = 1_600_000_000_000_000_000  # as --scene imu: the IMU clock at t = 0
DEFAULT_FIELD_UT = 50.0
CLOCK_ERROR_S = 0.005  # a declared time_offset_s is off by up to this in the truth
DEFAULTS = {"duration": 60.0, "hard_iron_ut": 30.0, "soft_iron": 0.15, "misalignment_deg": 3.0}
# the dance: two sines per angle (yaw, pitch, roll), slow and wide; a few cm of hand motion
ANG_AMP_RAD = np.array([[3.0, 1.0], [0.9, 0.45], [2.6, 0.8]])
ANG_FREQ_HZ = np.array([[0.04, 0.11], [0.07, 0.17], [0.05, 0.13]])
POS_AMP_M = np.array([[0.04, 0.015], [0.04, 0.015], [0.03, 0.01]])
POS_FREQ_HZ = np.array([[0.23, 0.61], [0.19, 0.53], [0.29, 0.71]])


def dance_trajectory(rng: np.random.Generator) -> imu_model.SineTrajectory:
    """A seeded hand-turned rotation through all orientations (frequencies jittered +-10 %)."""
    jitter = lambda f: f * rng.uniform(0.9, 1.1, f.shape)  # noqa: E731
    return imu_model.SineTrajectory(
        p0=np.zeros(3), pos_amp=POS_AMP_M, pos_freq=jitter(POS_FREQ_HZ),
        pos_phase=rng.uniform(0, 2 * math.pi, POS_AMP_M.shape), ypr0=np.zeros(3), ang_amp=ANG_AMP_RAD,
        ang_freq=jitter(ANG_FREQ_HZ), ang_phase=rng.uniform(0, 2 * math.pi, ANG_AMP_RAD.shape))


@dataclass(frozen=True)
class MagTruth:
    """One magnetometer's true errors (model.py): hard_iron (3,) uT, soft_iron (3, 3)."""

    hard_iron: np.ndarray
    soft_iron: np.ndarray


@dataclass(frozen=True)
class EarthField:
    field_uT: float
    inclination_deg: float
    declination_deg: float

    def world(self) -> np.ndarray:
        """The field (3,) in ENU: model.field_world turned by the declination about up."""
        Rz = geo.R_from_rotvec(np.array([0.0, 0.0, -math.radians(self.declination_deg)]))
        return Rz @ model.field_world(self.field_uT, math.radians(self.inclination_deg))


def true_magnetometer(mag: Magnetometer, rng: np.random.Generator, hard_iron_ut: float, soft_iron: float,
                      misalignment_deg: float) -> tuple[Magnetometer, MagTruth]:
    """The true mount and errors of a declared magnetometer (module docstring)."""
    d = rng.normal(size=3)
    h = d / np.linalg.norm(d) * rng.uniform(0.0, hard_iron_ut)
    Q = geo.R_from_rotvec(rng.normal(size=3))
    A = Q @ np.diag(1.0 + rng.uniform(-soft_iron, soft_iron, 3)) @ Q.T
    if mag.earth_field_uT is None:
        A, _ = model.normalise(A, 1.0)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = math.radians(misalignment_deg) * rng.uniform(1.0 / 3.0, 1.0)
    T = mag.T_body_mag.copy()
    T[:3, :3] = geo.R_from_rotvec(axis * angle) @ T[:3, :3]
    offset = mag.time_offset_s
    if offset is not None:  # a declared clock offset is the nominal one: the truth is within CLOCK_ERROR_S of it
        offset = float(offset + rng.uniform(-CLOCK_ERROR_S, CLOCK_ERROR_S))
    return replace(mag, T_body_mag=T, time_offset_s=offset), MagTruth(h, A)


def mag_readings(motion: imu_model.Motion, mag: Magnetometer, truth: MagTruth, b_world: np.ndarray,
                 rng: np.random.Generator | None) -> np.ndarray:
    """Raw readings (N, 3) along motion (sampled at the magnetometer's instants, IMU clock)."""
    b_body = np.einsum("nji,j->ni", motion.R_world_body, b_world)
    m = model.readings(b_body, truth.hard_iron, truth.soft_iron, mag.T_body_mag[:3, :3])
    if rng is not None:
        m = m + rng.standard_normal(m.shape) * mag.sample_sigma_uT
    return m


@dataclass(frozen=True)
class MagSimResult:
    out_dir: Path
    truth: Rig
    mags: dict[str, MagTruth]
    field: EarthField
    seconds: float


def check_settings(rig: Rig, duration: float, label: str) -> None:
    if not rig.magnetometers:
        raise InputError(f"{label}: magnetometers: --scene mag needs a rig that declares a magnetometer "
                         f"(and its IMU)")
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and 5.0 <= duration <= 3600.0):
        raise InputError(f"--duration: expected seconds from 5 to 3600 for --scene mag, got {duration!r}")


def simulate_mag_dataset(rig: Rig, out_dir: str | Path, *, duration: float = DEFAULTS["duration"], seed: int = 0,
                         hard_iron_ut: float = DEFAULTS["hard_iron_ut"], soft_iron: float = DEFAULTS["soft_iron"],
                         misalignment_deg: float = DEFAULTS["misalignment_deg"], force: bool = False,
                         rig_text: str | None = None, label: str = "<rig>",
                         trajectory: imu_model.SineTrajectory | None = None) -> MagSimResult:
    """Write a dance dataset of `rig` into out_dir, whole or not at all (`trajectory`: another
    motion than the dance, e.g. one that misses orientations)."""
    t0 = time.perf_counter()
    check_settings(rig, duration, label)
    traj = dance_trajectory(np.random.default_rng([seed, 21])) if trajectory is None else trajectory
    truth, truths, field = true_magnetometers(rig, seed, hard_iron_ut, soft_iron, misalignment_deg)
    out_dir = Path(out_dir)
    with atomic_dir(out_dir, force=force) as tmp:
        (tmp / "rig.yaml").write_text(rig_text if rig_text is not None else _dump(rig_to_dict(rig)), encoding="utf-8")
        (tmp / "imu").mkdir()
        for ii, imu in enumerate(truth.imus):
            t = np.arange(int(math.floor(duration * imu.update_rate)) + 1) / imu.update_rate
            s = imu_model.synthesize(traj.at(t), imu, np.random.default_rng([seed, 4, ii]))
            (tmp / "imu" / f"{imu.name}.csv").write_text(imu_csv(EPOCH_NS + np.rint(t * 1e9).astype(np.int64),
                                                                 s.gyro, s.accel), encoding="utf-8")
        write_mag_files(tmp, truth, truths, field, traj, seed, duration)
        doc = {"rig": rig_to_dict(truth), "magnetometers": magnetometer_truth(truth, truths),
               "earth_field": {"field_uT": field.field_uT, "inclination_deg": field.inclination_deg,
                               "declination_deg": field.declination_deg},
               "gravity_world": [float(x) + 0.0 for x in imu_model.G_WORLD],
               "render": {"seed": int(seed), "scene": "mag", "duration_s": float(duration), "epoch_ns": EPOCH_NS}}
        (tmp / "truth.yaml").write_text(_dump(doc), encoding="utf-8")
    return MagSimResult(out_dir, truth, truths, field, time.perf_counter() - t0)


def true_magnetometers(rig: Rig, seed: int, hard_iron_ut: float = DEFAULTS["hard_iron_ut"],
                       soft_iron: float = DEFAULTS["soft_iron"], misalignment_deg: float = DEFAULTS["misalignment_deg"]
                       ) -> tuple[Rig, dict[str, MagTruth], EarthField]:
    """The rig with its magnetometers' true mounts, their true errors and the local field."""
    frng = np.random.default_rng([seed, 22])
    F = next((m.earth_field_uT for m in rig.magnetometers if m.earth_field_uT is not None), DEFAULT_FIELD_UT)
    field = EarthField(float(F), float(frng.uniform(50.0, 70.0)), float(frng.uniform(-20.0, 20.0)))
    mags, truths = [], {}
    for i, m in enumerate(rig.magnetometers):
        tm, tr = true_magnetometer(m, np.random.default_rng([seed, 23, i]), hard_iron_ut, soft_iron, misalignment_deg)
        mags.append(tm)
        truths[m.name] = tr
    return replace(rig, magnetometers=tuple(mags)), truths, field


def add_magnetometers(tmp: Path, truth: Rig, traj: imu_model.SineTrajectory, seed: int, duration: float) -> None:
    """`--scene imu` for a rig that declares magnetometers: mag/ along the same motion, and
    truth.yaml's rig, `magnetometers` and `earth_field` to match."""
    truth, truths, field = true_magnetometers(truth, seed)
    write_mag_files(tmp, truth, truths, field, traj, seed, duration)
    path = tmp / "truth.yaml"
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    doc["rig"]["magnetometers"] = rig_to_dict(truth)["magnetometers"]
    doc["magnetometers"] = magnetometer_truth(truth, truths)
    doc["earth_field"] = {"field_uT": field.field_uT, "inclination_deg": field.inclination_deg,
                          "declination_deg": field.declination_deg}
    path.write_text(_dump(doc), encoding="utf-8")


def write_mag_files(tmp: Path, truth: Rig, truths: dict[str, MagTruth], field: EarthField,
                    traj: imu_model.SineTrajectory, seed: int, duration: float) -> None:
    """mag/<mag>.csv for every magnetometer of `truth`, from 0 to `duration` on the IMU clock."""
    (tmp / "mag").mkdir()
    b_world = field.world()
    for i, m in enumerate(truth.magnetometers):
        off = m.time_offset_s or 0.0
        t_mag = np.arange(int(math.floor(duration * m.update_rate)) + 1) / m.update_rate  # own clock, from 0
        t_mag = t_mag[(t_mag + off >= 0.0) & (t_mag + off <= duration)]
        readings = mag_readings(traj.at(t_mag + off), m, truths[m.name], b_world, np.random.default_rng([seed, 24, i]))
        t_ns = EPOCH_NS + np.rint(t_mag * 1e9).astype(np.int64)
        (tmp / "mag" / f"{m.name}.csv").write_text(mag_csv(t_ns, readings), encoding="utf-8")


def magnetometer_truth(truth: Rig, truths: dict[str, MagTruth]) -> dict[str, Any]:
    return {m.name: {"hard_iron_uT": [float(x) for x in truths[m.name].hard_iron],
                     "soft_iron": [[float(x) for x in r] for r in truths[m.name].soft_iron],
                     "time_offset_s": float(m.time_offset_s or 0.0)} for m in truth.magnetometers}


def _dump(d: dict) -> str:
    return yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=120)


def run(rig_path, out_dir, duration=None, seed=0, force=False) -> str:
    """`rigcal simulate --scene mag`: returns the summary for stdout."""
    rig_path = Path(rig_path)
    rig = load_rig(rig_path)
    res = simulate_mag_dataset(rig, out_dir, duration=DEFAULTS["duration"] if duration is None else duration,
                               seed=seed, force=force, rig_text=rig_path.read_text(encoding="utf-8"),
                               label=str(rig_path))
    f = res.field
    lines = [f"wrote {res.out_dir}: mag scene (the compass dance), {len(res.truth.imus)} IMU stream(s), "
             f"{len(res.mags)} magnetometer(s), {res.seconds:.1f} s",
             f"  field {f.field_uT:.1f} uT, inclination {f.inclination_deg:.1f} deg, declination "
             f"{f.declination_deg:.1f} deg"]
    for m in res.truth.magnetometers:
        t = res.mags[m.name]
        lines.append(f"  {m.name}: hard iron {np.linalg.norm(t.hard_iron):.1f} uT, soft iron eigenvalues "
                     + "/".join(f"{e:.3f}" for e in np.linalg.eigvalsh(t.soft_iron)))
    return "\n".join(lines)
