"""AprilGrid through the renderer: `simulate --target` with a Kalibr grid renders it so the
detector finds Kalibr's ids where truth.yaml puts them, and its corners are at least as
accurate as ChArUco corners on a board of the same size (6 x 6 cells over 0.713 m)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal import april
from rigcal import geometry as geo
from rigcal.dataset import list_dataset
from rigcal.detect import detect_dataset
from rigcal.rig import load_rig, rig_from_dict
from rigcal.simulate import simulate_dataset
from rigcal.target import load_target, parse_target

ROOT = Path(__file__).resolve().parents[1]
GRID = "boards:\n  - {name: grid, type: aprilgrid, tags: [6, 6], tag_size: 0.088, tag_spacing: 0.3}\n"
# the same outer size (0.7128 m) and number of cells
CHARUCO = ("boards:\n  - {name: grid, type: charuco, dictionary: DICT_5X5_1000, squares: [6, 6], "
           "square_length: 0.1188, marker_length: 0.0891}\n")
FRAMES = 3


def _errors(ds: Path) -> tuple[np.ndarray, int]:
    """Every detected corner's distance (px) from where truth.yaml projects it, and the views."""
    truth = yaml.safe_load((ds / "truth.yaml").read_text())
    rig = rig_from_dict(truth["rig"])
    target = load_target(ds / "target.yaml")
    res = detect_dataset(list_dataset(ds, rig), target, jobs=1, progress=False)
    out = []
    for v in res.views:
        fr = truth["frames"][v.frame]
        cam = rig.camera(v.camera)
        pose = fr.get("boards", {}).get(v.board, truth["boards"][v.board])
        T_cam_board = (geo.inv_T(geo.make_T(np.array(fr["rotation"]), fr["position"]) @ cam.T_body_cam)
                       @ geo.make_T(np.array(pose["rotation"]), pose["position"]))
        board = target.board(v.board)
        uv, _ = cam.intrinsics.project(geo.transform(T_cam_board, board.corners[v.ids]))
        out.append(np.linalg.norm(v.uv - uv, axis=1))
    return np.concatenate(out), len(res.views)


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


FISHEYE_ROOM = pytest.mark.xfail(strict=True, reason=(
    "not met on two counts (README, AprilGrid targets; bench/aprilgrid_excess.py). Views: 4 of 6 against "
    "ChArUco's 6 (frame 2's tags are 13-16 px: OpenCV decodes 4-8 of 36 and the corner-square box, +-1.5 px, "
    "refines none). Accuracy: 0.021 px RMS against 0.0115 (noise-free 0.011 against 0.0048): at ~22 px tags the "
    "point-symmetric box is +-3 px, and even placed by the true lens a symmetric fit gives 0.015; the long arms "
    "(tag edges, antisymmetric) give 0.0098 but are off: on the real EuRoC print they pull every corner 0.05 px "
    "towards its tag, and with that offset fitted still leave the corners twice as rough (0.07 against 0.03 px)"))


@pytest.mark.parametrize("rig_name, scene", [
    ("stereo-forward", "board"), ("stereo-forward", "room"),
    ("fisheye-stereo", "board"),
    pytest.param("fisheye-stereo", "room", marks=FISHEYE_ROOM),
])
def test_rendered_aprilgrid_corners_are_at_least_as_accurate_as_charuco(rig_name, scene, tmp_path):
    rig = load_rig(ROOT / "rigs" / f"{rig_name}.yaml")
    got = {}
    for name, text in (("aprilgrid", GRID), ("charuco", CHARUCO)):
        ds = tmp_path / name
        simulate_dataset(rig, ds, scene=scene, frames=FRAMES, seed=1, target=parse_target(text), jobs=1)
        got[name] = _errors(ds)
    (e_april, n_april), (e_charuco, n_charuco) = got["aprilgrid"], got["charuco"]
    assert n_april >= n_charuco - 1 and len(e_april) > 50
    # no corner on the wrong junction, and the detector's ids are Kalibr's (a wrong id is a tag away)
    assert e_april.max() < 0.3, e_april.max()
    assert _rms(e_april) <= _rms(e_charuco), (_rms(e_april), _rms(e_charuco))


def test_long_arms_bring_the_fisheye_room_within_charucos_accuracy(tmp_path, monkeypatch):
    """The long-arm pass (off by default: april.LONG_ARMS_BELOW_PX; README) turned on for
    every tag: through the fisheye in the room scene (tags ~22 px) the AprilGrid corners are
    then at least as accurate as ChArUco's (measured 0.0098 against 0.0115 px RMS; today's
    detector 0.021). The view count is a separate shortfall (the xfail above)."""
    monkeypatch.setattr(april, "LONG_ARMS_BELOW_PX", np.inf)
    rig = load_rig(ROOT / "rigs" / "fisheye-stereo.yaml")
    got = {}
    for name, text in (("aprilgrid", GRID), ("charuco", CHARUCO)):
        ds = tmp_path / name
        simulate_dataset(rig, ds, scene="room", frames=FRAMES, seed=1, target=parse_target(text), jobs=1)
        got[name] = _errors(ds)
    (e_april, _), (e_charuco, _) = got["aprilgrid"], got["charuco"]
    assert len(e_april) > 200 and e_april.max() < 0.3, (len(e_april), e_april.max())
    assert _rms(e_april) <= _rms(e_charuco), (_rms(e_april), _rms(e_charuco))


def test_simulated_aprilgrid_dataset_calibrates(tmp_path):
    from typer.testing import CliRunner

    from rigcal.cli import app

    (tmp_path / "grid.yaml").write_text(GRID)
    ds = tmp_path / "ds"
    runner = CliRunner()
    res = runner.invoke(app, ["simulate", str(ROOT / "rigs" / "stereo-forward.yaml"), "--scene", "board",
                              "--frames", "8", "--target", str(tmp_path / "grid.yaml"), "--out", str(ds), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert "AprilGrid 6x6 tags 88 mm" in res.output
    res = runner.invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml"), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    truth = rig_from_dict(yaml.safe_load((ds / "truth.yaml").read_text())["rig"])
    cal = load_rig(tmp_path / "cal.yaml")
    T_t = geo.inv_T(truth.camera("left").T_body_cam) @ truth.camera("right").T_body_cam
    T_c = geo.inv_T(cal.camera("left").T_body_cam) @ cal.camera("right").T_body_cam
    assert np.linalg.norm(T_c[:3, 3] - T_t[:3, 3]) < 0.2e-3
    for n in ("left", "right"):
        t, c = truth.camera(n).intrinsics, cal.camera(n).intrinsics
        np.testing.assert_allclose([c.fx, c.fy, c.cx, c.cy], [t.fx, t.fy, t.cx, t.cy], atol=0.5)


def test_board_command_prints_an_aprilgrid(tmp_path):
    from typer.testing import CliRunner

    from rigcal.cli import app
    from rigcal.board_detectors import BoardDetector
    from rigcal.image_read import read_gray

    (tmp_path / "grid.yaml").write_text(GRID)
    out = tmp_path / "grid.png"
    res = CliRunner().invoke(app, ["board", str(tmp_path / "grid.yaml"), "--out", str(out), "--dpi", "100"])
    assert res.exit_code == 0, res.output
    gray, _ = read_gray(str(out))
    views, _ = BoardDetector(parse_target(GRID)).detect(gray)
    assert len(views) == 1 and len(views[0][1]) == 144
