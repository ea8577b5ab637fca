"""Static IMU recordings of known white noise density and random walk for the imu-noise
tests (written independently of rigcal.sim.static_imu): 6 axes, gravity on z."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigcal.data.imu_csv import IMU_HEADER

T0_NS = 1_600_000_000_000_000_000


def static_imu(seconds: float, rate: float, n_density, k_walk, seed: int = 0):
    """(t_ns (N,), gyro (N, 3), accel (N, 3)); n_density, k_walk: (6,) or scalars, gyro then accel."""
    rng = np.random.default_rng(seed)
    n, dt = int(seconds * rate), 1.0 / rate
    nd, kw = np.broadcast_to(n_density, (6,)), np.broadcast_to(k_walk, (6,))
    x = nd / np.sqrt(dt) * rng.standard_normal((n, 6)) + np.cumsum(kw * np.sqrt(dt) * rng.standard_normal((n, 6)),
                                                                    axis=0)
    x[:, 5] += 9.80665
    t = T0_NS + np.round(np.arange(n) * dt * 1e9).astype(np.int64)
    return t, x[:, :3], x[:, 3:]


def write_csv(path: Path, t, gyro, accel, temp=None) -> Path:
    cols = [gyro, accel] + ([np.asarray(temp)[:, None]] if temp is not None else [])
    v = np.hstack(cols)
    fmt = "%d," + ",".join(["%.10g"] * v.shape[1])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(IMU_HEADER + ("" if temp is None else ",temperature [C]") + "\n"
                    + "\n".join(fmt % (int(ti), *row) for ti, row in zip(t, v.tolist())) + "\n")
    return path
