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


def filtered_axis(seconds: float, rate: float, n_density: float, k_walk: float, kind: str, seed: int,
                  up: int = 8) -> tuple[np.ndarray, float]:
    """(x (N,) at rate, its white noise density at low frequencies): one axis as an IMU chip
    makes it, white noise of density n_density at up * rate through the chip's filter with
    every up-th sample kept (consecutive samples correlated), plus a random walk k_walk.
    kind: "moving average" (16 taps at up * rate) or "one pole" (time constant 10 ms, unit
    gain at DC). The decimated series' density at frequencies well below the filter's is
    n_density sqrt(sum_k |H(2 pi k / up)|^2), k = 0 .. up - 1 (the filter's gain at DC and at
    the frequencies that alias onto it): n_density itself for the moving average (zeros at
    every multiple of rate / 2), 3.95 % more for the one-pole filter at 100 Hz."""
    from scipy.signal import freqz, lfilter

    rng = np.random.default_rng(seed)
    n, fs = int(seconds * rate), rate * up
    w = n_density * np.sqrt(fs) * rng.standard_normal(n * up + 64)
    if kind == "moving average":
        b, a = np.ones(16) / 16, np.array([1.0])
    elif kind == "one pole":
        pole = np.exp(-1.0 / (fs * 0.010))
        b, a = np.array([1.0 - pole]), np.array([1.0, -pole])
    else:
        raise ValueError(kind)
    x = lfilter(b, a, w)[64:][: n * up: up] + np.cumsum(k_walk / np.sqrt(rate) * rng.standard_normal(n))
    gain = np.abs(freqz(b, a, worN=2 * np.pi * np.arange(up) / up)[1])
    return x, n_density * float(np.sqrt(np.sum(gain ** 2)))


def write_csv(path: Path, t, gyro, accel, temp=None) -> Path:
    cols = [gyro, accel] + ([np.asarray(temp)[:, None]] if temp is not None else [])
    v = np.hstack(cols)
    fmt = "%d," + ",".join(["%.10g"] * v.shape[1])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(IMU_HEADER + ("" if temp is None else ",temperature [C]") + "\n"
                    + "\n".join(fmt % (int(ti), *row) for ti, row in zip(t, v.tolist())) + "\n")
    return path
