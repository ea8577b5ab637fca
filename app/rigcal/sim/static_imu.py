"""`rigcal simulate RIG --scene static`: a still IMU recording with known noise, for
`rigcal imu-noise`.

Each IMU of the rig rests level (body z up), and each axis of its gyroscope and
accelerometer reads a constant (gravity through the IMU's axes, a turn-on bias) plus:

- white noise of density N (the rig's `*_noise_density`): N / sqrt(dt) per sample;
- a bias random walk of density K (the rig's `*_random_walk`): cumulative sum of
  K sqrt(dt) steps;
- bias instability: flicker noise as a sum of first-order Gauss-Markov processes with
  equal variances and time constants spread by factors of GM_SPREAD from two sample
  periods to the whole recording, whose Allan deviation is then flat (within a few %) at
  0.664 B over every tau an analysis reads; each an AR(1) filter (scipy.signal.lfilter)
  started in its stationary distribution;
- quantisation: every reading rounded to the sensor's LSB, which adds white noise of
  density LSB sqrt(dt / 12) (the truth gives the density with it).

B defaults to the level where the flat term equals the minimum of the white + random-walk
deviation (sqrt(2 N K / sqrt 3) / 0.664), so that all three terms show.
`allan_variance` is the model's exact Allan variance (benchmarks and tests compare with it).

Randomness: stream [seed, 5, i] for IMU i. Axes are simulated one at a time (memory linear
in the recording: about 60 bytes a sample), the csv written in chunks.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.signal import lfilter

from rigcal.core.io import atomic_dir
from rigcal.core.rig import Imu, load_rig
from rigcal.data.imu_csv import IMU_HEADER
from rigcal.errors import InputError

EPOCH_NS = 1_600_000_000_000_000_000
GRAVITY = 9.80665
GM_SPREAD = 4.0
FLAT = 2.0 * math.log(2.0) / math.pi
LSB = {"gyroscope": 2000.0 * math.pi / 180.0 / 32768.0,  # 16 bits over +-2000 deg/s
       "accelerometer": 16.0 * GRAVITY / 32768.0}  # 16 bits over +-16 g
CHUNK = 200_000
DEFAULT_DURATION_S = 3.0 * 3600.0


@dataclass(frozen=True)
class SensorTruth:
    """One sensor's true noise: N, K, the bias-instability design level B with its
    Gauss-Markov components (time constants s, common sigma), the LSB, and N with the
    quantisation's white noise added (what an Allan deviation sees)."""

    noise_density: float
    random_walk: float
    bias_instability: float
    gm_time_constants_s: tuple[float, ...]
    gm_sigma: float
    lsb: float
    noise_density_with_quantisation: float


def crossing_tau(n: float, k: float) -> float:
    """The tau where white noise and random walk have equal Allan variance: sqrt(3) N / K."""
    return math.sqrt(3.0) * n / k


def gm_allan_variance(tau: np.ndarray, sigma: float, T: float) -> np.ndarray:
    """Allan variance of a stationary first-order Gauss-Markov process (variance sigma^2,
    time constant T): sigma^2 T^2 / tau^2 (2a - 3 + 4 e^-a - e^-2a), a = tau / T."""
    a = np.asarray(tau, float) / T
    bracket = np.where(a < 1e-3, (2.0 / 3.0) * a ** 3, 2 * a - 3 + 4 * np.exp(-a) - np.exp(-2 * a))
    return sigma ** 2 * T ** 2 / np.asarray(tau, float) ** 2 * bracket


def gm_time_constants(rate_hz: float, duration_s: float) -> tuple[float, ...]:
    """2 / rate_hz, x GM_SPREAD, ... up to the recording's length."""
    n = int(math.floor(math.log(duration_s * rate_hz / 2.0) / math.log(GM_SPREAD))) + 1
    return tuple(2.0 / rate_hz * GM_SPREAD ** i for i in range(max(n, 1)))


def sensor_truth(n: float, k: float, rate_hz: float, lsb: float, duration_s: float,
                 b: float | None = None) -> SensorTruth:
    if b is None:
        b = math.sqrt(2.0 * n * k / math.sqrt(3.0)) / math.sqrt(FLAT)
    Ts = gm_time_constants(rate_hz, duration_s)
    tau = np.geomspace(1.0 / rate_hz, duration_s / 10.0, 200)
    level = float(np.median(sum(gm_allan_variance(tau, 1.0, T) for T in Ts)))
    sigma = math.sqrt(FLAT * b ** 2 / level)
    nq = math.sqrt(n ** 2 + lsb ** 2 / (12.0 * rate_hz))
    return SensorTruth(n, k, b, Ts, sigma, lsb, nq)


def allan_variance(tau: np.ndarray, s: SensorTruth) -> np.ndarray:
    """The exact Allan variance of the simulated axis (quantisation as white noise)."""
    tau = np.asarray(tau, float)
    gm = sum(gm_allan_variance(tau, s.gm_sigma, T) for T in s.gm_time_constants_s)
    return s.noise_density_with_quantisation ** 2 / tau + s.random_walk ** 2 * tau / 3.0 + gm


def simulate_axis(n_samples: int, rate_hz: float, s: SensorTruth, offset: float, rng: np.random.Generator
                  ) -> np.ndarray:
    """One axis (n_samples,): offset + white + random walk + Gauss-Markov sum, quantised."""
    dt = 1.0 / rate_hz
    x = s.noise_density / math.sqrt(dt) * rng.standard_normal(n_samples)
    x += np.cumsum(s.random_walk * math.sqrt(dt) * rng.standard_normal(n_samples))
    for T in s.gm_time_constants_s:
        phi = math.exp(-dt / T)
        start = s.gm_sigma * rng.standard_normal()
        gm, _ = lfilter([s.gm_sigma * math.sqrt(1.0 - phi * phi)], [1.0, -phi], rng.standard_normal(n_samples),
                        zi=[phi * start])
        x += gm
    x += offset
    return np.round(x / s.lsb) * s.lsb


def imu_truth(imu: Imu, duration_s: float, bias_instability: dict[str, float] | None = None
              ) -> dict[str, SensorTruth]:
    b = bias_instability or {}
    return {"gyroscope": sensor_truth(imu.gyroscope_noise_density, imu.gyroscope_random_walk, imu.update_rate,
                                      LSB["gyroscope"], duration_s, b.get("gyroscope")),
            "accelerometer": sensor_truth(imu.accelerometer_noise_density, imu.accelerometer_random_walk,
                                          imu.update_rate, LSB["accelerometer"], duration_s, b.get("accelerometer"))}


def simulate_imu(imu: Imu, duration_s: float, rng: np.random.Generator,
                 truth: dict[str, SensorTruth]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_ns (N,), gyro (N, 3), accel (N, 3)) of a still, level IMU."""
    n = int(round(duration_s * imu.update_rate))
    t_ns = EPOCH_NS + np.round(np.arange(n) * (1e9 / imu.update_rate)).astype(np.int64)
    g_imu = imu.T_body_imu[:3, :3].T @ np.array([0.0, 0.0, GRAVITY])  # specific force at rest, IMU axes
    gyro_bias = rng.normal(0.0, 0.01, 3)  # rad/s, turn-on
    accel_bias = rng.normal(0.0, 0.05, 3)  # m/s^2, turn-on
    gyro = np.empty((n, 3))
    accel = np.empty((n, 3))
    for k in range(3):
        gyro[:, k] = simulate_axis(n, imu.update_rate, truth["gyroscope"], gyro_bias[k], rng)
        accel[:, k] = simulate_axis(n, imu.update_rate, truth["accelerometer"], g_imu[k] + accel_bias[k], rng)
    return t_ns, gyro, accel


def write_imu_csv(path: Path, t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
    """The IMU csv (docs/formats.md#imu-data), written in chunks: integer ns, then 10 significant digits (far below
    any sensor's resolution)."""
    fmt = "%d," + ",".join(["%.10g"] * 6)
    with open(path, "w", encoding="utf-8") as f:
        f.write(IMU_HEADER + "\n")
        for s in range(0, len(t_ns), CHUNK):
            rows = zip(t_ns[s:s + CHUNK].tolist(), *gyro[s:s + CHUNK].T.tolist(), *accel[s:s + CHUNK].T.tolist())
            f.write("\n".join([fmt % r for r in rows]))
            f.write("\n")


def truth_doc(truth: dict[str, dict[str, SensorTruth]], duration_s: float, seed: int) -> dict:
    imus = {}
    for name, sensors in truth.items():
        imus[name] = {}
        for sensor, s in sensors.items():
            d = asdict(s)
            d["gm_time_constants_s"] = list(d["gm_time_constants_s"])
            imus[name][sensor] = {k: (float(v) if not isinstance(v, list) else [float(x) for x in v])
                                  for k, v in d.items()}
    return {"scene": "static", "duration_s": float(duration_s), "seed": int(seed), "gravity": GRAVITY,
            "imus": imus}


def simulate_static(rig_path: str | Path, out_dir: str | Path, duration_s: float = DEFAULT_DURATION_S,
                    seed: int = 0, force: bool = False) -> str:
    """Write DIR/rig.yaml, DIR/imu/<imu>.csv per IMU of the rig and DIR/truth.yaml; returns the summary."""
    t0 = time.perf_counter()
    rig_path = Path(rig_path)
    rig = load_rig(rig_path)
    if not rig.imus:
        raise InputError(f"{rig_path}: imus: the rig declares no IMU; --scene static simulates the rig's IMUs")
    if not (duration_s > 0 and math.isfinite(duration_s)):
        raise InputError(f"--duration {duration_s}: expected a positive number of seconds")
    truth = {imu.name: imu_truth(imu, duration_s) for imu in rig.imus}
    lines = []
    with atomic_dir(out_dir, force=force) as tmp:
        (tmp / "imu").mkdir()
        (tmp / "rig.yaml").write_text(rig_path.read_text(encoding="utf-8"), encoding="utf-8")
        for i, imu in enumerate(rig.imus):
            rng = np.random.default_rng([seed, 5, i])
            t_ns, gyro, accel = simulate_imu(imu, duration_s, rng, truth[imu.name])
            write_imu_csv(tmp / "imu" / f"{imu.name}.csv", t_ns, gyro, accel)
            lines.append(f"  {imu.name}: {len(t_ns)} samples at {imu.update_rate:g} Hz; bias instability gyroscope "
                         f"{truth[imu.name]['gyroscope'].bias_instability:.3g} rad/s, accelerometer "
                         f"{truth[imu.name]['accelerometer'].bias_instability:.3g} m/s^2")
        (tmp / "truth.yaml").write_text(yaml.safe_dump(truth_doc(truth, duration_s, seed), sort_keys=False),
                                        encoding="utf-8")
    return "\n".join([f"wrote {out_dir}: static scene, {duration_s:g} s, {len(rig.imus)} IMU(s), "
                      f"{time.perf_counter() - t0:.1f} s"] + lines)
