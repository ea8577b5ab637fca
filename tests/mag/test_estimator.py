"""The joint estimator's analytic Jacobian against central finite differences of its
residuals, at a point away from the solution (biases, rotations, soft iron and the clock
offset all non-trivial), and its solver against scipy's least_squares."""

from __future__ import annotations

import numpy as np

from rigcal.core import geometry as geo
from rigcal.mag import estimator as est
from rigcal.mag.attitude import integrate_windows
from rigcal.sim import mag_scene


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    traj = mag_scene.dance_trajectory(np.random.default_rng(3))
    t = np.arange(0.0, 6.0, 0.005)
    motion = traj.at(t)
    tm = np.arange(0.003, 5.9, 0.01)
    inp = est.MagInput(t, motion.omega_body + 0.01, np.ones((len(t), 3)), tm, rng.normal(size=(len(tm), 3)) * 30,
                       np.eye(3), np.eye(3), 0.5, estimate_offset=True)
    bias = np.array([0.001, 0.002, -0.001])
    ia = np.arange(0, len(t) - 1, 4)
    wm = integrate_windows(t, inp.gyro, tm, 2.0, bias)
    wa = integrate_windows(t, inp.gyro, t[ia], 2.0, bias)
    K = wm.n
    p = est._Problem(inp, wm, wa, inp.accel[ia], 50.0, geo.R_from_rotvec(np.array([0.3, -0.2, 0.1])),
                     geo.R_from_rotvec(rng.normal(size=(K, 3))), 0.3, traj.at(tm).omega_body)
    x = np.concatenate([[3, -2, 1], [1.05, 0.97, 1.0, 0.02, -0.01, 0.03], [0, 0, 0], [1.0], [0.002, -0.001, 0.003],
                        [0.1, 0.2, -0.1], [0.004], np.zeros(3 * K)])
    J = est._jacobian(x, p).toarray()
    Jn = np.empty_like(J)
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = 1e-6
        Jn[:, i] = (est._residuals(x + d, p) - est._residuals(x - d, p)) / 2e-6
    scale = np.maximum(np.abs(Jn).max(axis=0), 1e-12)
    assert (np.abs(J - Jn).max(axis=0) / scale).max() < 1e-4


def test_schur_levenberg_marquardt_agrees_with_scipy_least_squares(tmp_path):
    from rigcal.core.rig import load_rig
    from rigcal.data.imu_csv import read_imu_csv
    from rigcal.data.mag_csv import read_mag_csv
    from rigcal.mag.step import mag_input

    from tests.support.mag_data import mag_dataset

    sim = mag_dataset(tmp_path / "d", seed=1, duration=20.0)
    rig = load_rig(sim.out_dir / "rig.yaml")
    inp = mag_input(rig, rig.magnetometers[0], read_mag_csv(sim.out_dir / "mag" / "mag0.csv"),
                    read_imu_csv(sim.out_dir / "imu" / "imu0.csv"), np.eye(3))
    fast = est.estimate(inp)
    slow = est.estimate(inp, solve=est.least_squares_solve)
    # the same optimum, to a hundredth of a sigma
    assert (np.abs(fast.hard_iron - slow.hard_iron) < 0.01 * fast.sigma_hard_iron).all()
    assert (np.abs(fast.soft_iron - slow.soft_iron) < 0.01 * fast.sigma_soft_iron).all()
    assert geo.rotation_angle_deg(fast.R_body_mag @ slow.R_body_mag.T) < 0.01 * fast.sigma_rotation_deg.min()
    assert abs(fast.inclination_deg - slow.inclination_deg) < 0.01 * fast.sigma_inclination_deg
    np.testing.assert_allclose(fast.sigma_hard_iron, slow.sigma_hard_iron, rtol=1e-3)
