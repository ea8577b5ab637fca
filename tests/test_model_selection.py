"""`--distortion auto`: which pinhole model the joint solve keeps (core.keep_k3,
core.select_rational) on synthetic corners whose true distortion is known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

import rigcal
from rigcal.core import K3_LEVEL, calibrate_views, keep_k3
from rigcal.synthetic import room_scene, with_noise


@pytest.fixture(scope="module")
def drone():
    return rigcal.load_rig("rigs/drone-stereo-back.yaml")


def _with_dist(rig, dist):
    return rig.with_cameras([replace(c, intrinsics=c.intrinsics.with_(dist=tuple(dist))) for c in rig.cameras])


def _auto(rig, truth, seed, n_frames=20, sigma=0.1):
    rng = np.random.default_rng(seed)
    sc = room_scene(truth, rng, n_frames=n_frames)
    return calibrate_views(with_noise(sc.views, sigma, rng), rig, sc.corners, distortion="auto")


def test_keep_k3_threshold_is_the_chi2_quantile():
    need = chi2.ppf(1 - K3_LEVEL, 1)
    assert 15.0 < need < 15.3
    assert keep_k3(0.01, (0.01 / np.sqrt(need)) ** 2 * 0.99)[0]  # just beyond the threshold
    assert not keep_k3(0.01, (0.01 / np.sqrt(need)) ** 2 * 1.01)[0]
    assert keep_k3(-0.02, 1e-6)[0]  # the sign does not matter
    kept, line = keep_k3(0.0, 1e-6)
    assert not kept and "dropped" in line


def test_auto_keeps_decentering_and_drops_an_absent_k3(drone):
    """Truth: radial plus decentering, k3 = 0. auto must estimate p1, p2 (radtan4 is the
    floor) and not invent k3; the fitted decentering must match the truth within 4 of
    its reported sigmas."""
    truth = _with_dist(drone, (-0.03, 0.01, 3e-4, -2e-4, 0.0))
    cal = _auto(drone, truth, 1)
    for n in cal.cam_names:
        assert cal.stats[n].distortion_model == "radtan4", (n, cal.stats[n].model_selection)
        assert any("k3" in line and "dropped" in line for line in cal.stats[n].model_selection)
        p = np.array(cal.rig.camera(n).intrinsics.dist[2:4])
        sd = np.array(cal.stats[n].sigma_intrinsics["distortion"][2:4])
        assert np.all(np.abs(p - [3e-4, -2e-4]) < 4 * sd), (n, p, sd)


def test_auto_keeps_a_strong_k3(drone):
    """Truth with a k3 that bends the image corners by several pixels: kept, and within 4
    of its reported sigmas."""
    truth = _with_dist(drone, (-0.05, 0.02, 1e-4, 1e-4, 0.05))
    cal = _auto(drone, truth, 2)
    for n in cal.cam_names:
        assert cal.stats[n].distortion_model == "radtan5", (n, cal.stats[n].model_selection)
        k3 = cal.rig.camera(n).intrinsics.dist[4]
        assert abs(k3 - 0.05) < 4 * cal.stats[n].sigma_intrinsics["distortion"][4], (n, k3)


def test_auto_k3_tested_in_the_joint_solve_not_per_camera(drone):
    """The log says where each decision was made, so a user can see why."""
    truth = _with_dist(drone, (-0.03, 0.01, 0.0, 0.0, 0.0))
    cal = _auto(drone, truth, 3, n_frames=12)
    for n in cal.cam_names:
        log = cal.stats[n].model_selection
        assert any(line.startswith("joint solve: k3") for line in log), log
        assert any("rational8" in line and "rejected" in line for line in log), log
