"""Why no board of the target shows in a camera's images, in words (for error paths).

Tries, on a few readable images: the target's dictionary (normal and inverted) and
whether its markers carry other ids; the other legacy_pattern; the squares swapped;
every other common dictionary; a plain chessboard. Slow (seconds).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from rigcal.detect.board_detectors import CLASSIC_FLAGS, FLAT_STD, CharucoGroup, as_ids
from rigcal.data.image_read import read_gray
from rigcal.core.target import Board, Target

MIN_CLAIM_MARKERS = 3  # a lone decode in clutter or noise does not name a dictionary
DIAGNOSE_DICTIONARIES = (
    "DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_4X4_1000",
    "DICT_5X5_50", "DICT_5X5_100", "DICT_5X5_250", "DICT_5X5_1000",
    "DICT_6X6_50", "DICT_6X6_100", "DICT_6X6_250", "DICT_6X6_1000",
    "DICT_7X7_50", "DICT_7X7_100", "DICT_7X7_250", "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_16h5", "DICT_APRILTAG_25h9", "DICT_APRILTAG_36h10",
    "DICT_APRILTAG_36h11", "DICT_ARUCO_MIP_36h12",
)


def _markers_of(gray: np.ndarray, dictionary: str, polarities: tuple[bool, ...] = (False, True)) -> np.ndarray:
    """Marker ids of a dictionary found in the image or (polarity True) in its inverse."""
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)),
                                  cv2.aruco.DetectorParameters())
    best = np.zeros(0, np.int64)
    for inverted in polarities:
        ids = as_ids(det.detectMarkers(cv2.bitwise_not(gray) if inverted else gray)[1])
        if len(ids) > len(best):
            best = ids
    return best


def _corner_count(gray: np.ndarray, board: Board) -> int:
    try:
        return sum(len(ids) for _, ids, _ in CharucoGroup(board.dictionary, [board]).detect(gray))
    except (cv2.error, ValueError):
        return 0


def _best_other_dictionary(grays: list[np.ndarray], wanted: set[str]) -> tuple[str, int, int] | None:
    """The common dictionary, other than `wanted`, with the most markers in these images:
    (name, markers found, highest id), or None. A big dictionary costs up to a second an image,
    so all are tried on the first image showing any marker (as printed, else inverted),
    and only those that found some on the rest, in that polarity. On a tie the later,
    bigger dictionary of a family wins (the smaller ones are its first codes, so both
    read the print)."""
    others = [d for d in DIAGNOSE_DICTIONARIES if d not in wanted]
    hits: list[str] = []
    for k, g in enumerate(grays):
        for polarity in ((False,), (True,)):
            first = {d: _markers_of(g, d, polarity) for d in others}
            hits = [d for d in others if len(first[d])]
            if hits:
                break
        if hits:
            break
    else:
        return None
    best = None
    for d in hits:
        ids = np.concatenate([first[d]] + [_markers_of(g, d, polarity) for g in grays[k + 1:]])
        if best is None or len(ids) >= best[1]:
            best = (d, len(ids), int(ids.max()))
    return best


def diagnose_no_detection(paths: Iterable[str | Path], target: Target, max_images: int = 4) -> str:
    """The most likely reason no board of `target` shows in these images, in words.

    Tries, on a few readable images: the target's dictionary (normal and inverted) and
    whether its markers carry other ids; the other legacy_pattern; the squares swapped;
    every other common dictionary; a plain chessboard. Slow (seconds): for error paths."""
    grays = _readable_grays(paths, max_images)
    if not grays:
        return "none of the images tried could be read or shows anything (all flat)"
    n = len(grays)
    charuco = [b for b in target.boards if b.type == "charuco"]
    wanted = {b.dictionary for b in charuco}
    found = {d: np.concatenate([_markers_of(g, d) for g in grays]) for d in wanted}
    in_range = sum(int(np.isin(found[b.dictionary], b.marker_ids).sum()) for b in charuco)
    # markers of the boards in every image: the dictionary is right (scanning the others takes seconds)
    best = _best_other_dictionary(grays, wanted) if in_range < 3 * n else None
    grids = [b.name for b in target.boards if b.type == "aprilgrid"]
    says = ("target.yaml says " + ", ".join(sorted(wanted) + [f"AprilGrid {n} (AprilTag 36h11)" for n in grids])
            if wanted or grids else "target.yaml describes a chessboard")
    # A wrong dictionary still decodes a few stray markers in the real ones' bit patterns
    # (DICT_4X4_1000 read in DICT_5X5_1000 prints): judge it by how many more the other finds.
    if (best is not None and best[1] >= MIN_CLAIM_MARKERS
            and best[1] > 2 * max((len(v) for v in found.values()), default=0)):
        return f"markers of {best[0]} found ({best[1]} in {n} images, ids up to {best[2]}); {says}"
    hints = []
    for b in charuco:
        if len(found[b.dictionary]) == 0:
            continue
        verdict, hint = _charuco_hint(b, found[b.dictionary], grays)
        if verdict is not None:
            return verdict
        hints.append(hint)
    if hints:
        return "; ".join(hints)
    return _chessboard_hint(target, grays) or (
        f"no ArUco markers of any common dictionary and no chessboard found in the {n} images tried "
        "(blurred, too dark, or the board too small?)")


def _readable_grays(paths: Iterable[str | Path], max_images: int) -> list[np.ndarray]:
    """The first max_images images that read and are not flat."""
    grays = []
    for p in paths:
        g, _ = read_gray(p)
        if g is not None and float(g.std()) >= FLAT_STD:
            grays.append(g)
        if len(grays) >= max_images:
            break
    return grays


def _charuco_hint(b: Board, ids: np.ndarray, grays: list[np.ndarray]) -> tuple[str | None, str]:
    """For a ChArUco board whose dictionary's markers (ids, at least one) were found: the
    verdict (its ids are not the board's, or a layout change makes corners appear) or
    None, and the hint to give when no board has a verdict."""
    lo, hi = b.first_marker_id, b.first_marker_id + b.n_markers - 1
    inside = ids[(ids >= lo) & (ids <= hi)]
    if len(inside) == 0:
        return (f"markers of {b.dictionary} found with ids {ids.min()}..{ids.max()}, but board {b.name} uses ids "
                f"{lo}..{hi}: check first_marker_id and squares"), ""
    for change, alt in ((f"legacy_pattern: {str(not b.legacy_pattern).lower()}",
                         replace(b, legacy_pattern=not b.legacy_pattern)),
                        (f"squares: [{b.squares[1]}, {b.squares[0]}]", replace(b, squares=b.squares[::-1]))):
        if sum(_corner_count(g, alt) for g in grays):
            return f"board {b.name}: its markers are found and corners appear with {change}", ""
    return None, (f"markers of board {b.name} ({b.dictionary}, ids {inside.min()}..{inside.max()}) are found "
                  f"but no corners: check squares, marker_length and legacy_pattern")


def _chessboard_hint(target: Target, grays: list[np.ndarray]) -> str | None:
    """A plain chessboard near a board's declared size found in the images, in words, or None."""
    for b in target.boards:
        if b.type == "aprilgrid":
            continue  # its corner lattice is no chessboard
        nx, ny = b.inner_corners
        # the board as declared (a ChArUco printed without markers), or one off along either axis;
        # OpenCV needs at least 3 inner corners each way (it raises below that)
        patterns = sorted({(nx + i, ny + j) for i in (-1, 0, 1) for j in (-1, 0, 1)},
                          key=lambda q: (abs(q[0] - nx) + abs(q[1] - ny), q))
        for pattern in patterns:
            if b.type == "chessboard" and pattern == (nx, ny):
                continue
            if min(pattern) < 3:
                continue
            if any(cv2.findChessboardCorners(g, pattern, flags=CLASSIC_FLAGS)[0] for g in grays):
                what = "squares" if b.type == "charuco" else "inner_corners"
                return (f"a plain chessboard with {pattern[0]}x{pattern[1]} inner corners is found "
                        f"(target.yaml: board {b.name}, {b.type}, {what} {list(b.squares if b.type == 'charuco' else b.inner_corners)})")
    return None
