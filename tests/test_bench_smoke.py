"""The benchmark modules import, and one micro-scenario runs end to end through the same
code `make bench` uses (synthetic corners, no rendering; a few seconds). Timed numbers
are never asserted: tolerances are physical and loose."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

import rigcal
from rigcal.camcal.bounds import pair_bounds
from rigcal.sim.synthetic import room_scene, with_noise

BENCH = Path(__file__).resolve().parents[1] / "bench"
# checks run by hand, not benchmark sections (bench/__main__.py's docstring lists them)
CHECKS = ("same_outputs", "faults", "indie_corners")
MODULES = ("common", "accuracy", "noise_limit", "peer_opencv", "montecarlo", "scale", "speed", "real", "indie",
           "indie_noise", "simulate_imu", "imu_calib", "imu_coverage", "imu_euroc", "imu_freerun", "imu_speed",
           "indie_imu", "solver_libraries", "ingest", "aprilgrid_excess", "imu_noise", "imu_noise_real", "mag", "check",
           "dome", "long_recording", "intrinsics_holdout", "visual_freerun", "__main__") + CHECKS


@pytest.mark.parametrize("name", MODULES)
def test_bench_module_imports(name):
    mod = importlib.import_module(f"bench.{name}")
    assert mod.__doc__


def test_every_live_bench_module_is_a_section_a_check_or_shared():
    """bench/'s convention: a module in bench/ itself is a section of the one
    TABLE (running its module), a check named in CHECKS, or shared code; finished studies
    live in bench/archive/ with a line in its README."""
    from bench.__main__ import TABLE

    live = {p.stem for p in BENCH.glob("*.py")} - {"__init__", "__main__", "common"}
    in_table = set()
    for sec in TABLE:
        in_table |= {n for n in sec.run.__code__.co_names if n in live}
    assert live - in_table - set(CHECKS) == set(), "neither a TABLE section nor a check"
    assert set(MODULES) - {"common", "__main__"} == live
    readme = (BENCH / "archive" / "README.md").read_text(encoding="utf-8")
    for p in (BENCH / "archive").glob("*.py"):
        if p.stem != "__init__":
            assert f"`{p.stem}`" in readme, p.stem


@pytest.mark.slow
def test_scale_and_montecarlo_sections_run_small():
    from bench import montecarlo, scale

    r = scale.one(10)
    assert r["frames"] == 10 and r["max_pair_rot_err_deg"] < 0.1
    assert "Scale" in scale.tables([r])
    m = montecarlo.run(seeds=1, log=lambda *a: None)
    assert set(m["variants"]) and "Monte Carlo" in montecarlo.tables(m)


@pytest.fixture(scope="module")
def micro():
    from bench import common

    rig = rigcal.load_rig(common.RIGS / "stereo-forward.yaml")
    truth_rig = common.perturbed_truth(rig, 3)
    sc = room_scene(truth_rig, np.random.default_rng(4), n_frames=12)
    views = with_noise(sc.views, 0.05, np.random.default_rng(5))
    cal = common.calibrate(views, rig, sc.corners)
    return rig, truth_rig, sc, views, cal


def test_micro_scenario_calibrates_near_the_bound(micro):
    from bench import common, noise_limit

    rig, truth_rig, sc, views, cal = micro
    bounds = pair_bounds(cal, sc.truth, 0.05)
    est = common.rig_errors(cal.rig, truth_rig)["pairs"]["left/right"]
    declared = common.rig_errors(rig, truth_rig)["pairs"]["left/right"]
    b = bounds[("left", "right")]
    assert 0 < b["trans_mm"] < 1.0 and 0 < b["rot_deg"] < 0.1
    # one seed: a loose multiple of the bound, and far better than not calibrating
    assert est["trans_mm"] < 6 * b["trans_mm"] and est["rot_deg"] < 6 * b["rot_deg"]
    assert declared["trans_mm"] > 20 * est["trans_mm"]
    # the noise-limit pieces on the same calibration
    stats = noise_limit.pair_stats(cal, sc.truth, 0.05)
    assert stats["left/right"]["bound_trans_mm"] == pytest.approx(b["trans_mm"])
    cov = noise_limit._coverage_samples(cal, truth_rig)
    assert set(cov) == {"left", "right"} and all(np.all(np.isfinite(c["sigma"])) for c in cov.values())


def test_truth_reexpressed_does_not_depend_on_truths_body_frame(micro):
    """The true rig is compared in the frame fitted to the declared rig: moving the
    truth's own body frame rigidly must not change it (comparing raw truth.yaml poses would)."""
    from bench import common
    from rigcal.core import geometry as geo

    rig, truth_rig, sc, views, cal = micro
    T_shift = geo.make_T(geo.R_from_rotvec([0.3, -0.2, 0.5]), [0.4, -1.0, 0.25])
    moved = truth_rig.with_cameras([c.__class__(c.name, c.intrinsics, T_shift @ c.T_body_cam)
                                    for c in truth_rig.cameras])
    a, b = common.truth_in_output_frame(cal, truth_rig), common.truth_in_output_frame(cal, moved)
    for n in a:
        np.testing.assert_allclose(a[n], b[n], atol=1e-9)
    # and it is close to the declared rig (the mounting errors are a few mm / ~1 deg)
    for n in a:
        assert np.linalg.norm(a[n][:3, 3] - rig.camera(n).T_body_cam[:3, 3]) < 0.03


def test_gaussian_views_keep_the_corners(micro):
    from bench import common

    rig, truth_rig, sc, views, cal = micro
    uv_true = common.true_projections(cal, sc.truth)
    assert np.sqrt(np.mean((uv_true - cal.obs.uv) ** 2)) == pytest.approx(0.05, rel=0.2)
    g = common.gaussian_views(cal, uv_true, sc.corners, 0.0, np.random.default_rng(0))
    assert sum(len(v.ids) for v in g) == len(cal.obs)
    first = g[0]
    P = sc.corners[first.board][first.ids]
    m = cal.obs.view == cal.obs.view[0]
    np.testing.assert_allclose(P, cal.obs.p_board[m], atol=1e-12)


def test_opencv_peer_on_the_micro_scenario(micro):
    from bench import common, peer_opencv

    rig, truth_rig, sc, views, cal = micro
    cv = peer_opencv.run_multiview(views, rig, sc.corners)
    assert cv["ok"], cv.get("error")
    assert cv["frames_shared"] > 0 and 0 < cv["observations_used"] <= cv["observations_available"]
    e = common.rig_errors(cv["rig"], truth_rig)["pairs"]["left/right"]
    assert e["trans_mm"] < 2.0 and e["rot_deg"] < 0.2


def test_tables_render():
    from bench.common import md_table

    t = md_table(["a", "b"], [[1.23456, None], ["x", float("nan")]], "title")
    assert "| a " in t and "1.23" in t and "-" in t and "**title**" in t


def test_view_offsets_leave_out_the_corners_the_solve_rejected(micro):
    """A misdetection the calibration rejected never reached the estimate: it must not
    show up as a per-view offset (one corner 3 px off in a view of ~40 is ~0.05 px)."""
    from dataclasses import replace

    from bench import common, noise_limit

    rig, truth_rig, sc, views, cal = micro
    uv_true = common.true_projections(cal, sc.truth)
    base = noise_limit.view_offsets(cal, uv_true, 0.05)
    # white noise of 0.05 px: each view's mean is white too
    assert 0.5 < base["view_offset_rms_px"] / base["white_expectation_px"] < 2.0
    k = int(np.nonzero(cal.inliers)[0][0])
    uv = cal.obs.uv.copy()
    uv[k] += 3.0
    inliers = cal.inliers.copy()
    inliers[k] = False
    bad = noise_limit.view_offsets(replace(cal, obs=replace(cal.obs, uv=uv), inliers=inliers), uv_true, 0.05)
    assert bad["view_offset_rms_px"] == pytest.approx(base["view_offset_rms_px"], rel=0.3)
    assert bad["view_offset_rms_px"] < 2 * bad["white_expectation_px"]
    assert bad["rejected_corners"] == base["rejected_corners"] + 1


def test_rigcal_and_gtsam_solvers_reach_the_same_optimum():
    # bench.solver_libraries on a small problem: two independently written solvers (rigcal's
    # Schur LM, gtsam's factor graph with its own pose retraction) from the same start must
    # land on the same least-squares optimum: apart by under 1 % of the noise-limited error
    # (rigcal stops when a step gains < 0.01 in chi-square, gtsam at a relative 1e-8; seed 1
    # ends 1.6e-4 of the error apart, seed 2 2e-6).
    pytest.importorskip("gtsam", reason="gtsam is not installed (no wheel for this Python and numpy 2)")
    from bench import solver_libraries as sl

    (r,) = sl.run(frames=(10,), seed=1, log=lambda *_: None)
    err, apart = r["rigcal_err"], r["apart"]
    assert err["trans_mm"] > 0.1 and err["rot_deg"] > 0.01  # noisy data: a real error to be far below
    assert apart["rot_deg"] < 0.01 * err["rot_deg"] and apart["trans_mm"] < 0.01 * err["trans_mm"], (err, apart)
    assert apart["intr_px"] < 0.01, apart


def test_simulate_imu_section_runs_small(tmp_path, monkeypatch):
    from bench import simulate_imu

    monkeypatch.setattr(simulate_imu, "OUT", tmp_path)
    r = simulate_imu.run(duration=0.3, camera_rate=5.0, jobs=1)
    assert r["images"] == 3 and r["imu_samples"]["imu0"] == int(1.3 * 200) + 1
    assert (tmp_path / "simulate_imu.png").stat().st_size > 0 and (tmp_path / "simulate_imu.html").exists()
    assert "peak angular rate" in simulate_imu.tables(r)


def test_imu_calib_section_runs_small():
    from bench import imu_calib

    r = imu_calib.run(duration=3.0, seeds=1, rendered=0.0)
    x = r["results"][0]
    assert len(x["rot_err_deg"]) == 3 and max(x["rot_err_deg"]) < 0.2 and max(x["pos_err_m"]) < 0.01
    assert "offset err ms" in imu_calib.tables(r)


@pytest.mark.slow
def test_imu_calib_rendered_part_runs_small():
    from bench import imu_calib

    x = imu_calib.run_rendered(duration=2.5, camera_rate=10.0)
    assert x["corners"] > 1000 and max(x["rot_err_deg"]) < 0.2 and max(x["pos_err_m"]) < 0.01
    assert "rendered 2.5 s" in imu_calib.tables({"results": [], "rendered": x})


@pytest.mark.slow
def test_ingest_bench_runs_at_small_size():
    """bench.ingest end to end on 0.5 s of tiny images: both bags ingest every frame."""
    from bench import ingest

    r = ingest.run(seconds=0.5, scale=0.3, log=lambda *a: None)
    assert [x["kind"] for x in r["rows"]] == ["ros1", "mcap"]
    assert all(x["ok"] and x["images"] == 20 for x in r["rows"]), r["rows"]
    assert "ros1" in ingest.tables(r)


@pytest.mark.slow
def test_aprilgrid_excess_runs_on_one_small_render():
    """bench.aprilgrid_excess end to end on one fisheye-room frame (no EuRoC): every method
    measures the same corners, and the tables render."""
    from bench import aprilgrid_excess

    r = aprilgrid_excess.run(frames=1, cases=(("fisheye-stereo", "room"),), noises=(2.0,), with_euroc=False)
    (row,) = r["rendered"]
    assert row["n"] > 20
    for k in ("box", "detector", "long arms", "exact symmetric", "exact long arms", "charuco"):
        assert 0.0 < row[k] < 0.2, (k, row[k])
    assert "long arms" in aprilgrid_excess.tables(r)


@pytest.mark.slow
def test_dome_dataset_is_a_dataset_calibrate_reads(tmp_path):
    """bench.dome at a tiny size (12 cameras, 6 frames): the boards face out of the box and
    a camera behind a print sees nothing, the corners files read back as views inside the
    images, and `rigcal calibrate` on the folder recovers the true rig."""
    from typer.testing import CliRunner

    from bench import common, dome
    from rigcal.core import geometry as geo
    from rigcal.cli import app
    from rigcal.data.corners import read_corners
    from rigcal.core.target import load_target

    for T in dome.box_boards(np.zeros((1, 3))).values():
        assert T[:3, 2] @ T[:3, 3] < 0  # z into the print points back into the box
        assert not dome.printed_side(T)  # a camera at the box's centre (T_cam_board = T_box_board) is behind it
        assert dome.printed_side(geo.inv_T(geo.make_T(np.eye(3), [0.0, 0.0, -2.0])))  # 2 m out on the print's side
    d, truth = dome.make_dataset(6, n_cameras=12, root=tmp_path, log=lambda s: None)
    target = load_target(d / "target.yaml")
    assert len(list((d / "corners").glob("*.csv"))) == 12
    n_views = 0
    for cam in truth.cameras:
        for frame, board, ids, uv in read_corners(d / "corners" / f"{cam.name}.csv", target):
            n_views += 1
            assert len(ids) >= dome.MIN_CORNERS and np.all(np.diff(ids) > 0)
            assert np.all((uv >= 0) & (uv < [cam.intrinsics.width, cam.intrinsics.height]))
    assert n_views > 12 * 6  # most cameras see more than one face per frame
    out = tmp_path / "cal.yaml"
    r = CliRunner().invoke(app, ["calibrate", str(d), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 0, r.output
    # the corners are exact projections + 0.1 px noise: a convention slip (board frame, ids,
    # pixel origin) would leave residuals of pixels
    rms = float(re.search(r"reprojection RMS ([\d.]+) px", r.output).group(1))
    assert 0.05 < rms < 0.2
    # 6 frames of a narrow-angle dome pin the rig down loosely, but far better than declared
    e = common.rig_errors(rigcal.load_rig(out), truth)
    declared = common.rig_errors(rigcal.load_rig(d / "rig.yaml"), truth)
    for k in ("rot_deg", "trans_mm"):
        assert max(p[k] for p in e["pairs"].values()) < 0.5 * max(p[k] for p in declared["pairs"].values())


def test_same_outputs_compares_full_precision_at_1e9_and_printed_figures_to_their_last_digit(tmp_path):
    from bench.same_outputs import compare

    doc = {"cameras": {"a": {"intrinsics": {"fx": 300.123456789, "cx": 320.5}, "distortion": [0.1, 0.0],
                             "calibration": {"sigma": {"position_mm": [0.0081]}, "dataset": "x"}}}}
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "s.yaml").write_text(yaml.safe_dump(doc))
    cases = {"same": (lambda d: None, 0),
             "tiny": (lambda d: d["cameras"]["a"]["intrinsics"].update(fx=300.123456789 * (1 + 1e-12)), 0),
             "real": (lambda d: d["cameras"]["a"]["intrinsics"].update(fx=300.123456789 * (1 + 1e-8)), 1),
             "zero": (lambda d: d["cameras"]["a"]["distortion"].__setitem__(1, 1e-10), 1),
             "round": (lambda d: d["cameras"]["a"]["calibration"]["sigma"].update(position_mm=[0.0082]), 0),
             "stat": (lambda d: d["cameras"]["a"]["calibration"]["sigma"].update(position_mm=[0.0084]), 1),
             "path": (lambda d: d["cameras"]["a"]["calibration"].update(dataset="elsewhere"), 0),
             "key": (lambda d: d["cameras"]["a"].update(extra=1), 1)}
    for name, (edit, expected) in cases.items():
        new = yaml.safe_load(yaml.safe_dump(doc))
        edit(new)
        (tmp_path / name).mkdir()
        (tmp_path / name / "s.yaml").write_text(yaml.safe_dump(new))
        assert compare(tmp_path / "old", tmp_path / name) == expected, name


def test_holdout_scores_are_zero_for_the_truth_and_grow_with_a_wrong_rig():
    """bench.intrinsics_holdout's two scores on noise-free synthetic views: the true rig
    predicts held-out views exactly; turning one camera by 0.2 deg moves camera-to-camera
    predictions by about f x 0.2 deg, and a principal point off by 10 px shows in PnP."""
    from bench import common
    from bench.intrinsics_holdout import cross_errors, pnp_rms
    from rigcal.core import geometry as geo

    rig = rigcal.load_rig(common.RIGS / "stereo-forward.yaml")
    sc = room_scene(rig, np.random.default_rng(4), n_frames=8)
    left = [v for v in sc.views if v.camera == "left"]
    obj = [sc.corners[v.board][np.asarray(v.ids)] for v in left]
    img = [np.asarray(v.uv, float) for v in left]
    m = rig.camera("left").intrinsics
    assert pnp_rms(m, obj, img)[0] < 1e-6
    assert pnp_rms(m.with_(cx=m.cx + 10, dist=tuple(np.asarray(m.dist) + 0.05)), obj, img)[0] > 0.05
    exact = cross_errors(rig, sc.views, sc.corners)
    assert exact and max(e for e, _ in exact) < 1e-6
    right = rig.camera("right")
    turned = rig.with_cameras([c if c.name != "right" else
                               type(c)(c.name, c.intrinsics, c.T_body_cam @ geo.make_T(
                                   geo.R_from_rotvec(np.radians([0.2, 0, 0])), np.zeros(3)))
                               for c in rig.cameras])
    moved = np.median([e for e, _ in cross_errors(turned, sc.views, sc.corners)])
    expected = right.intrinsics.fy * np.radians(0.2)
    assert 0.7 * expected < moved < 1.3 * expected


def test_imu_speed_reads_the_console_stage_times():
    from bench.imu_speed import stage_times

    t = stage_times("note: x\ntime: detection 61.2 s, intrinsics 3.0 s, solve 9.5 s, guided pass 1.5 s, total 88.0 s\n")
    assert t == {"detection_s": 61.2, "intrinsics_s": 3.0, "solve_s": 9.5, "guided_pass_s": 1.5, "total_s": 88.0}


def test_imu_coverage_scores_each_component_in_its_own_sigma():
    """bench.imu_coverage's error / sigma: a rig against itself with one camera's cx moved by
    2 of its sigmas, another turned by 3 sigma about body L and its clock 1.5 sigma late."""
    from dataclasses import replace

    from bench.imu_coverage import normalised_errors
    from rigcal.core import geometry as geo
    from rigcal.core.rig import load_rig

    truth = load_rig(Path(__file__).resolve().parents[1] / "rigs" / "drone-stereo-back-imu.yaml")
    truth = replace(truth, cameras=tuple(replace(c, time_offset_s=0.001) for c in truth.cameras))
    sig = {"rotation_deg": [0.01, 0.02, 0.03], "position_mm": [0.5, 0.5, 0.5], "time_offset_ms": 0.04,
           "intrinsics": {"fx": 0.1, "fy": 0.1, "cx": 0.2, "cy": 0.2}}
    cams = []
    for k, c in enumerate(truth.cameras):
        T, lens, off = c.T_body_cam.copy(), c.intrinsics, c.time_offset_s
        if k == 0:
            lens = lens.with_(cx=lens.cx + 0.4)
        if k == 1:
            T[:3, :3] = geo.R_from_rotvec([0.0, np.radians(0.06), 0.0]) @ T[:3, :3]
            off += 0.00006
        cams.append(replace(c, T_body_cam=T, intrinsics=lens, time_offset_s=off, calibration={"sigma": sig}))
    z = normalised_errors(replace(truth, cameras=tuple(cams)), truth)
    expect_intr = np.zeros((3, 4))
    expect_intr[0, 2] = 2.0
    np.testing.assert_allclose(z["intrinsics"], expect_intr, atol=1e-9)
    expect_rot = np.zeros((3, 3))
    expect_rot[1, 1] = 3.0
    np.testing.assert_allclose(z["rotation"], expect_rot, atol=1e-6)
    np.testing.assert_allclose(z["time offset"].ravel(), [0.0, 1.5, 0.0], atol=1e-6)
    np.testing.assert_allclose(z["translation"], 0.0, atol=1e-9)


def test_imu_freerun_tables_summarise_each_case():
    from bench import imu_freerun

    cams = lambda rot, off: {c: {"imu0_rot_deg": rot, "imu0_pos_mm": 0.5, "offset_ms": off}  # noqa: E731
                             for c in ("a", "b")}
    res = {"duration_s": 8.0, "seeds": 1, "runs": [
        {"case": "synchronised", "cameras": cams(0.002, 0.01), "z": {"rotation": [[0.5, 3.0]]}},
        {"case": "free-running", "cameras": cams(0.004, -0.03), "z": {"rotation": [[1.0, 1.5]]},
         "z_formal": {"rotation": [[1.0, 3.0]]}}]}
    s = imu_freerun.summary(res)
    assert s["synchronised"]["within_2_sigma"] == 0.5 and s["free-running"]["within_2_sigma"] == 1.0
    assert s["free-running"]["offset_ms_max"] == 0.03 and s["synchronised"]["rot_deg_max"] == 0.002
    assert s["free-running"]["within_2_formal"] == 0.5 and "within_2_formal" not in s["synchronised"]
    assert "free-running" in imu_freerun.tables(res)


def test_the_render_cache_key_reads_every_code_file():
    """bench.common.code_hash finds its CODE_FILES wherever they live in the package (the
    cached renders of bench.accuracy and bench.same_outputs are keyed by it)."""
    from bench import common

    h = common.code_hash()
    assert re.fullmatch(r"[0-9a-f]{10}", h) and h == common.code_hash()


def test_indie_imu_scores_the_truth_as_zero_and_a_turned_camera_by_its_angle(tmp_path):
    """bench.indie_imu's scoring on an unrendered independent recording: the truth scored
    against itself is exact; one camera turned by 0.01 deg about body z and moved 1 mm along
    body x, and its clock 0.02 ms late, shows exactly that, in units of the sigmas given."""
    import copy

    import numpy as np
    import yaml

    from bench.indie_imu import score
    from tests.support import indie_motion as im

    im.write_recording(im.recording(seed=0, duration=1.0), tmp_path, render=False)
    truth = yaml.safe_load((tmp_path / "truth.yaml").read_text())
    cal = copy.deepcopy(truth["rig"])
    for c in cal["cameras"].values():
        c["calibration"] = {"sigma": {"rotation_deg": [0.005] * 3, "position_mm": [0.5] * 3, "time_offset_ms": 0.01}}
    true_bias = np.mean(truth["imus"]["imu0"]["gyroscope_bias"]["values"], axis=0)
    cal["imus"]["imu0"]["calibration"] = {"gyroscope_bias": true_bias.tolist()}
    r = score(cal, truth)
    assert max(max(abs(x) for x in v) for v in r["z"].values()) < 1e-9
    c = cal["cameras"]["back"]
    a = np.radians(0.01)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    c["rotation"] = (Rz @ np.asarray(c["rotation"])).tolist()
    c["position"] = (np.asarray(c["position"]) + [0.001, 0, 0]).tolist()
    c["time_offset_s"] += 2e-5
    r = score(cal, truth)["cameras"]["back"]
    assert abs(r["rot_deg"] - 0.01) < 1e-9 and abs(r["pos_mm"] - 1.0) < 1e-9 and abs(r["offset_ms"] - 0.02) < 1e-9
    np.testing.assert_allclose(r["rot_deg_xyz"], [0, 0, 0.01], atol=1e-9)
    np.testing.assert_allclose(r["pos_mm_xyz"], [1.0, 0, 0], atol=1e-9)


def test_imu_noise_real_units_and_random_walk_bound():
    """bench.imu_noise_real: an imudata ADIS16405 row (deg/s, g) becomes rad/s and m/s^2 at
    100 Hz; and the random-walk bound of a curve that is exactly white noise plus a random
    walk lies above the true K by the chi-square factor of the longest tau's few clusters
    (the white noise is negligible there)."""
    from scipy.stats import chi2

    from bench import imu_noise_real as real
    from rigcal.imunoise.allan import ALPHA, AllanCurve, curve_edf, octave_clusters

    t_ns, g, a = real.adis_samples(np.array([[1.0, -2.0, 0.5, 0.01, 0.0, -1.0]] * 3))
    np.testing.assert_array_equal(t_ns, [0, 10_000_000, 20_000_000])
    np.testing.assert_allclose(g[0], np.deg2rad([1.0, -2.0, 0.5]))
    np.testing.assert_allclose(a[0], [0.0980665, 0.0, -9.80665])
    with pytest.raises(ValueError):
        real.adis_samples(np.zeros((3, 5)))

    n, rate, N, K = 10 ** 9, 100.0, 6e-4, 2e-5
    m = octave_clusters(n)
    tau = m / rate
    curve = AllanCurve(tau, np.sqrt(N ** 2 / tau + K ** 2 * tau / 3.0), m, n, rate)
    bound = real.max_random_walk(curve, np.array([0.0, N ** 2, 0.0, K ** 2]))
    nu = float(curve_edf(ALPHA["random_walk"], curve, m[-1:])[0])
    assert 1.0 < nu < 30.0  # a tenth of the recording: ten clusters, whatever n
    assert bound > K
    assert bound == pytest.approx(K * np.sqrt(nu / chi2.ppf(0.05, nu)), rel=1e-4)
