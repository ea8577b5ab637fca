"""`rigcal simulate --scene static` (rigcal.sim.static_imu): the Gauss-Markov Allan variance
against its limits, the simulated axis against the model's exact Allan variance, the
dataset it writes, and the round trip through `rigcal imu-noise`."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.imunoise.allan import allan_deviation, edf
from rigcal.imunoise.recording import read_imu_file
from rigcal.sim.static_imu import FLAT, allan_variance, gm_allan_variance, sensor_truth, simulate_axis

RIG = """\
rig: static
body_frame: FLU
imus:
  imu0:
    position: [0.0, 0.0, 0.0]
    axes: [F, L, U]
    update_rate: 100.0
    gyroscope_noise_density: 1.0e-3
    gyroscope_random_walk: 1.0e-3
    accelerometer_noise_density: 2.0e-3
    accelerometer_random_walk: 2.0e-3
cameras:
  cam0:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0}
    distortion: [0.0, 0.0, 0.0, 0.0]
    position: [0.1, 0.0, 0.0]
    axes: [-L, -U, F]
"""


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_gauss_markov_allan_variance_limits():
    sigma, T = 0.3, 2.0
    small, large = np.array([1e-3]), np.array([1e4])
    assert gm_allan_variance(small, sigma, T)[0] == pytest.approx(2 * sigma ** 2 * small[0] / (3 * T), rel=1e-3)
    assert gm_allan_variance(large, sigma, T)[0] == pytest.approx(2 * sigma ** 2 * T / large[0], rel=1e-3)


def test_flicker_is_flat_at_the_bias_instability():
    s = sensor_truth(1e-3, 1e-4, 200.0, 1e-6, 3600.0, b=5e-4)
    tau = np.geomspace(30 / 200.0, 360.0, 40)
    gm = sum(gm_allan_variance(tau, s.gm_sigma, T) for T in s.gm_time_constants_s)
    assert np.all(np.abs(np.sqrt(gm / FLAT) / 5e-4 - 1) < 0.05)


def test_simulated_axis_matches_the_exact_allan_variance():
    s = sensor_truth(1e-3, 1e-3, 100.0, 4e-3, 1200.0)
    x = simulate_axis(120_000, 100.0, s, 9.8, np.random.default_rng(3))
    c = allan_deviation(x, 100.0)
    nu = edf(0, c.m, c.n)  # white-noise edf: the smallest, so the bound is loose at the long taus
    z = (c.adev / np.sqrt(allan_variance(c.tau, s)) - 1) * np.sqrt(2 * np.minimum(nu, 50.0))
    assert np.all(np.abs(z) < 4), z
    assert np.all(np.abs(x - np.round(x / 4e-3) * 4e-3) < 1e-12)  # quantised to the LSB


def test_static_scene_writes_a_dataset_that_imu_noise_reads_back(tmp_path):
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG)
    ds = tmp_path / "ds"
    r = run("simulate", rig, "--scene", "static", "--out", ds, "--duration", 1200, "--seed", 4)
    assert r.exit_code == 0, r.stderr
    rec = read_imu_file(ds / "imu" / "imu0.csv")
    assert len(rec.t_ns) == 120_000 and np.all(np.diff(rec.t_ns) == 10_000_000)
    assert np.median(rec.accel[:, 2]) == pytest.approx(9.80665, abs=0.3)  # level, z up
    truth = yaml.safe_load((ds / "truth.yaml").read_text())["imus"]["imu0"]
    out = tmp_path / "imu.yaml"
    r = run("imu-noise", ds, "--out", out)
    assert r.exit_code == 0, r.stderr
    got = yaml.safe_load(out.read_text())
    for sensor in ("gyroscope", "accelerometer"):
        t = truth[sensor]
        assert got[f"{sensor}_noise_density"] == pytest.approx(t["noise_density_with_quantisation"], rel=0.03)
        assert got[f"{sensor}_random_walk"] == pytest.approx(t["random_walk"], rel=0.4)


def test_static_scene_bad_input(tmp_path):
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG.split("imus:")[0] + "cameras:" + RIG.split("cameras:")[1])
    r = run("simulate", rig, "--scene", "static", "--out", tmp_path / "a")
    assert r.exit_code == 2 and "declares no IMU" in r.stderr and not (tmp_path / "a").exists()
    rig.write_text(RIG)
    r = run("simulate", rig, "--scene", "static", "--out", tmp_path / "b", "--frames", 3)
    assert r.exit_code == 2 and "--frames" in r.stderr and not (tmp_path / "b").exists()
