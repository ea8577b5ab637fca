"""`--intrinsics`: tied and held intrinsics in the bundle adjustment (solve.Intrinsics.basis),
their covariance, the per-camera choice (model_selection.select_structure), the calibrated YAML's
`calibration.intrinsics_model` and the warning for intrinsics the data leave open."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import rigcal
from rigcal.core import geometry as geo
from rigcal.results.outputs import calibrated_rig, intrinsics_warnings
from rigcal.cli import app
from rigcal.results.compare import compare_rigs
from rigcal.camcal.pipeline import calibrate_views
from rigcal.camcal.model_selection import INTRINSICS_LEVEL, structure_tests
from rigcal.errors import InputError
from rigcal.core.rig import dump_rig, load_rig
from rigcal.camcal.solve import (Intrinsics, Observations, Problem, State, bundle_adjust, camera_covariance,
                                 intrinsics_covariance)
from rigcal.sim.synthetic import grid_corners, room_scene, with_noise

from tests.support.synthetic_obs import central_jacobian

DIST = (-0.03, 0.01, 2e-4, -1e-4)


@pytest.fixture(scope="module")
def drone():
    return rigcal.load_rig("rigs/drone-stereo-back.yaml")


def _truth(rig, fy_ratio: float = 1.0, dpp=(0.0, 0.0)):
    """The declared rig with a radtan4 lens, fy = fx * fy_ratio and the principal point
    moved by dpp px from the declared one."""
    cams = []
    for c in rig.cameras:
        m = c.intrinsics
        cams.append(replace(c, intrinsics=m.with_(fy=m.fx * fy_ratio, cx=m.cx + dpp[0], cy=m.cy + dpp[1], dist=DIST)))
    return rig.with_cameras(cams)


def _calibrate(rig, truth, seed, mode="auto", n_frames=20, sigma=0.1):
    rng = np.random.default_rng(seed)
    sc = room_scene(truth, rng, n_frames=n_frames)
    return calibrate_views(with_noise(sc.views, sigma, rng), rig, sc.corners, distortion="radtan4", intrinsics=mode)


# ----------------------------------------------------------------------------- parameterisation


def test_basis_round_trip_and_sizes():
    v = np.array([300.0, 302.0, 321.0, 239.0, -0.03, 0.01, 2e-4, -1e-4])
    for tie, hold, n in ((False, False, 8), (True, False, 7), (False, True, 6), (True, True, 5)):
        it = Intrinsics("pinhole", v.copy(), tie, hold)
        assert it.basis().shape == (8, n)
        x = it.params()
        back = it.with_params(x).values
        assert back[0] == pytest.approx(301.0 if tie else 300.0)
        assert back[1] == pytest.approx(301.0 if tie else 302.0)
        np.testing.assert_allclose(back[2:4], [321.0, 239.0])  # free or held, the same values here
        np.testing.assert_allclose(back[4:], v[4:])
    held = Intrinsics("pinhole", v.copy(), False, True).with_params(np.arange(6.0))
    np.testing.assert_allclose(held.values[2:4], [321.0, 239.0])  # held values never move
    np.testing.assert_allclose(held.values[[0, 1, 4, 5, 6, 7]], np.arange(6.0))


def _small_problem(drone, tie_hold):
    rng = np.random.default_rng(5)
    truth = _truth(drone, 1.0, (2.0, -1.0))
    sc = room_scene(truth, rng, n_frames=6)
    views, corners = with_noise(sc.views, 0.1, rng), sc.corners
    names, boards = list(truth.names), list(corners)
    frames = sorted({v.frame for v in views})
    obs = Observations(np.concatenate([np.full(len(v.ids), names.index(v.camera)) for v in views]),
                       np.concatenate([np.full(len(v.ids), frames.index(v.frame)) for v in views]),
                       np.concatenate([np.full(len(v.ids), boards.index(v.board)) for v in views]),
                       np.concatenate([corners[v.board][v.ids] for v in views]), np.concatenate([v.uv for v in views]),
                       np.zeros(sum(len(v.ids) for v in views), int))
    intr = [Intrinsics("pinhole", np.concatenate([[c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy],
                                                   c.intrinsics.dist]), *tie_hold[k])
            for k, c in enumerate(truth.cameras)]
    state = State(intr, np.array([geo.inv_T(c.T_body_cam) for c in truth.cameras]),
                  np.array([geo.inv_T(sc.T_world_body[f]) for f in frames]),
                  np.array([sc.T_world_board[b] for b in boards]))
    return obs, state


def test_masked_jacobian_matches_central_differences(drone):
    """A tied focal's column is d/d f of both fx and fy; held cx, cy have no column."""
    obs, state = _small_problem(drone, [(True, False), (False, True), (True, True)])
    pb = Problem(obs, state, gauge_cam=0, gauge_board=0)
    assert pb.layout.intr[0].stop - pb.layout.intr[0].start == 7
    assert pb.layout.intr[1].stop - pb.layout.intr[1].start == 6
    assert pb.layout.intr[2].stop - pb.layout.intr[2].start == 5
    rng = np.random.default_rng(1)
    x = pb.x0() + rng.normal(0, 1e-3, pb.layout.size)
    J = pb.jacobian(x).toarray()
    Jn = central_jacobian(pb.residuals, x)
    scale = np.abs(Jn).max(axis=0) + 1e-9
    assert np.max(np.abs(J - Jn) / scale) < 1e-5
    st = pb.state(x)
    assert st.intrinsics[0].values[0] == st.intrinsics[0].values[1]  # tied stays tied
    np.testing.assert_array_equal(st.intrinsics[1].values[2:4], state.intrinsics[1].values[2:4])  # held stays held


def test_masked_covariance_equals_the_reduced_problem_dense_reference():
    """One camera, fx = fy and cx, cy held, six board views: rigcal's covariance (Schur
    complement over the views, mapped back by E C E^T) against sigma^2 (J^T J)^-1 of an
    independently written reduced problem (cv2.projectPoints, Rodrigues poses, central
    differences, dense inverse)."""
    rng = np.random.default_rng(11)
    P = grid_corners(8, 6, 0.04)
    P = P - P.mean(0)
    K = np.array([[600.0, 0, 321.0], [0, 600.0, 238.0], [0, 0, 1]])
    dist = np.array(DIST)
    obj, img, poses = [], [], []
    for _ in range(6):
        rv = rng.normal(0, 0.35, 3)
        t = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.5, 0.8)])
        uv = cv2.projectPoints(P, rv, t, K, dist)[0].reshape(-1, 2) + rng.normal(0, 0.1, (len(P), 2))
        obj.append(P)
        img.append(uv)
        poses.append((rv, t))
    n = len(P)
    obs = Observations(np.zeros(6 * n, int), np.repeat(np.arange(6), n), np.zeros(6 * n, int), np.vstack(obj),
                       np.vstack(img), np.repeat(np.arange(6), n))
    it = Intrinsics("pinhole", np.array([590.0, 590.0, 321.0, 238.0, 0, 0, 0, 0]), tie_focal=True, hold_centre=True)
    T_bw = np.array([geo.make_T(cv2.Rodrigues(rv)[0], t) for rv, t in poses])
    res = bundle_adjust(obs, State([it], np.eye(4)[None], T_bw, np.eye(4)[None]), 0, 0)
    assert res.inliers.all()
    cov, intr_sl, _ = camera_covariance(res)
    full = intrinsics_covariance(cov, intr_sl, res.state.intrinsics)[0]

    sol = res.state.intrinsics[0].values

    def residuals(theta):  # theta: f, k1 k2 p1 p2, then (rotvec, t) per view
        Kt = np.array([[theta[0], 0, sol[2]], [0, theta[0], sol[3]], [0, 0, 1]])
        out = []
        for k in range(6):
            p = theta[5 + 6 * k:11 + 6 * k]
            out.append(cv2.projectPoints(P, p[:3], p[3:], Kt, theta[1:5])[0].reshape(-1, 2) - img[k])
        return np.concatenate(out).ravel()

    theta = np.concatenate([[sol[0]], sol[4:]] + [np.concatenate([cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3]])
                                                 for T in res.state.T_body_world])
    J = central_jacobian(residuals, theta)
    ref = res.sigma_px ** 2 * np.linalg.inv(J.T @ J)[:5, :5]
    mine = full[np.ix_([0, 4, 5, 6, 7], [0, 4, 5, 6, 7])]
    np.testing.assert_allclose(mine, ref, rtol=2e-3, atol=1e-3 * np.sqrt(np.outer(np.diag(ref), np.diag(ref))).max())
    assert full[1, 1] == pytest.approx(full[0, 0]) and full[0, 1] == pytest.approx(full[0, 0])  # fy is fx
    assert np.all(full[2:4, :] == 0) and np.all(full[:, 2:4] == 0)  # held: no variance, no correlation


# ----------------------------------------------------------------------------- selection


def test_wald_screen_thresholds_are_the_chi2_quantiles():
    from scipy.stats import chi2

    need1, need2 = chi2.ppf(1 - INTRINSICS_LEVEL, 1), chi2.ppf(1 - INTRINSICS_LEVEL, 2)
    cov = np.diag([1.0, 1.0, 4.0, 4.0, 1e-6])
    # fx - fy = d with var(fx - fy) = 2: Wald d^2 / 2
    d_edge = np.sqrt(2 * need1)
    for d, tie in ((0.99 * d_edge, True), (1.01 * d_edge, False)):
        tied, _, _ = structure_tests(Intrinsics("pinhole", np.array([300 + d, 300, 320, 240, 0.0])), cov, (320, 240))
        assert tied is tie
    # offset (a, 0) with var 4: Wald a^2 / 4
    a_edge = np.sqrt(4 * need2)
    for a, hold in ((0.99 * a_edge, True), (1.01 * a_edge, False)):
        _, held, _ = structure_tests(Intrinsics("pinhole", np.array([300, 300, 320 + a, 240, 0.0])), cov, (320, 240))
        assert held is hold


def test_auto_ties_and_holds_when_the_truth_is_square_and_centred(drone):
    cal = _calibrate(drone, _truth(drone), 3)
    for n in cal.cam_names:
        m, st = cal.rig.camera(n).intrinsics, cal.stats[n]
        assert st.intrinsics_model == {"focal": "fx=fy", "principal_point": "held", "distortion": "radtan4"}, \
            (n, st.model_selection)
        assert m.fx == m.fy
        d = drone.camera(n).intrinsics
        assert (m.cx, m.cy) == (d.cx, d.cy)
        sig = st.sigma_intrinsics
        assert sig["cx"] == 0.0 and sig["fy"] == pytest.approx(sig["fx"])
        assert abs(m.fx / d.fx - 1) < 5 * st.sigma_intrinsics["fx"] / d.fx  # the tied focal is right


def test_auto_frees_what_the_truth_has(drone):
    """fy 0.4 % above fx and the principal point (4, -3) px off the declared one, 0.1 px
    noise: both far beyond the threshold, so both estimated, within 5 sigma of the truth."""
    truth = _truth(drone, 1.004, (4.0, -3.0))
    cal = _calibrate(drone, truth, 4)
    for n in cal.cam_names:
        st, m, t = cal.stats[n], cal.rig.camera(n).intrinsics, truth.camera(n).intrinsics
        assert st.intrinsics_model["focal"] == "fx,fy" and st.intrinsics_model["principal_point"] == "free", \
            (n, st.model_selection)
        sig = st.sigma_intrinsics
        for k in ("fx", "fy", "cx", "cy"):
            assert abs(getattr(m, k) - getattr(t, k)) < 5 * sig[k], (n, k, getattr(m, k), getattr(t, k), sig[k])


def test_forced_structure_and_free(drone):
    truth = _truth(drone, 1.004, (4.0, -3.0))
    forced = _calibrate(drone, truth, 4, mode="square-centred", n_frames=8)
    free = _calibrate(drone, _truth(drone), 3, mode="free", n_frames=8)
    for n in forced.cam_names:
        m, d = forced.rig.camera(n).intrinsics, drone.camera(n).intrinsics
        assert m.fx == m.fy and (m.cx, m.cy) == (d.cx, d.cy)
        assert forced.stats[n].model_selection == [] or not any("Wald" in x and "fx - fy" in x
                                                                for x in forced.stats[n].model_selection)
        assert free.stats[n].intrinsics_model["focal"] == "fx,fy"
        assert free.stats[n].intrinsics_model["principal_point"] == "free"
    with pytest.raises(InputError, match="--intrinsics"):
        _calibrate(drone, truth, 4, mode="round", n_frames=4)


# ----------------------------------------------------------------------------- outputs


def test_yaml_carries_the_structure_and_reads_back(drone, tmp_path):
    truth = _truth(drone, 1.004, (4.0, -3.0))
    rng = np.random.default_rng(6)
    sc = room_scene(truth, rng, n_frames=10)
    cal = calibrate_views(with_noise(sc.views, 0.1, rng), drone, sc.corners, distortion="radtan4",
                          intrinsics="square")
    path = tmp_path / "cal.yaml"
    path.write_text(dump_rig(calibrated_rig(cal, {}, dataset="synthetic")))
    back = load_rig(path)
    for c in back.cameras:
        assert c.calibration["intrinsics_model"] == {"focal": "fx=fy", "principal_point": "free",
                                                     "distortion": "radtan4"}
    assert set(compare_rigs(back, truth)["cameras"]) == set(drone.names)  # compare reads it
    truth_path = tmp_path / "truth_rig.yaml"
    truth_path.write_text(dump_rig(truth))
    r = CliRunner().invoke(app, ["compare", str(path), str(truth_path)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["export", str(path), "--format", "json", "--out", str(tmp_path / "cal.json")])
    assert r.exit_code == 0, r.output


def test_poorly_determined_warning_fires_on_a_weak_set_only(drone):
    """Good: 20 frames of the room at 0.1 px. Weak: one camera's 4 frames at 1 px, boards
    only near the image centre: its principal point cannot be placed, and the warning names
    it, its sigma and the empty parts of the image."""
    good = _calibrate(drone, _truth(drone, 1.004, (4.0, -3.0)), 7)
    assert not any(intrinsics_warnings(good, c, n) for c, n in enumerate(good.cam_names))

    rng = np.random.default_rng(8)
    truth = _truth(drone, 1.0, (6.0, -5.0))
    sc = room_scene(truth, rng, n_frames=30)
    d = drone.camera("back").intrinsics
    centre = np.array([d.cx, d.cy])

    def central(v):
        keep = np.all(np.abs(v.uv - centre) < [d.width / 6.5, d.height / 6.5], axis=1)  # the middle ninth
        return replace(v, ids=v.ids[keep], uv=v.uv[keep])

    views = [central(v) if v.camera == "back" else v for v in sc.views]
    views = [v for v in views if len(v.ids) >= 8]
    back = [v for v in views if v.camera == "back"]
    keep_frames = {v.frame for v in back[:4]}
    views = [v for v in views if v.camera != "back" or v.frame in keep_frames]
    weak = calibrate_views(with_noise(views, 1.0, rng), drone, sc.corners, distortion="radtan4")
    c = weak.cam_names.index("back")
    lines = intrinsics_warnings(weak, c, "back")
    pp = [x for x in lines if x.startswith("back: principal point is poorly constrained")]
    assert len(pp) == 1 and "1-sigma" in pp[0], lines
    assert "none seen in" in pp[0] and "top left" in pp[0], lines
    assert not any(intrinsics_warnings(weak, weak.cam_names.index(n), n) for n in ("front_left", "front_right"))


def test_cli_offers_the_structures_and_refuses_others(tmp_path):
    r = CliRunner().invoke(app, ["calibrate", "--help"])
    assert r.exit_code == 0 and "--intrinsics" in r.output
    r = CliRunner().invoke(app, ["calibrate", str(tmp_path), "--out", str(tmp_path / "o.yaml"), "--intrinsics", "round"])
    assert r.exit_code == 2 and not (tmp_path / "o.yaml").exists()
