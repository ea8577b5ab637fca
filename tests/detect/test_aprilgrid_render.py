"""AprilGrid through the renderer: `simulate --target` with a Kalibr grid renders it so the
detector finds Kalibr's ids where truth.yaml puts them, and its corners are at least as
accurate as ChArUco corners on a board of the same size (6 x 6 cells over 0.713 m)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.detect import april
from rigcal.core import geometry as geo
from rigcal.data.dataset import list_dataset
from rigcal.detect.detect import detect_dataset
from rigcal.core.rig import load_rig, rig_from_dict
from rigcal.sim.simulate import simulate_dataset
from rigcal.core.target import load_target, parse_target

ROOT = Path(__file__).resolve().parents[2]
GRID = "boards:\n  - {name: grid, type: aprilgrid, tags: [6, 6], tag_size: 0.088, tag_spacing: 0.3}\n"
# the same outer size (0.7128 m) and number of cells
CHARUCO = ("boards:\n  - {name: grid, type: charuco, dictionary: DICT_5X5_1000, squares: [6, 6], "
           "square_length: 0.1188, marker_length: 0.0891}\n")
FRAMES = 3


def _errors(ds: Path, refine: str = "symmetric") -> tuple[np.ndarray, int]:
    """Every detected corner's distance (px) from where truth.yaml projects it, and the views."""
    truth = yaml.safe_load((ds / "truth.yaml").read_text())
    rig = rig_from_dict(truth["rig"])
    target = load_target(ds / "target.yaml")
    res = detect_dataset(list_dataset(ds, rig), target, jobs=1, progress=False, refine=refine)
    out = [np.linalg.norm(v.uv - _projected(truth, rig, v.frame, v.camera, target.board(v.board), v.ids), axis=1)
           for v in res.views]
    return np.concatenate(out), len(res.views)


def _projected(truth: dict, rig, frame: str, camera: str, board, ids: np.ndarray) -> np.ndarray:
    """(N, 2) where truth.yaml puts a board's corners ids in a camera's image of a frame."""
    fr = truth["frames"][frame]
    cam = rig.camera(camera)
    pose = fr.get("boards", {}).get(board.name, truth["boards"][board.name])
    T_cam_board = (geo.inv_T(geo.make_T(np.array(fr["rotation"]), fr["position"]) @ cam.T_body_cam)
                   @ geo.make_T(np.array(pose["rotation"]), pose["position"]))
    return cam.intrinsics.project(geo.transform(T_cam_board, board.corners[ids]))[0]


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


FISHEYE_ROOM = pytest.mark.xfail(strict=True, reason=(
    "not met on accuracy (docs/accuracy.md, AprilGrid; bench/aprilgrid_excess.py); the views now match ChArUco's "
    "(6 of 6: frame 2's 13-16 px tags are decoded upsampled and their corners refined, "
    "test_fisheye_room_gives_as_many_aprilgrid_views_as_charuco). Accuracy: 0.029 px RMS against 0.0115 "
    "(frames 0-1 alone 0.027; before the small tags were found 0.021 on 4 views): at ~22 px tags the "
    "point-symmetric box is +-3 px, at 16 px +-1.7, and even placed by the true lens a symmetric fit gives "
    "0.019 (0.015 on the 4 views before); "
    "the long arms (tag edges, antisymmetric) give 0.0114 but are off: on the real EuRoC print they pull every "
    "corner 0.05 px towards its tag, and with that offset fitted still leave the corners twice as rough "
    "(0.07 against 0.03 px); on the real frames averaged down to the room's 23 and 17 px tags they are no "
    "better either (0.044 against 0.027, 0.028 against 0.025 px; bench.aprilgrid_excess EUROC_SCALES)"))


@pytest.fixture(scope="module")
def fisheye_room(tmp_path_factory) -> dict[str, Path]:
    """The fisheye room rendered with the AprilGrid and with ChArUco (FRAMES frames, seed 1)."""
    rig = load_rig(ROOT / "rigs" / "fisheye-stereo.yaml")
    out = {}
    for name, text in (("aprilgrid", GRID), ("charuco", CHARUCO)):
        out[name] = tmp_path_factory.mktemp("fisheye-room") / name
        simulate_dataset(rig, out[name], scene="room", frames=FRAMES, seed=1, target=parse_target(text), jobs=1)
    return out


@pytest.mark.parametrize("rig_name, scene", [
    ("stereo-forward", "board"), ("stereo-forward", "room"),
    ("fisheye-stereo", "board"),
    pytest.param("fisheye-stereo", "room", marks=FISHEYE_ROOM),
])
@pytest.mark.slow
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


@pytest.mark.slow
def test_long_arms_bring_the_fisheye_room_within_charucos_accuracy(fisheye_room):
    """The long-arm pass (off by default: april.LONG_ARMS_BELOW_PX; refine mode "long-arms") turned on for
    every tag: through the fisheye in the room scene (tags 13-26 px) the AprilGrid corners are
    then at least as accurate as ChArUco's (measured 0.0114 against 0.0115 px RMS over all six
    views; frames 0-1 0.0104, frame 2's 13-16 px tags 0.0137 against ChArUco's 0.0106 there;
    today's detector 0.029)."""
    (e_april, _), (e_charuco, _) = _errors(fisheye_room["aprilgrid"], "long-arms"), _errors(fisheye_room["charuco"])
    assert len(e_april) > 600 and e_april.max() < 0.3, (len(e_april), e_april.max())
    assert _rms(e_april) <= _rms(e_charuco), (_rms(e_april), _rms(e_charuco))


def test_fisheye_room_gives_as_many_aprilgrid_views_as_charuco(fisheye_room):
    """Frame 2's tags are 13-16 px: OpenCV decodes 6 of 36 at full size and the corner-square
    box refined none of their corners, so 4 AprilGrid views against ChArUco's 6. Upsampled
    around the tags found (april.upsampled_regions) it decodes 31 and 35, and the box, sampled
    densely enough (corner_fit.MIN_SAMPLES_PER_ARM), refines them: 6 views, 773 corners (385
    before), none on a wrong junction."""
    (e_april, n_april), (_, n_charuco) = _errors(fisheye_room["aprilgrid"]), _errors(fisheye_room["charuco"])
    assert n_charuco == 2 * FRAMES
    assert n_april >= n_charuco, (n_april, n_charuco)
    assert len(e_april) > 600 and e_april.max() < 0.3, (len(e_april), e_april.max())


def test_upsampled_tags_are_placed_without_a_shift(fisheye_room):
    """The tags only the upsampled pass decodes (frame 2, 13-16 px) come back to the image's
    pixels with cv2.resize's pixel centres, x = (x' + 0.5) / 2 - 0.5: their quads' centres
    (OpenCV's corner errors, 1 px and more, cancel around a tag) sit on the true tags'
    centres to 0.02 px on average (measured); x' / 2 would put them 0.25 px off."""
    ds = fisheye_room["aprilgrid"]
    truth = yaml.safe_load((ds / "truth.yaml").read_text())
    rig = rig_from_dict(truth["rig"])
    board = load_target(ds / "target.yaml").boards[0]
    group = april.AprilGridGroup([board])
    offsets = []
    for cam in ("left", "right"):
        gray = cv2.imread(str(ds / "images" / cam / "000002.png"), cv2.IMREAD_GRAYSCALE)
        ids, quads = group.tags(gray)
        native = np.concatenate([_decoded(p, gray) for p in group.passes])
        up = ~np.isin(ids, group.ids[native])
        true_uv = _projected(truth, rig, "000002", cam, board, np.arange(board.n_corners))
        centres = true_uv.reshape(-1, 4, 2)[ids[up] - board.first_marker_id].mean(axis=1)
        offsets.append(quads[up].mean(axis=1) - centres)
    d = np.concatenate(offsets)
    assert len(d) >= 40, len(d)
    assert np.all(np.abs(d.mean(axis=0)) < 0.1), d.mean(axis=0)


def _decoded(aruco, gray: np.ndarray) -> np.ndarray:
    """Indices into the detector's own dictionary of the tags one pass decodes."""
    _, idx, _ = aruco.detectMarkers(gray)
    return np.zeros(0, int) if idx is None else np.asarray(idx).ravel()


@pytest.mark.slow
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
    assert "tag_spacing" not in res.output  # 0.3: no spacing warning
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
    from rigcal.detect.board_detectors import BoardDetector
    from rigcal.data.image_read import read_gray

    (tmp_path / "grid.yaml").write_text(GRID)
    out = tmp_path / "grid.png"
    res = CliRunner().invoke(app, ["board", str(tmp_path / "grid.yaml"), "--out", str(out), "--dpi", "100"])
    assert res.exit_code == 0, res.output
    gray, _ = read_gray(str(out))
    views, _ = BoardDetector(parse_target(GRID)).detect(gray)
    assert len(views) == 1 and len(views[0][1]) == 144


THREE_GRIDS = GRID + (
    "  - {name: grid2, type: aprilgrid, tags: [6, 6], tag_size: 0.088, tag_spacing: 0.3, first_tag_id: 36}\n"
    "  - {name: grid3, type: aprilgrid, tags: [6, 6], tag_size: 0.088, tag_spacing: 0.3, first_tag_id: 72}\n")


def test_a_room_of_three_aprilgrids_through_the_fisheye(tmp_path):
    """Three AprilGrids in the room, seen through the fisheye (3 frames, seed 3): boards far
    off, small, or squashed at the image's edge. No corner may sit on a wrong junction: one
    board squashed near the edge had three corners refined onto the centres of their corner
    squares, 3 px off (april.MIN_CONTRAST now rejects them); and a board none of whose tags
    decoded at full size is searched upsampled around its undecoded quads
    (april.candidate_regions, away_from): measured 18 views, 550 corners (16, 487 before)."""
    rig = load_rig(ROOT / "rigs" / "fisheye-stereo.yaml")
    ds = tmp_path / "ds"
    simulate_dataset(rig, ds, scene="room", frames=3, seed=3, target=parse_target(THREE_GRIDS), jobs=1)
    e, n = _errors(ds)
    assert n >= 17 and len(e) > 520, (n, len(e))
    assert e.max() < 0.3, e.max()
    assert _rms(e) < 0.05, _rms(e)


@pytest.mark.slow
def test_a_corner_left_far_off_does_not_tilt_its_tags_other_corners(tmp_path):
    """stereo-forward, board scene, seed 3: in the third frame one tag's OpenCV quad is 13-18
    px off (its neighbour above is cut by the image's edge). The box passes restart three of
    its corners from the neighbouring tags and refine them to 0.01 px, and leave the fourth
    out; the last pass took that tag's axes from all four, the far one too, and moved two
    good corners to 0.11 and 0.51 px (sigma 0.03). The axes now leave such a corner out and
    its tag's corners keep the box's result (corner_refine.FAILED_NEAR_PX): measured max
    0.052 px, rms 0.0125 (0.512, 0.0329 before)."""
    rig = load_rig(ROOT / "rigs" / "stereo-forward.yaml")
    ds = tmp_path / "ds"
    simulate_dataset(rig, ds, scene="board", frames=FRAMES, seed=3, target=parse_target(GRID), jobs=1)
    e, n = _errors(ds)
    assert n == 2 * FRAMES and len(e) > 250, (n, len(e))
    assert e.max() < 0.2, e.max()


def test_wide_spacing_keeps_the_cross_arms_short(tmp_path):
    """tag_spacing 1.0 (corner squares as big as the tags): the last pass's arms ran along the
    whole corner square and left 0.058 px RMS, 0.44 px at worst on the close pinhole board
    (seed 1); held to 0.3 tag (april.MAX_ARM, where the pass was measured) 0.0078 / 0.033."""
    text = GRID.replace("tag_spacing: 0.3", "tag_spacing: 1.0")
    rig = load_rig(ROOT / "rigs" / "stereo-forward.yaml")
    ds = tmp_path / "ds"
    simulate_dataset(rig, ds, scene="board", frames=FRAMES, seed=1, target=parse_target(text), jobs=1)
    e, n = _errors(ds)
    assert n == 2 * FRAMES and len(e) > 300, (n, len(e))
    assert _rms(e) < 0.02 and e.max() < 0.1, (_rms(e), e.max())
