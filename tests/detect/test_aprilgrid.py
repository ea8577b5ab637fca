"""AprilGrid (Kalibr's target): target.yaml and Kalibr files, the printed face, detection
(flat prints, inverted prints, the real EuRoC frame checked by PnP with EuRoC's intrinsics)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.detect import april
from rigcal.core import geometry as geo
from rigcal.detect.board_detectors import BoardDetector
from rigcal.detect.corner_refine import refine_corners
from rigcal.errors import TargetFileError
from rigcal.core.target import Board, dump_target, load_target, parse_target

ROOT = Path(__file__).resolve().parents[2]
EUROC = ROOT.parent / "shared" / "data" / "real" / "euroc_imu_april"
euroc = pytest.mark.skipif(not EUROC.is_dir(), reason="../shared/data/real/euroc_imu_april is not here")

GRID = """boards:
  - name: grid
    type: aprilgrid
    tags: [6, 6]
    tag_size: 0.088
    tag_spacing: 0.3
"""


CHARUCO_BOARD = """  - name: cb
    type: charuco
    dictionary: DICT_5X5_1000
    squares: [5, 4]
    square_length: 0.04
    marker_length: 0.03
"""


def _grid(**kw) -> Board:
    d = dict(name="grid", tags=(6, 6), tag_size=0.088, tag_spacing=0.3, first_tag_id=0)
    d.update(kw)
    return Board.aprilgrid(**d)


def test_corner_ids_and_positions_are_kalibrs():
    b = parse_target(GRID).boards[0]
    assert b.n_corners == 144 and b.n_markers == 36
    pitch = 0.088 * 1.3
    # tag 7 = column 1, row 1 (from the bottom); corner k = 2 is its top-right
    np.testing.assert_allclose(b.corners[4 * 7 + 2], [pitch + 0.088, pitch + 0.088, 0.0], atol=1e-12)
    np.testing.assert_allclose(b.corners[4 * 5 + 0], [5 * pitch, 0.0, 0.0], atol=1e-12)  # tag 5: bottom-right tag
    np.testing.assert_allclose(b.corners[4 * 30 + 3], [0.0, 5 * pitch + 0.088, 0.0], atol=1e-12)  # tag 30: top-left
    # the README of the EuRoC set: x = floor(c / 2) (1 + spacing) size + (c mod 2) size along each axis
    cx = np.array([0, 1, 1, 0])[None, :] + 2 * (np.arange(36) % 6)[:, None]
    np.testing.assert_allclose(b.corners[:, 0].reshape(36, 4), cx // 2 * pitch + cx % 2 * 0.088, atol=1e-12)


def test_print_frame_is_a_proper_motion_onto_the_board_frame():
    b = _grid(tags=(4, 3), tag_spacing=0.25)
    T = b.T_board_print
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    # the print's top-left outer corner is the board's (-gap, height - gap); z flips
    np.testing.assert_allclose(geo.transform(T, np.zeros((1, 3)))[0], [-b.gap, b.size_m[1] - b.gap, 0.0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0, 0, -1], atol=1e-12)


@pytest.mark.parametrize("inverted", [False, True])
def test_flat_print_is_detected_with_kalibr_ids_at_sub_pixel_accuracy(inverted):
    b = _grid()
    ppm, margin = 600.0, 30  # a tag of ~53 px
    img = b.image(ppm, margin)
    if inverted:
        img = 255 - img
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    views, dropped = BoardDetector(parse_target(GRID)).detect_with_sigma(img)
    assert len(views) == 1 and dropped == 0
    name, ids, uv, amb, sigma = views[0]
    assert name == "grid" and not amb
    np.testing.assert_array_equal(ids, np.arange(144))
    p_print = geo.transform(geo.inv_T(b.T_board_print), b.corners[ids])
    truth = p_print[:, :2] * ppm + margin - 0.5
    err = np.linalg.norm(uv - truth, axis=1)
    assert err.max() < 0.05, err.max()


def _small_flat_print(tag_px: float, blur: float) -> tuple[Board, np.ndarray, np.ndarray]:
    """A flat print (exact area coverage, closed-form blur, noise 2) with tags of tag_px, and
    its corners' true pixels (144, 2)."""
    b = parse_target(GRID).boards[0]
    ppm, margin = tag_px / b.tag_size, 40
    cover = b.coverage(ppm, margin, blur)
    img = cover * 200.0 + 30.0 + np.random.default_rng(0).normal(0.0, 2.0, cover.shape)
    truth = geo.transform(geo.inv_T(b.T_board_print), b.corners)[:, :2] * ppm + margin - 0.5
    return b, np.clip(np.rint(img), 0, 255).astype(np.uint8), truth


@pytest.mark.parametrize("tag_px, blur, native, found", [(16.0, 0.5, 11, 28), (17.0, 0.7, 16, 24), (19.0, 0.9, 8, 16)])
def test_small_tags_are_decoded_upsampled_and_their_corners_refined(tag_px, blur, native, found):
    """Tags of 16-19 px (a bit under 2 px): OpenCV decodes 8-16 of the 36 at full size
    (`native` pins that, so the upsampled pass is what is tested); the pass on the image
    upsampled around them finds most of the rest (measured 32, 27, 19), at Kalibr's ids, and
    their corners refine onto the true junctions (measured 0.021-0.033 px RMS, max 0.08)."""
    b, img, truth = _small_flat_print(tag_px, blur)
    group = april.AprilGridGroup([b])
    assert len(np.unique(np.concatenate([_decoded(p, img) for p in group.passes]))) <= native
    ids, quads = group.tags(img)
    assert len(ids) >= found and len(np.unique(ids)) == len(ids)
    # OpenCV's quads sit within ~1.5 px of their tags' true corners: a wrong id is a tag away
    cid, uv = april.tag_corners_to_ids(ids - b.first_marker_id, quads)
    assert np.abs(uv - truth[cid]).max() < 3.0
    views, _ = BoardDetector(parse_target(GRID)).detect_with_sigma(img)
    assert len(views) == 1
    _, vid, q, _, _ = views[0]
    err = np.linalg.norm(q - truth[vid], axis=1)
    assert len(vid) >= 3.5 * found and err.max() < 0.15, (len(vid), err.max())


def _decoded(aruco, img: np.ndarray) -> np.ndarray:
    _, idx, _ = aruco.detectMarkers(img)
    return np.zeros(0, int) if idx is None else np.asarray(idx).ravel()


def test_box_pass_refines_the_corners_of_14_px_tags():
    """The corner square's box at 14-15 px tags is +-1.4 px: at the symmetric fit's usual
    0.8 px steps one sample each way, and no corner converged (measured: none refined).
    Sampled at corner_fit.MIN_SAMPLES_PER_ARM steps, corners started 0.5 px off refine onto
    the true junctions (measured 96 % of them, 0.036-0.039 px RMS, max 0.105)."""
    b, img, truth = _small_flat_print(14.0, 0.7)
    ids = np.arange(b.n_corners)
    start = truth + np.random.default_rng(1).uniform(-0.5, 0.5, truth.shape)
    q, ok, sigma = refine_corners(img, b, ids, start, "symmetric")
    err = np.linalg.norm(q - truth, axis=1)[ok]
    assert ok.mean() > 0.85, ok.mean()
    assert np.sqrt(np.mean(err ** 2)) < 0.05 and err.max() < 0.15, (np.sqrt(np.mean(err ** 2)), err.max())
    assert np.isfinite(sigma[ok]).all()


def test_upsampled_regions_cover_the_small_missing_tags_only():
    b = _grid()
    H = np.array([[170.0, 12.0, 100.0], [-6.0, -165.0, 300.0], [0.05, 0.02, 1.0]])  # tags ~15 px

    def quads(H: np.ndarray, tags: np.ndarray) -> np.ndarray:
        px = cv2.perspectiveTransform(b.corners[:, :2].reshape(-1, 1, 2), H).reshape(-1, 4, 2)
        return px[tags][:, april.CV_TO_KALIBR]  # OpenCV's corner j is Kalibr's k = CV_TO_KALIBR[j]

    found = np.arange(10)
    # ten tags give the homography itself: the far tags land where it puts them
    cid, uv = april.tag_corners_to_ids(found, quads(H, found))
    far = b.corners[4 * 35:4 * 36, :2]
    np.testing.assert_allclose(april.board_to_image(b.corners[cid, :2], uv)(far),
                               cv2.perspectiveTransform(far.reshape(-1, 1, 2), H).reshape(-1, 2), atol=1e-6)
    regions = april.upsampled_regions([b], found, quads(H, found), (600, 600))
    assert len(regions) == 1
    x0, y0, x1, y1 = regions[0]
    missing = quads(H, np.arange(10, 36)).reshape(-1, 2)
    assert (missing.min(0) > [x0, y0]).all() and (missing.max(0) < [x1, y1]).all()
    assert (x1 - x0) * (y1 - y0) < 0.25 * 600 * 600
    # one tag found: its affine map still reaches them
    (x0, y0, x1, y1), = april.upsampled_regions([b], found[:1], quads(H, found[:1]), (600, 600))
    assert (missing.min(0) > [x0, y0]).all() and (missing.max(0) < [x1, y1]).all()
    # nothing to search: no tag found, none missing, the missing ones outside the image or large
    assert april.upsampled_regions([b], found[:0], quads(H, found[:0]), (600, 600)) == []
    assert april.upsampled_regions([b], np.arange(36), quads(H, np.arange(36)), (600, 600)) == []
    up = np.array([[1.0, 0, 0], [0, 1.0, -1.0 - quads(H, np.arange(10, 36))[..., 1].mean(1).max()], [0, 0, 1.0]]) @ H
    assert april.upsampled_regions([b], found, quads(up, found), (600, 600)) == []  # their centres above the image
    big = H * [[10.0], [10.0], [1.0]]  # tags ~150 px
    assert april.upsampled_regions([b], found, quads(big, found), (6000, 6000)) == []


@pytest.mark.parametrize("tag_px, blur, found", [(20.0, 0.5, 30), (14.0, 0.7, 3)])
def test_a_board_none_of_whose_tags_decodes_at_full_size_is_found_upsampled(tag_px, blur, found):
    """A flat print whose tags OpenCV decodes none of at full size (a 20 px tag at blur 0.5:
    the corner squares' tips close its outline; 14 px: a bit is 1.4 px): the undecoded small
    quads the passes saw point the upsampled search at it (april.candidate_regions; measured
    35 and 5 tags, 140 corners at 0.019 px RMS for the 20 px print; none before)."""
    b, img, truth = _small_flat_print(tag_px, blur)
    group = april.AprilGridGroup([b])
    assert len(np.concatenate([_decoded(p, img) for p in group.passes])) == 0
    ids, quads = group.tags(img)
    assert len(ids) >= found and len(np.unique(ids)) == len(ids)
    cid, uv = april.tag_corners_to_ids(ids - b.first_marker_id, quads)
    assert np.abs(uv - truth[cid]).max() < 3.0  # each at Kalibr's id: a wrong one is a tag away
    if tag_px >= 20:
        views, _ = BoardDetector(parse_target(GRID)).detect_with_sigma(img)
        _, vid, q, _, _ = views[0]
        err = np.linalg.norm(q - truth[vid], axis=1)
        assert len(vid) >= 120 and np.sqrt(np.mean(err ** 2)) < 0.03 and err.max() < 0.1, (len(vid), err.max())


def _squares(centres: np.ndarray, size: float) -> np.ndarray:
    return centres[:, None, :] + 0.5 * size * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1.0]])


def test_candidate_regions_need_a_crowd_of_small_quads():
    grid = np.stack(np.meshgrid(np.arange(6) * 20.0 + 100, np.arange(6) * 20.0 + 50), -1).reshape(-1, 2)
    (x0, y0, x1, y1), = april.candidate_regions(_squares(grid, 11.0), (480, 640))
    # the quads' extent (94.5-205.5, 44.5-155.5 px) grown by two of their sizes, whole pixels
    assert (x0, y0, x1, y1) == (72, 22, 229, 179)
    # two crowds, two regions; each detector pass reports the same quads: counted once
    two = np.r_[_squares(grid[:3], 11.0), _squares(grid[:3] + 300, 11.0)]
    assert len(april.candidate_regions(two, (480, 640))) == 2
    assert april.candidate_regions(np.r_[two[:2], two[:2]], (480, 640)) == []
    # scattered (clutter): no crowd, nothing searched
    assert april.candidate_regions(_squares(grid * 6.0 - 500, 11.0), (480, 640)) == []
    assert april.candidate_regions(_squares(grid, 2.0), (480, 640)) == []  # specks, not tags
    assert april.candidate_regions(_squares(grid, 40.0), (480, 640)) == []  # large: decodable at full size
    assert april.candidate_regions(np.zeros((0, 4, 2)), (480, 640)) == []
    # clipped to the image
    assert april.candidate_regions(_squares(grid - 100, 11.0), (480, 640))[0][:2] == (0, 0)


def test_undecoded_quads_of_a_board_already_found_are_left_to_its_own_search():
    """away_from: quads at a found board's other tags (where its found tags put them) are
    that board's; only those elsewhere can be a board with no tag found."""
    b = _grid()
    H = np.array([[300.0, 0.0, 50.0], [0.0, -300.0, 300.0], [0.0, 0.0, 1.0]])  # tags ~26 px
    px = cv2.perspectiveTransform(b.corners[:, :2].reshape(-1, 1, 2), H).reshape(-1, 4, 2)
    found = np.arange(8)
    quads = px[found][:, april.CV_TO_KALIBR]
    own = px[8:20]  # the same board's undecoded tags
    elsewhere = _squares(np.array([[500.0, 400.0], [515.0, 400.0], [500.0, 415.0]]), 11.0)
    kept = april.away_from(np.r_[own, elsewhere], [b], found, quads)
    np.testing.assert_array_equal(kept, elsewhere)
    assert len(april.away_from(np.r_[own, elsewhere], [b], found[:0], quads[:0])) == len(own) + 3


def test_a_corner_squares_centre_does_not_look_like_a_tag_corner():
    """The centre of a corner square is point-symmetric too: a corner refined onto it (a
    board near the fisheye's edge squashes the square to a few pixels: three corners 3 px off
    in a rendered room) must fail the check, where every true corner passes. There all four
    samples fall on the square, and the contrast is the noise's."""
    b, img, truth = _small_flat_print(40.0, 0.7)
    ids = np.arange(b.n_corners)
    ax, ay = april.corner_axes(ids, truth)
    box = april.symmetric_box(b, ax, ay)
    assert april.looks_like_a_tag_corner(img, ids, truth, ax, ay, box).all()
    contrast, normal = april.junction_contrast(img, ids, truth, ax, ay, box)
    assert normal and april.contrast_reference(contrast) > 100  # the print: 30 to 230 grey levels
    inner = (ids // 4 % 6 > 0) & (ids // 4 % 6 < 5) & (ids // 24 > 0) & (ids // 24 < 5)
    away = -april.TOWARDS_TAG[ids % 4] * (0.5 * b.tag_spacing)  # tag sizes along board x, y
    centres = truth + away[:, :1] * ax + away[:, 1:] * ay
    g, _ = april.junction_contrast(img, ids[inner], centres[inner], ax[inner], ay[inner], box, normal)
    assert np.abs(g).max() < 20, np.abs(g).max()  # all four samples on the square
    ok = april.looks_like_a_tag_corner(img, ids[inner], centres[inner], ax[inner], ay[inner], box, normal,
                                       april.contrast_reference(contrast))
    assert not ok.any(), ok.sum()
    # mixed in with true corners (the median contrast is theirs), the centres still fail
    both = np.r_[truth, centres[inner]]
    ok = april.looks_like_a_tag_corner(img, np.r_[ids, ids[inner]], both, np.r_[ax, ax[inner]],
                                       np.r_[ay, ay[inner]], box)
    assert ok[:len(ids)].all() and not ok[len(ids):].any()


def test_narrow_spacing_is_warned_about():
    t = parse_target(GRID.replace("tag_spacing: 0.3", "tag_spacing: 0.12") + CHARUCO_BOARD)
    (w,) = april.spacing_warnings(t.boards)
    assert w.startswith("board grid: tag_spacing 0.12 is under 0.17")
    assert april.spacing_warnings(parse_target(GRID).boards) == []


def test_kalibr_target_files_are_read_as_they_are():
    t = parse_target("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 5\ntagSize: 0.088\ntagSpacing: 0.3\n")
    b = t.boards[0]
    assert (b.type, b.name, b.squares, b.tag_size, b.tag_spacing) == ("aprilgrid", "grid", (6, 5), 0.088, 0.3)
    c = parse_target("target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\n"
                     "colSpacingMeters: 0.06\n").boards[0]
    assert (c.type, c.inner_corners, c.square_length) == ("chessboard", (6, 7), 0.06)


def test_round_trip():
    t = parse_target(GRID.replace("tag_spacing: 0.3", "tag_spacing: 0.3\n    first_tag_id: 40"))
    assert parse_target(dump_target(t)) == t


@pytest.mark.parametrize("text, where", [
    (GRID.replace("tags: [6, 6]", "tags: [30, 20]"), "AprilTag 36h11 holds ids 0..586"),
    (GRID.replace("tag_spacing: 0.3", "tag_spacing: 0.3\n    first_tag_id: 560"), "ids 560..595"),
    (GRID.replace("tag_size: 0.088", "tag_size: -0.088"), "boards[0].tag_size"),
    (GRID.replace("tag_spacing: 0.3", "tag_spacing: 0"), "boards[0].tag_spacing"),
    (GRID.replace("tag_spacing: 0.3", "tag_spacing: 3"), "boards[0].tag_spacing"),
    (GRID.replace("tag_size: 0.088", "tag_size: 88"), "millimetres"),
    (GRID.replace("tags: [6, 6]", "tags: [6]"), "boards[0].tags"),
    (GRID.replace("tag_spacing: 0.3", "tag_spacing: 0.3\n    square_length: 0.1"), "square_length"),
    (GRID + GRID.replace("boards:\n", "").replace("name: grid", "name: grid2"), "overlap"),
    ("target_type: circlegrid\n", "target_type"),
    ("target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\ncolSpacingMeters: 0.05\n",
     "colSpacingMeters"),
    ("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\n", "tagSpacing: missing"),
])
def test_bad_aprilgrid_targets_give_one_line(text, where, tmp_path):
    p = tmp_path / "target.yaml"
    p.write_text(text)
    with pytest.raises(TargetFileError) as e:
        load_target(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg and where in msg, msg


def test_aprilgrid_and_charuco_ids_may_coincide_across_dictionaries():
    text = GRID + """  - name: wall
    type: charuco
    dictionary: DICT_5X5_1000
    squares: [5, 4]
    square_length: 0.05
    marker_length: 0.035
"""
    assert parse_target(text).names == ("grid", "wall")


def _euroc_frame(cam: int) -> np.ndarray:
    return cv2.imread(str(EUROC / "images" / f"cam{cam}_1403709395937837056.png"), cv2.IMREAD_GRAYSCALE)


@euroc
@pytest.mark.parametrize("cam", [0, 1])
def test_real_euroc_frame_gives_all_144_corners_that_fit_euroc_intrinsics(cam):
    target = load_target(EUROC / "kalibr_target.yaml")
    board = target.boards[0]
    views, _ = BoardDetector(target).detect_with_sigma(_euroc_frame(cam))
    assert len(views) == 1
    _, ids, uv, _, _ = views[0]
    np.testing.assert_array_equal(ids, np.arange(144))
    ref = yaml.safe_load((EUROC / "reference.yaml").read_text())[f"cam{cam}"]
    fx, fy, cx, cy = ref["intrinsics"]
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    D = np.array(ref["distortion"], float)
    obj = board.corners[ids]
    ok, r, t = cv2.solvePnP(obj, uv, K, D)
    r, t = cv2.solvePnPRefineLM(obj, uv, K, D, r, t)
    err = np.linalg.norm(cv2.projectPoints(obj, r, t, K, D)[0].reshape(-1, 2) - uv, axis=1)
    # measured 0.16 / 0.15 px RMS, 0.44 / 0.37 max; a wrong id or corner order is tens of px
    assert np.sqrt(np.mean(err ** 2)) < 0.3 and err.max() < 1.0, (np.sqrt(np.mean(err ** 2)), err.max())
    # the board faces the camera: Kalibr's z comes out of the print, towards the camera
    R = cv2.Rodrigues(r)[0]
    assert (R.T @ -t.ravel())[2] > 0


@euroc
@pytest.mark.parametrize("cam", [0, 1])
def test_rendered_print_matches_the_real_kalibr_grid_bit_for_bit(cam):
    """Every bit cell of the 36 tags, read off the real frame where PnP puts it, is the colour
    rigcal prints (Board.image / april_tag_bits): same codes, same turn, same ids, same rows."""
    from rigcal.core.target import april_tag_bits

    target = load_target(EUROC / "kalibr_target.yaml")
    b = target.boards[0]
    gray = _euroc_frame(cam)
    _, ids, uv, _, _ = BoardDetector(target).detect_with_sigma(gray)[0][0]
    ref = yaml.safe_load((EUROC / "reference.yaml").read_text())[f"cam{cam}"]
    fx, fy, cx, cy = ref["intrinsics"]
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    D = np.array(ref["distortion"], float)
    _, r, t = cv2.solvePnP(b.corners[ids], uv, K, D)
    # cell (v, u) of tag t, v counted down the print: board y falls as v grows
    tag = np.arange(36)
    u, v = np.meshgrid(np.arange(10), np.arange(10))
    x = (tag % 6)[:, None, None] * b.square_length + (u[None] + 0.5) * b.tag_size / 10
    y = (tag // 6)[:, None, None] * b.square_length + b.tag_size - (v[None] + 0.5) * b.tag_size / 10
    p = np.stack([x, y, np.zeros_like(x)], -1).reshape(-1, 3)
    px = cv2.projectPoints(p, r, t, K, D)[0].reshape(1, -1, 2).astype(np.float32)
    val = cv2.remap(gray.astype(np.float32), px[..., 0], px[..., 1], cv2.INTER_LINEAR).ravel()
    black = (val < 0.5 * (np.percentile(val, 5) + np.percentile(val, 95))).reshape(36, 10, 10)
    np.testing.assert_array_equal(black, april_tag_bits(np.arange(36)))
