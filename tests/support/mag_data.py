"""Small simulated magnetometer datasets (rigcal simulate --scene mag) for the tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigcal.core.rig import load_rig
from rigcal.sim import imu_model
from rigcal.sim.mag_scene import MagSimResult, simulate_mag_dataset

ROOT = Path(__file__).resolve().parents[2]
MAG_RIG = ROOT / "rigs" / "drone-imu-mag.yaml"


def mag_dataset(out: Path, seed: int = 0, duration: float = 20.0, yaw_only: bool = False) -> MagSimResult:
    """The dance (or, yaw_only, turns about the vertical with 10 degrees of tilt: half the
    sphere never seen) of the shipped drone-imu-mag rig into `out`."""
    traj = None
    if yaw_only:
        traj = imu_model.SineTrajectory(
            p0=np.zeros(3), pos_amp=np.zeros((3, 1)), pos_freq=np.full((3, 1), 0.3), pos_phase=np.zeros((3, 1)),
            ypr0=np.zeros(3), ang_amp=np.array([[3.5], [0.17], [0.17]]), ang_freq=np.array([[0.05], [0.3], [0.4]]),
            ang_phase=np.zeros((3, 1)))
    return simulate_mag_dataset(load_rig(MAG_RIG), out, duration=duration, seed=seed,
                                rig_text=MAG_RIG.read_text(encoding="utf-8"), trajectory=traj)
