"""rigcal.core.target: target.yaml validation, board geometry against OpenCV, the exact raster."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from rigcal.errors import TargetFileError
from rigcal.core.target import Board, dump_target, load_target, parse_target, pixel_weights, save_target

CHARUCO = "{name: %s, type: charuco, dictionary: DICT_5X5_1000, squares: [5, 4], square_length: 0.05, marker_length: 0.035%s}"


def one(extra: str = "", name: str = "a") -> str:
    return "boards:\n  - " + CHARUCO % (name, extra) + "\n"


def test_charuco_board_fields_and_defaults():
    t = parse_target(one())
    b = t.boards[0]
    assert (b.type, b.squares, b.dictionary, b.first_marker_id, b.legacy_pattern) == ("charuco", (5, 4), "DICT_5X5_1000", 0, False)
    assert b.inner_corners == (4, 3) and b.n_corners == 12
    assert b.n_markers == 10 and list(b.marker_ids) == list(range(10))
    assert b.size_m == pytest.approx((0.25, 0.20))
    assert not b.symmetric
    assert t.board("a") is b
    with pytest.raises(KeyError):
        t.board("nope")


@pytest.mark.parametrize("legacy", [False, True])
@pytest.mark.parametrize("squares", [(5, 4), (6, 6), (7, 3)])
def test_corners_are_opencvs(legacy, squares):
    b = Board(name="a", type="charuco", square_length=0.05, squares=squares, dictionary="DICT_5X5_1000",
              marker_length=0.035, first_marker_id=17, legacy_pattern=legacy)
    cvb = b.cv_board()
    assert np.allclose(b.corners, cvb.getChessboardCorners(), atol=1e-7)
    assert list(np.asarray(cvb.getIds()).reshape(-1)) == list(b.marker_ids)
    assert cvb.getLegacyPattern() == legacy


@pytest.mark.parametrize("legacy", [False, True])
def test_image_equals_opencv_generate_image_at_integer_scale(legacy):
    # 60 px per square and 6 px per marker cell: OpenCV's own drawing is exact there.
    b = Board(name="a", type="charuco", square_length=0.05, squares=(5, 4), dictionary="DICT_5X5_1000",
              marker_length=0.035, first_marker_id=7, legacy_pattern=legacy)
    mine = b.image(60 / 0.05)
    ref = b.cv_board().generateImage((5 * 60, 4 * 60), marginSize=0, borderBits=1)
    assert mine.shape == ref.shape
    assert np.array_equal(mine, ref)


def test_image_scale_and_area_coverage_are_exact():
    b = parse_target(one()).boards[0]
    ppm, margin = 1234.5, 7
    img = b.coverage(ppm, margin)
    assert img.shape == (int(np.ceil(0.20 * ppm)) + 14, int(np.ceil(0.25 * ppm)) + 14)
    # total black area equals the design's black area, whatever the scale
    xs, ys, black = b._design
    area_m2 = float((np.diff(ys)[:, None] * np.diff(xs)[None, :] * black).sum())
    assert (1 - img).sum() / ppm**2 == pytest.approx(area_m2, rel=1e-5)
    # blurring keeps the area (it only moves grey around) and matches a numerical blur
    blurred = b.coverage(ppm, margin, blur_px=2.0)
    assert (1 - blurred).sum() == pytest.approx((1 - img).sum(), rel=1e-5)


def test_closed_form_blur_matches_numerical_blur():
    b = parse_target(one()).boards[0]
    ppm = 60 / 0.05
    fine = b.coverage(ppm * 8, 30 * 8).astype(np.float64)
    ref = cv2.resize(cv2.GaussianBlur(fine, (0, 0), 8 * 1.5, borderType=cv2.BORDER_REPLICATE),
                     (b.coverage(ppm, 30).shape[1], b.coverage(ppm, 30).shape[0]), interpolation=cv2.INTER_AREA)
    assert np.abs(b.coverage(ppm, 30, blur_px=1.5) - ref).max() < 1e-3


def test_pixel_weights_rows_sum_to_coverage_of_the_span():
    breaks = np.array([2.3, 5.0, 9.75])
    w0 = pixel_weights(12, breaks)
    assert np.allclose(w0.sum(axis=0), np.diff(breaks))
    w1 = pixel_weights(40, breaks + 10, blur_px=1.3)
    assert np.allclose(w1.sum(axis=0), np.diff(breaks), atol=1e-9)


@pytest.mark.parametrize("inner", [(9, 6), (8, 6), (7, 5)])
def test_chessboard_corner_order_is_findchessboardcorners(inner):
    t = parse_target(f"boards:\n  - {{type: chessboard, inner_corners: [{inner[0]}, {inner[1]}], square_length: 0.03}}\n")
    b = t.boards[0]
    assert b.name == "chessboard" and b.squares == (inner[0] + 1, inner[1] + 1)
    assert b.symmetric == ((inner[0] + inner[1]) % 2 == 0)
    ppm, margin = 40 / 0.03, 40
    ok, found = cv2.findChessboardCorners(b.image(ppm, margin), b.inner_corners)
    assert ok
    expected = b.corners[:, :2] * ppm + margin - 0.5  # OpenCV's pixel-centre convention
    assert np.abs(found.reshape(-1, 2) - expected).max() < 1e-6


def test_round_trip(tmp_path):
    text = ("boards:\n  - " + CHARUCO % ("front", ", first_marker_id: 0") + "\n  - "
            + CHARUCO % ("back", ", first_marker_id: 10, legacy_pattern: true") + "\n")
    t = parse_target(text)
    save_target(t, tmp_path / "t.yaml")
    assert load_target(tmp_path / "t.yaml") == t
    assert parse_target(dump_target(t)) == t
    chess = parse_target("boards:\n  - {name: c, type: chessboard, inner_corners: [9, 6], square_length: 0.03}\n")
    assert parse_target(dump_target(chess)) == chess


BAD = {
    "unknown dictionary": (one().replace("DICT_5X5_1000", "DICT_5X5_2000"),
                           "boards[0].dictionary: expected a cv2.aruco dictionary name", "did you mean DICT_5X5_1000"),
    "overlapping ids": (one(", first_marker_id: 0", "front") + "  - " + CHARUCO % ("back", ", first_marker_id: 5") + "\n",
                        "boards[1].first_marker_id", "'back' overlap those of board 'front'"),
    "too many markers": (one().replace("DICT_5X5_1000", "DICT_4X4_50").replace("[5, 4]", "[12, 9]"),
                         "boards[0]: needs marker ids 0..53", "DICT_4X4_50 holds ids 0..49"),
    "marker not smaller": (one().replace("marker_length: 0.035", "marker_length: 0.05"),
                           "boards[0].marker_length", "less than square_length"),
    "negative size": (one().replace("square_length: 0.05", "square_length: -0.05"),
                      "boards[0].square_length", "positive"),
    "millimetres": (one().replace("square_length: 0.05", "square_length: 50").replace("marker_length: 0.035",
                                                                                       "marker_length: 35"),
                    "boards[0].square_length", "expected metres (at most 2), got 50; in millimetres that is 0.05 m"),
    "zero marker": (one().replace("marker_length: 0.035", "marker_length: 0"), "boards[0].marker_length", "positive"),
    "nan": (one().replace("square_length: 0.05", "square_length: .nan"), "boards[0].square_length", "finite"),
    "unknown key": (one().replace("square_length", "square_lenght", 1), "boards[0].square_lenght", "did you mean `square_length`"),
    "missing key": (one().replace("dictionary: DICT_5X5_1000, ", ""), "boards[0].dictionary", "missing"),
    "missing type": ("boards:\n  - {name: a, squares: [5, 4]}\n", "boards[0].type", "missing"),
    "chessboard not alone": ("boards:\n  - {type: chessboard, inner_corners: [9, 6], square_length: 0.03}\n  - "
                             + CHARUCO % ("a", "") + "\n", "boards[0]", "only board"),
    "duplicate key": ("boards:\n  - {name: a, name: b, type: charuco}\n", "boards[0].name", "duplicate"),
    "duplicate name": (one(name="a") + "  - " + CHARUCO % ("a", ", first_marker_id: 10") + "\n", "boards[1].name", "already used"),
    "too few squares": (one().replace("[5, 4]", "[5, 1]"), "boards[0].squares", "at least 2"),
    "no boards": ("boards: []\n", "boards", "non-empty list"),
    "not yaml": ("boards: [\n", "not valid YAML", ""),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_targets_give_one_line_naming_file_and_key(case):
    text, where, what = BAD[case]
    with pytest.raises(TargetFileError) as e:
        parse_target(text, "t.yaml")
    msg = str(e.value)
    assert msg.startswith("t.yaml: ") and "\n" not in msg
    assert where in msg and what in msg


def test_missing_file(tmp_path):
    with pytest.raises(TargetFileError, match="file not found"):
        load_target(tmp_path / "none.yaml")


def test_board_is_picklable_and_cv_board_is_built_on_call():
    import pickle

    b = parse_target(one()).boards[0]
    b.corners  # cached arrays pickle fine
    b2 = pickle.loads(pickle.dumps(b))
    assert b2 == b and np.array_equal(b2.corners, b.corners)
    assert replace(b, first_marker_id=3).cv_board().getIds()[0] == 3
