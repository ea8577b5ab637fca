"""One board partly in front of another: the far board's corners at the near sheet's edge
are left out (detect/overlap.py), the near board keeps its own, boards apart are untouched."""

from __future__ import annotations

import numpy as np
import pytest

import rigcal.detect.board_detectors as board_detectors
from rigcal.core.target import Board, Target
from rigcal.detect.board_detectors import BoardDetector
from rigcal.detect.overlap import near_other_boards
from tests.detect.test_detect import render, truth

WALL = Board("wall", "charuco", 0.04, (9, 7), "DICT_5X5_1000", 0.03, first_marker_id=0)
HELD = Board("held", "charuco", 0.04, (7, 5), "DICT_5X5_1000", 0.03, first_marker_id=40)
PX_PER_M = 700.0  # 28 px squares
SHEET_MARGIN = 0.5  # paper around each print, squares (overlap.py assumes up to 1)


def similarity(x0: float, y0: float, spin: float) -> np.ndarray:
    """H: board (x, y, 1) -> pixel, a frontal view turned by `spin` rad."""
    c, s = np.cos(spin), np.sin(spin)
    return np.array([[PX_PER_M * c, -PX_PER_M * s, x0], [PX_PER_M * s, PX_PER_M * c, y0], [0, 0, 1.0]])


def sheet(board: Board, px_per_square: int = 64) -> tuple[tuple, tuple]:
    """(print, A) and (an all-ink sheet of the same size, A): A maps board (x, y, 1) to texels."""
    ppm = px_per_square / board.square_length
    m = int(SHEET_MARGIN * px_per_square)
    A = np.array([[ppm, 0, m - 0.5], [0, ppm, m - 0.5], [0, 0, 1.0]])
    img = board.image(ppm, m)
    return (img, A), (np.zeros_like(img), A)


def occluded_scene(spin: float, offset_px: float, corner: int = 36, seed: int = 0):
    """HELD hangs in front of WALL, the top edge of its sheet turned by `spin` and passing
    `offset_px` from WALL's corner `corner`. Returns the image, H_wall, H_held."""
    rng = np.random.default_rng(seed)
    H_wall = similarity(150, 60, 0.05)
    c = truth(WALL, H_wall, np.array([corner]))[0]
    d = np.array([np.cos(spin), np.sin(spin)])
    top_left = c - 120 * d + offset_px * np.array([-d[1], d[0]])  # the sheet's top-left corner
    R = np.array([[d[0], -d[1]], [d[1], d[0]]])
    t = top_left - R @ np.full(2, -SHEET_MARGIN * HELD.square_length) * PX_PER_M
    H_held = similarity(t[0], t[1], spin)
    wall = render(WALL, H_wall, rng, noise=0, blur=1.0, tex=sheet(WALL)[0]).astype(float)
    held = render(HELD, H_held, rng, noise=0, blur=1.0, tex=sheet(HELD)[0]).astype(float)
    ink = render(HELD, H_held, rng, noise=0, blur=1.0, tex=sheet(HELD)[1]).astype(float)
    alpha = np.clip((200.0 - ink) / 160.0, 0.0, 1.0)  # HELD's sheet coverage (ink 40, paper 200)
    img = alpha * held + (1 - alpha) * wall + rng.normal(0.0, 1.0, wall.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), H_wall, H_held


def errors(views, H: dict) -> dict:
    """board name -> (ids, (N,) px error against the truth)."""
    boards = {"wall": WALL, "held": HELD}
    return {n: (ids, np.linalg.norm(uv - truth(boards[n], H[n], ids), axis=1)) for n, ids, uv, _ in views}


@pytest.mark.parametrize("offset_px", [0.0, 2.0])
def test_far_board_corners_at_the_near_sheet_edge_are_left_out(offset_px, monkeypatch):
    img, H_wall, H_held = occluded_scene(0.45, offset_px)
    H = {"wall": H_wall, "held": H_held}
    detector = BoardDetector(Target((WALL, HELD)))
    got = errors(detector.detect(img)[0], H)
    monkeypatch.setattr(board_detectors, "near_other_boards",
                        lambda views, size: [np.zeros(len(v[1]), bool) for v in views])
    plain = errors(detector.detect(img)[0], H)
    # the scene is a real test: refined as if alone, a WALL corner at HELD's edge is 0.2 px off
    assert plain["wall"][1].max() > 0.15
    # those are left out, the rest of WALL is kept and as accurate as a lone board's corners
    assert 15 <= len(got["wall"][0]) < len(plain["wall"][0])
    assert got["wall"][1].max() < 0.03
    # HELD is in front (WALL's corners behind it are missing): it keeps every corner
    assert np.array_equal(got["held"][0], plain["held"][0])


def test_boards_apart_are_untouched():
    rng = np.random.default_rng(3)
    H_wall, H_held = similarity(20, 40, 0.05), similarity(380, 200, -0.1)
    wall = render(WALL, H_wall, rng, noise=0, blur=1.0, tex=sheet(WALL)[0]).astype(float)
    held = render(HELD, H_held, rng, noise=0, blur=1.0, tex=sheet(HELD)[0]).astype(float)
    img = np.clip(np.rint(np.minimum(wall, held) + rng.normal(0.0, 1.0, wall.shape)), 0, 255).astype(np.uint8)
    views = BoardDetector(Target((WALL, HELD))).detect(img)[0]
    assert {v[0] for v in views} == {"wall", "held"}
    boards = {"wall": WALL, "held": HELD}
    masks = near_other_boards([(boards[n], ids, uv) for n, ids, uv, _ in views], (img.shape[1], img.shape[0]))
    assert not any(m.any() for m in masks)
    assert not near_other_boards([(WALL, views[0][1], views[0][2])], (640, 480))[0].any()
