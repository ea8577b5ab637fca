"""Free-running cameras given as corners/<camera>.csv (the dataset's pre-detected corners):
their csv frames (integer ns, shared by no other camera) are grouped by time for the
camera-only start exactly as image folders are, then every view is placed at its own time:
without an IMU (imucal.visual_motion) and with imu/ (the camera-IMU step). Without an IMU
also: the formal sigmas checked on the recording's halves (`sigma_source`) and the HTML
report's section on the continuous-time estimate. The recordings are projected corners of
simulate's free-running schedule (tests/support/imu_check_cases.record), so each round
trip takes seconds."""

from __future__ import annotations

import re

import numpy as np
import pytest

from rigcal.commands.calibrate import CalibrateOptions, run
from rigcal.core.rig import load_rig
from tests.support.imu_check_cases import record, true_rig

DURATION, RATE = 5.0, 20.0


@pytest.fixture(scope="module")
def truth():
    return true_rig(1, 3.0)


def _calibrate(truth, tmp, with_imu: bool, report=None):
    ds = record(truth, tmp / "ds", DURATION, RATE, seed=3, free_running=True, with_imu=with_imu)
    stems = [{ln.split(",", 1)[0] for ln in (ds / "corners" / f"{c}.csv").read_text().splitlines()[1:]}
             for c in truth.names]
    assert all(not (a & b) for i, a in enumerate(stems) for b in stems[i + 1:])  # really free-running
    out = tmp / "cal.yaml"
    run(ds, out, CalibrateOptions(jobs=1, report=report))
    return load_rig(out)


@pytest.fixture(scope="module")
def without_imu(truth, tmp_path_factory):
    """(the calibrated rig, the report page, the continuous-time estimate calibrate made)."""
    from rigcal.imucal import visual_motion

    tmp = tmp_path_factory.mktemp("noimu")
    made = []

    def keep(*args, **kwargs):
        made.append(real(*args, **kwargs))
        return made[-1]

    real = visual_motion.calibrate_visual_motion
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(visual_motion, "calibrate_visual_motion", keep)
        est = _calibrate(truth, tmp, with_imu=False, report=tmp / "report.html")
    return est, (tmp / "report.html").read_text(), made[0]


@pytest.mark.slow
def test_corner_files_of_free_running_cameras_without_an_imu(truth, without_imu):
    est = without_imu[0]
    ref = est.calibration["free_running"]["clock"].split(":", 1)[1]
    for c in est.cameras:
        sig = c.calibration["sigma"]["time_offset_ms"]
        true_rel = truth.camera(c.name).time_offset_s - truth.camera(ref).time_offset_s
        if c.name == ref:
            continue
        assert abs(true_rel) > 3e-4  # the clocks really differ: the estimate must find them
        err_ms = 1000 * (c.time_offset_s - true_rel)
        assert abs(err_ms) <= 3 * sig and abs(err_ms) < 0.2, (c.name, err_ms, sig)


@pytest.mark.slow
def test_corner_files_of_free_running_cameras_with_an_imu(truth, tmp_path):
    est = _calibrate(truth, tmp_path, with_imu=True)
    for c in est.cameras:
        sig = c.calibration["sigma"]["time_offset_ms"]
        err_ms = 1000 * (c.time_offset_s - truth.camera(c.name).time_offset_s)
        assert abs(err_ms) <= 3 * sig and abs(err_ms) < 0.2, (c.name, err_ms, sig)


def test_the_sigmas_are_checked_on_the_halves(without_imu):
    """The halves were estimated and compared for every camera but the held reference; the
    written sigmas are the reported ones: never below the formal ones, at least half the
    halves' difference, and `sigma_source` says `subsets` exactly where a sigma was raised."""
    est, _, vm = without_imu
    check = vm.subsets
    assert check is not None
    names = [c.name for c in est.cameras]
    g = vm.reference
    assert not check.compared[g] and check.compared[np.arange(len(names)) != g].all()
    assert np.all(vm.sigma >= vm.formal_sigma - 1e-15)
    half = 0.5 * np.abs(np.column_stack([check.d_rot, check.d_pos, check.d_offset]))
    assert np.all(vm.sigma[check.compared] >= half[check.compared] * (1 - 1e-12))
    for k, c in enumerate(est.cameras):
        raised = bool(np.any(vm.sigma[k] > vm.formal_sigma[k] * (1 + 1e-9)))
        assert c.calibration["sigma_source"] == ("subsets" if raised else "formal"), c.name
        np.testing.assert_allclose(c.calibration["sigma"]["time_offset_ms"], 1000 * vm.sigma[k, 6], atol=1e-5)
        np.testing.assert_allclose(c.calibration["sigma"]["position_mm"], 1000 * vm.sigma[k, 3:6], atol=1e-4)


def test_subset_sigmas_are_at_least_the_formal_ones():
    """visual_motion.subset_check's sigmas, as the camera-IMU step's: never below the formal
    one, and at least half the halves' difference (imucal.step.inflated)."""
    from rigcal.imucal.step import inflated

    formal = np.array([0.1, 0.2, 0.3])
    assert np.all(inflated(formal, np.zeros(3)) == formal)
    v = inflated(formal, np.array([1.0, 0.0, 0.0]))
    assert v[0] >= 0.5 and np.all(v >= formal)


def _row(html_part: str, name: str) -> list[str]:
    """The cells of the table row whose first cell is `name`."""
    row = re.search(r"<tr><td class=\"name\">" + re.escape(name) + r"</td>(.*?)</tr>", html_part).group(1)
    return re.findall(r"<td[^>]*>([^<]*)</td>", row)


def test_the_report_shows_the_continuous_time_estimate(without_imu):
    """The page has the free-running section: every camera's clock offset and its 1-sigma as
    written (not the start's zero), the sigmas' source, the motion figure; the pose table's
    sigmas are the estimate's (the written ones), not the camera-only start's."""
    est, page, _ = without_imu
    assert 'id="fig-visual-motion"' in page and "continuous-time estimate (see its section below" in page
    section = page[page.index("Free-running cameras: clock offsets and poses of the continuous-time estimate"):]
    for c in est.cameras:
        offset_ms, sigma_ms, *_, source = _row(section, c.name)
        assert float(offset_ms) == pytest.approx(1000 * c.time_offset_s, abs=1e-4)
        assert float(sigma_ms) == pytest.approx(c.calibration["sigma"]["time_offset_ms"], abs=1e-4)
        assert source in ("held (the time base)", c.calibration["sigma_source"])
    poses = page[page.index("Cameras: pose in the body frame"):page.index("Stereo pairs")]
    for c in est.cameras:  # the written position sigmas (the table's 6th column)
        shown = [float(x) for x in _row(poses, c.name)[4].split()]
        np.testing.assert_allclose(shown, c.calibration["sigma"]["position_mm"], atol=1e-3)


def _shift_corners(path, share: float, shift_px: float, seed: int) -> int:
    """Move `share` of the corners of one corners/<camera>.csv right by shift_px: as corners
    whose refinement took in the edge of something in front of the board are all pulled
    one way. Returns how many."""
    lines = path.read_text().splitlines()
    rng = np.random.default_rng(seed)
    hit = rng.random(len(lines) - 1) < share
    out = [lines[0]]
    for ln, h in zip(lines[1:], hit):
        f, b, k, u, v = ln.split(",")
        out.append(f"{f},{b},{k},{float(u) + shift_px * h:.4f},{v}")
    path.write_text("\n".join(out) + "\n")
    return int(hit.sum())


@pytest.mark.slow
def test_corners_pulled_off_by_an_occluding_edge_are_left_out(truth, tmp_path):
    """5 % of one free-running camera's corners 2 px off in one direction (about 7 corner
    sigmas), as corners whose refinement took in the edge of something in front of the
    board: the camera-IMU step names about that many corners beyond 5 robust sigmas (no
    more: the others are Gaussian) and refines without them."""
    from typer.testing import CliRunner

    from rigcal.cli import app

    ds = record(truth, tmp_path / "ds", DURATION, RATE, seed=3, free_running=True, with_imu=True)
    name = truth.names[0]
    n = _shift_corners(ds / "corners" / f"{name}.csv", 0.05, 2.0, seed=5)
    assert n > 100
    r = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml"), "--jobs", "1"])
    assert r.exit_code == 0, r.output
    m = re.search(r"the second without the (\d+) corners the first put beyond 5 robust sigmas", r.output)
    assert m, r.output
    # 2 px is 6.7 sigmas: a shifted corner whose noise pulls it back under 5 sigmas stays
    assert 0.85 * n <= int(m.group(1)) <= n + 3, (m.group(1), n)
    est = load_rig(tmp_path / "cal.yaml")
    c, t = est.camera(name), truth.camera(name)
    assert abs(c.intrinsics.cx - t.intrinsics.cx) <= 3 * c.calibration["sigma"]["intrinsics"]["cx"]
