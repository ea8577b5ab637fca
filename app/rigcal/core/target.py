"""Calibration targets: target.yaml (docs/formats.md#dataset), board geometry, printable boards.

Board coordinates are OpenCV's (`CharucoBoard.getChessboardCorners()`): origin at
the top-left *outer* corner of the print, x right along the print, y down the
print, z into the printed face; metres.

The printed face is rasterised here by exact area coverage (each pixel's grey is
the fraction of its area that is white), so a board image at any scale carries
its geometry exactly: an edge between pixels is where it should be to within
the 8-bit grey quantisation, not to within a pixel. The renderer uses the same
rasteriser for its textures, and `rigcal board` for print.
"""

from __future__ import annotations

import difflib
import math
import re
import struct
import zlib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from scipy.special import ndtr

from rigcal.errors import InputError, OutputError, TargetFileError
from rigcal.core.io import atomic_write_bytes, atomic_write_text
from rigcal.core.rig import load_yaml
from rigcal.core.validate import describe, positive_number, read_text, refuse_unknown_keys

TYPES = ("charuco", "chessboard", "aprilgrid")
TOP_KEYS = ("boards",)
# A printed square longer than this is a length in millimetres or centimetres: taken as
# metres it would scale every calibrated position by 100-1000x without another sign.
MAX_SQUARE_M = 2.0
CHARUCO_KEYS = ("name", "type", "dictionary", "squares", "square_length", "marker_length", "first_marker_id",
                "legacy_pattern")
CHESSBOARD_KEYS = ("name", "type", "inner_corners", "square_length")
APRILGRID_KEYS = ("name", "type", "tags", "tag_size", "tag_spacing", "first_tag_id")
# Kalibr's AprilGrid: AprilTag 36h11 (587 codes) drawn with a 2-bit black border.
APRIL_DICTIONARY = "DICT_APRILTAG_36h11"
APRIL_BORDER_BITS = 2
KALIBR_GRID_NAME = "grid"  # the board name a Kalibr aprilgrid file gets (corners/ files name it)
# Kalibr target files (target_type: ...), read as they are.
KALIBR_APRILGRID_KEYS = ("target_type", "tagCols", "tagRows", "tagSize", "tagSpacing")
KALIBR_CHECKER_KEYS = ("target_type", "targetCols", "targetRows", "rowSpacingMeters", "colSpacingMeters")
NAME_RE = re.compile(r"^[A-Za-z0-9_.-]+$")
DICTIONARIES = tuple(sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_")))
MAX_PRINT_PX = 30000  # per side; a bigger raster is a mistake (dpi or size), not a print


@dataclass(frozen=True)
class Board:
    """One planar target. `squares` counts squares along board x and y (a chessboard's
    inner corners are squares - 1).

    An AprilGrid (Kalibr's target) is held in the same fields: `squares` = tags [cols,
    rows], `marker_length` = tag_size, `square_length` = the tag pitch tag_size * (1 +
    tag_spacing), `first_marker_id` = first_tag_id, `dictionary` = DICT_APRILTAG_36h11.
    Its board frame is Kalibr's, not the print's (see `T_board_print`)."""

    name: str
    type: str  # "charuco" | "chessboard" | "aprilgrid"
    square_length: float  # metres
    squares: tuple[int, int]
    dictionary: str | None = None
    marker_length: float | None = None
    first_marker_id: int = 0
    legacy_pattern: bool = False
    tag_spacing: float = 0.0  # aprilgrid only: gap between tags / tag size

    @classmethod
    def aprilgrid(cls, name: str, tags: tuple[int, int], tag_size: float, tag_spacing: float,
                  first_tag_id: int = 0) -> "Board":
        """Kalibr's AprilGrid of tags [cols, rows] (see the class docstring)."""
        return cls(name=name, type="aprilgrid", square_length=tag_size * (1.0 + tag_spacing),
                   squares=(int(tags[0]), int(tags[1])), dictionary=APRIL_DICTIONARY,
                   marker_length=float(tag_size), first_marker_id=int(first_tag_id),
                   tag_spacing=float(tag_spacing))

    @property
    def tag_size(self) -> float:
        """AprilGrid: the outer edge of a tag's black border, metres."""
        return float(self.marker_length)

    @property
    def gap(self) -> float:
        """AprilGrid: the white gap between tags (= the corner squares' side), metres."""
        return self.tag_spacing * self.tag_size

    @property
    def inner_corners(self) -> tuple[int, int]:
        """Chessboard/ChArUco: the inner corner grid. AprilGrid: its 2 cols x 2 rows corner lattice."""
        if self.type == "aprilgrid":
            return (2 * self.squares[0], 2 * self.squares[1])
        return (self.squares[0] - 1, self.squares[1] - 1)

    @property
    def n_corners(self) -> int:
        nx, ny = self.inner_corners
        return nx * ny

    @property
    def n_markers(self) -> int:
        if self.type == "aprilgrid":
            return self.squares[0] * self.squares[1]
        # ChArUco puts a marker in every white square: half of them, rounded down.
        return (self.squares[0] * self.squares[1]) // 2 if self.type == "charuco" else 0

    @property
    def marker_ids(self) -> np.ndarray:
        """(M,) int: first_marker_id .. first_marker_id + M - 1 (empty for a chessboard)."""
        return np.arange(self.first_marker_id, self.first_marker_id + self.n_markers, dtype=int)

    @property
    def symmetric(self) -> bool:
        """A chessboard that looks the same turned by 180 degrees (ambiguous corner order)."""
        return self.type == "chessboard" and (self.squares[0] + self.squares[1]) % 2 == 0

    @property
    def size_m(self) -> tuple[float, float]:
        """Outer width and height of the pattern in metres (AprilGrid: including the outer
        corner squares)."""
        if self.type == "aprilgrid":
            return tuple(n * self.square_length + self.gap for n in self.squares)
        return (self.squares[0] * self.square_length, self.squares[1] * self.square_length)

    @property
    def T_board_print(self) -> np.ndarray:
        """(4, 4) the print frame in the board frame: p_board = T_board_print @ p_print.

        The print frame is OpenCV's (origin at the pattern's top-left outer corner, x right,
        y down the print, z into the face); textures, `image` and the renderer use it. It is
        the board frame itself except for an AprilGrid, whose board frame is Kalibr's
        (origin at tag 0's bottom-left corner, x right, y up, z out of the face): a turn of
        180 degrees about x and a shift."""
        T = np.eye(4)
        if self.type == "aprilgrid":
            T[:3, :3] = np.diag([1.0, -1.0, -1.0])
            T[:3, 3] = [-self.gap, self.size_m[1] - self.gap, 0.0]
        return T

    @property
    def print_face(self) -> float:
        """The sign of board z on the printed side: -1 for OpenCV's frame, +1 for Kalibr's."""
        return float(-self.T_board_print[2, 2])

    @cached_property
    def corners(self) -> np.ndarray:
        """(N, 3) board-frame corner positions in metres; row index == corner id.

        Row-major over the inner corners, x fastest, starting next to the top-left
        outer corner: exactly OpenCV's getChessboardCorners() for ChArUco.
        AprilGrid (Kalibr): id 4 t + k is corner k (bottom-left, bottom-right, top-right,
        top-left) of the t-th tag, tag t at column t % cols, row t // cols from the bottom."""
        if self.type == "aprilgrid":
            return _aprilgrid_corners(self.squares[0], self.squares[1], self.tag_size, self.square_length)
        nx, ny = self.inner_corners
        k = np.arange(nx * ny)
        s = self.square_length
        out = np.zeros((nx * ny, 3))
        out[:, 0] = (k % nx + 1) * s
        out[:, 1] = (k // nx + 1) * s
        return out

    def cv_board(self) -> "cv2.aruco.CharucoBoard":
        """OpenCV's board with this board's ids and layout (built on call: not picklable)."""
        if self.type != "charuco":
            raise ValueError(f"board {self.name} is a {self.type}; it has no ChArUco board")
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        b = cv2.aruco.CharucoBoard(self.squares, self.square_length, self.marker_length, d,
                                   self.marker_ids.astype(np.int32))
        b.setLegacyPattern(self.legacy_pattern)
        return b

    @cached_property
    def _design(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The printed face as a piecewise-constant grid: x breaks (Gx,), y breaks (Gy,) in
        metres and black fraction (Gy-1, Gx-1) of each cell (1 black, 0 white)."""
        return _board_design(self)

    def image(self, px_per_m: float, margin_px: int = 0) -> np.ndarray:
        """The printed face, uint8 (H, W), 0 black 255 white, white margin around it.

        Pixel (i, j) covers board x in [(i - margin_px) / px_per_m, (i + 1 - margin_px) / px_per_m)
        and likewise y, so board point (x, y) is at pixel x * px_per_m + margin_px - 0.5
        in OpenCV's pixel-centre convention. Grey levels are exact area coverage."""
        return np.clip(np.rint(self.coverage(px_per_m, margin_px) * 255.0), 0, 255).astype(np.uint8)

    def coverage(self, px_per_m: float, margin_px: int = 0, blur_px: float = 0.0) -> np.ndarray:
        """Float (H, W) in [0, 1]: the fraction of each pixel that is white (see `image`).

        With blur_px > 0 the printed face is first convolved with a Gaussian of that sigma
        (pixels), evaluated in closed form, so the result is still exact (no kernel
        truncation or resampling). Everything outside the pattern counts as white."""
        return 1.0 - self.black_fraction(px_per_m, margin_px, blur_px)

    def black_fraction(self, px_per_m: float, margin_px: int = 0, blur_px: float = 0.0) -> np.ndarray:
        """Float32 (H, W): 1 - coverage(...), the fraction of each pixel that is printed black."""
        if not (px_per_m > 0 and math.isfinite(px_per_m)):
            raise ValueError(f"px_per_m must be a positive number, got {px_per_m!r}")
        w_m, h_m = self.size_m
        width = int(math.ceil(w_m * px_per_m - 1e-9)) + 2 * margin_px
        height = int(math.ceil(h_m * px_per_m - 1e-9)) + 2 * margin_px
        xs, ys, black = self._design
        Ax = pixel_weights(width, xs * px_per_m + margin_px, blur_px)  # (W, Gx-1)
        Ay = pixel_weights(height, ys * px_per_m + margin_px, blur_px)  # (H, Gy-1)
        # contiguous float32 operands: numpy's matmul skips BLAS for a transposed view
        black_x = black.astype(np.float32) @ np.ascontiguousarray(Ax.T, dtype=np.float32)
        return np.ascontiguousarray(Ay, dtype=np.float32) @ black_x


@dataclass(frozen=True)
class Target:
    """The calibration target: its boards (target.yaml, one or several)."""

    boards: tuple[Board, ...]

    def board(self, name: str) -> Board:
        for b in self.boards:
            if b.name == name:
                return b
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.boards)


# ----------------------------------------------------------------------------- rasterising


def pixel_weights(n_px: int, breaks_px: np.ndarray, blur_px: float = 0.0) -> np.ndarray:
    """(n_px, len(breaks) - 1): how much of interval [b_j, b_j+1) pixel i = [i, i+1) sees.

    Without blur, the overlap length. With a Gaussian blur of sigma blur_px, the mean over
    the pixel of the blurred interval indicator, in closed form: with
    G(t) = t Phi(t / s) + s phi(t / s) (the integral of the Gaussian CDF), it is
    G(i+1-a) - G(i-a) - G(i+1-b) + G(i-b) for the interval [a, b)."""
    lo = np.arange(n_px, dtype=float)[:, None]
    if blur_px <= 0:
        return np.clip(np.minimum(lo + 1.0, breaks_px[None, 1:]) - np.maximum(lo, breaks_px[None, :-1]), 0.0, None)
    s = float(blur_px)
    # G at every pixel edge k = 0..n_px for every break; G(t) = max(t, 0) to double precision
    # beyond 9 sigma, so the Gaussian terms are only evaluated near the breaks.
    t = np.arange(n_px + 1, dtype=float)[:, None] - breaks_px[None, :]
    g = np.maximum(t, 0.0)
    near = np.abs(t) < 9.0 * s
    tn = t[near] / s
    g[near] = s * (tn * ndtr(tn) + np.exp(-0.5 * tn * tn) / math.sqrt(2 * math.pi))
    edge = g[1:] - g[:-1]  # (n_px, n_breaks): mean over pixel i of Phi((x - b) / s)
    return edge[:, :-1] - edge[:, 1:]


def _aprilgrid_corners(cols: int, rows: int, tag_size: float, pitch: float) -> np.ndarray:
    """(4 cols rows, 3) Kalibr's corner positions (see Board.corners)."""
    t = np.arange(cols * rows)
    k = np.arange(4)
    x = (t[:, None] % cols) * pitch + np.array([0.0, 1.0, 1.0, 0.0])[k] * tag_size
    y = (t[:, None] // cols) * pitch + np.array([0.0, 0.0, 1.0, 1.0])[k] * tag_size
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def april_tag_bits(ids: np.ndarray) -> np.ndarray:
    """(M, 10, 10) bool, True black: 36h11 tags with a 2-bit border, as printed, rows down
    the print. Kalibr draws each code turned by 180 degrees from OpenCV's marker image."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, APRIL_DICTIONARY))
    cells = d.markerSize + 2 * APRIL_BORDER_BITS
    img = np.stack([cv2.aruco.generateImageMarker(d, int(i), cells, borderBits=APRIL_BORDER_BITS) for i in ids])
    return img[:, ::-1, ::-1] < 128


def _aprilgrid_design(board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """_board_design for an AprilGrid, in print coordinates: a gap, then per tag its 10
    cells and a gap; black corner squares in every gap crossing."""
    cols, rows = board.squares
    s, g, pitch = board.tag_size, board.gap, board.square_length
    cells = np.linspace(0.0, s, 11)
    xs = np.unique(np.concatenate([[0.0], (g + np.arange(cols)[:, None] * pitch + np.concatenate([cells, [s + g]])).ravel()]))
    ys = np.unique(np.concatenate([[0.0], (g + np.arange(rows)[:, None] * pitch + np.concatenate([cells, [s + g]])).ravel()]))
    cx, cy = np.meshgrid(0.5 * (xs[1:] + xs[:-1]), 0.5 * (ys[1:] + ys[:-1]))
    # position inside the repeating pitch: [0, g) gap, [g, g + s) tag
    ix, iy = np.floor(cx / pitch).astype(int), np.floor(cy / pitch).astype(int)
    ox, oy = cx - ix * pitch, cy - iy * pitch
    in_x, in_y = (ox >= g) & (ix < cols), (oy >= g) & (iy < rows)
    black = (~in_x & ~in_y).astype(float)  # gap crossings: the corner squares
    tag = in_x & in_y
    row_from_bottom = rows - 1 - iy[tag]  # print rows go down, Kalibr's rows go up
    tag_index = row_from_bottom * cols + ix[tag]
    bits = april_tag_bits(board.first_marker_id + np.arange(cols * rows))
    u = np.minimum(((ox[tag] - g) / s * 10).astype(int), 9)
    v = np.minimum(((oy[tag] - g) / s * 10).astype(int), 9)
    black[tag] = bits[tag_index, v, u]
    return xs, ys, black


def _board_design(board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if board.type == "aprilgrid":
        return _aprilgrid_design(board)
    s = board.square_length
    nx, ny = board.squares
    square_breaks_x = np.arange(nx + 1) * s
    square_breaks_y = np.arange(ny + 1) * s
    if board.type == "chessboard":
        jj, ii = np.mgrid[0:ny, 0:nx]
        # OpenCV's chessboard convention: the top-left square is black.
        return square_breaks_x, square_breaks_y, ((ii + jj) % 2 == 0).astype(float)

    cvb = board.cv_board()
    d = cvb.getDictionary()
    cells = d.markerSize + 2  # marker bits plus the one-bit black border
    m = board.marker_length
    # Where each marker sits, taken from OpenCV's own layout (legacy or not); the
    # float32 object points only pick the square, the offsets are recomputed in float64.
    obj = np.array(cvb.getObjPoints(), dtype=float)  # (M, 4, 3)
    sq_i = np.floor((obj[:, 0, 0] + 0.5 * s) / s).astype(int)
    sq_j = np.floor((obj[:, 0, 1] + 0.5 * s) / s).astype(int)
    ids = np.asarray(cvb.getIds()).reshape(-1)
    bits = np.stack([cv2.aruco.generateImageMarker(d, int(i), cells, borderBits=1) for i in ids]) < 128

    inset = np.linspace(0.0, m, cells + 1) + (s - m) / 2.0
    xs = np.unique(np.concatenate([square_breaks_x, (np.arange(nx)[:, None] * s + inset).ravel()]))
    ys = np.unique(np.concatenate([square_breaks_y, (np.arange(ny)[:, None] * s + inset).ravel()]))
    cx = 0.5 * (xs[1:] + xs[:-1])
    cy = 0.5 * (ys[1:] + ys[:-1])
    gx, gy = np.meshgrid(cx, cy)
    si = np.minimum((gx // s).astype(int), nx - 1)
    sj = np.minimum((gy // s).astype(int), ny - 1)
    marker_at = np.full((ny, nx), -1)
    marker_at[sq_j, sq_i] = np.arange(len(ids))
    k = marker_at[sj, si]
    black = (k < 0).astype(float)  # squares without a marker are the black ones
    cell = m / cells
    u = np.floor((gx - si * s - (s - m) / 2.0) / cell).astype(int)
    v = np.floor((gy - sj * s - (s - m) / 2.0) / cell).astype(int)
    inside = (k >= 0) & (u >= 0) & (u < cells) & (v >= 0) & (v < cells)
    black[inside] = bits[k[inside], v[inside], u[inside]]
    return xs, ys, black


# ----------------------------------------------------------------------------- loading


def load_target(path: str | Path) -> Target:
    """Read and validate target.yaml; raises TargetFileError `file: key: what was expected`."""
    return parse_target(read_text(path, TargetFileError), str(path))


def parse_target(text: str, label: str = "<target>") -> Target:
    # rig.load_yaml refuses duplicate keys, alias bombs and PyYAML's leaked errors.
    return target_from_dict(load_yaml(text, label, TargetFileError), label)


def target_from_dict(doc: Any, label: str = "<target>") -> Target:
    def err(key: str, msg: str) -> TargetFileError:
        return TargetFileError(f"{label}: {key}: {msg}" if key else f"{label}: {msg}")

    if not isinstance(doc, dict):
        raise err("", f"expected a mapping with `boards`, got {describe(doc)}")
    if "target_type" in doc:
        return Target(boards=(_kalibr_board(doc, err),))
    refuse_unknown_keys(doc, TOP_KEYS, "", err)
    if "boards" not in doc:
        raise err("boards", "missing (expected a list of boards)")
    raw = doc["boards"]
    if not isinstance(raw, list) or not raw:
        raise err("boards", f"expected a non-empty list of boards, got {describe(raw)}")
    boards = tuple(_board_from_dict(b, f"boards[{i}]", err) for i, b in enumerate(raw))
    _check_together(boards, err)
    return Target(boards=boards)


def _board_from_dict(d: Any, key: str, err) -> Board:
    if not isinstance(d, dict):
        raise err(key, f"expected a mapping, got {describe(d)}")
    if "type" not in d:
        raise err(f"{key}.type", f"missing (expected one of {', '.join(TYPES)})")
    typ = d["type"]
    if typ not in TYPES:
        raise err(f"{key}.type", f"expected one of {', '.join(TYPES)}, got {describe(typ)}")
    allowed = {"charuco": CHARUCO_KEYS, "chessboard": CHESSBOARD_KEYS, "aprilgrid": APRILGRID_KEYS}[typ]
    refuse_unknown_keys(d, allowed, key, err)
    if "name" not in d and typ != "chessboard":
        raise err(f"{key}.name", "missing (expected a board name)")
    name = d.get("name", "chessboard")
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise err(f"{key}.name", f"expected a name of letters, digits, '_', '.', '-', got {describe(name)}")
    if typ == "aprilgrid":
        return _aprilgrid_from_dict(d, name, key, err)
    square = positive_number(_required(d, "square_length", key, err, "a length in metres"), f"{key}.square_length", err)
    if square > MAX_SQUARE_M:
        raise err(f"{key}.square_length", f"expected metres (at most {MAX_SQUARE_M:g}), got {square:g}; in "
                  f"millimetres that is {square / 1000:g} m")
    if typ == "chessboard":
        inner = _int_pair(_required(d, "inner_corners", key, err, "[nx, ny] inner corners"),
                          f"{key}.inner_corners", 3, err)
        return Board(name=name, type="chessboard", square_length=square, squares=(inner[0] + 1, inner[1] + 1))

    dict_name = _required(d, "dictionary", key, err, "a cv2.aruco dictionary name such as DICT_5X5_1000")
    if not isinstance(dict_name, str) or dict_name not in DICTIONARIES:
        hint = difflib.get_close_matches(str(dict_name), DICTIONARIES, n=1, cutoff=0.6)
        raise err(f"{key}.dictionary", f"expected a cv2.aruco dictionary name (e.g. DICT_5X5_1000), got {describe(dict_name)}"
                  + (f" (did you mean {hint[0]}?)" if hint else ""))
    squares = _int_pair(_required(d, "squares", key, err, "[nx, ny] squares"), f"{key}.squares", 2, err)
    marker = positive_number(_required(d, "marker_length", key, err, "a length in metres"), f"{key}.marker_length", err)
    if marker >= square:
        raise err(f"{key}.marker_length", f"expected less than square_length ({square:g}), got {marker:g}")
    first = d.get("first_marker_id", 0)
    if isinstance(first, bool) or not isinstance(first, int) or first < 0:
        raise err(f"{key}.first_marker_id", f"expected a non-negative integer, got {describe(first)}")
    legacy = d.get("legacy_pattern", False)
    if not isinstance(legacy, bool):
        raise err(f"{key}.legacy_pattern", f"expected true or false, got {describe(legacy)}")
    board = Board(name=name, type="charuco", square_length=square, squares=squares, dictionary=dict_name,
                  marker_length=marker, first_marker_id=first, legacy_pattern=legacy)
    size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dict_name)).bytesList.shape[0]
    if first + board.n_markers > size:
        raise err(key, f"needs marker ids {first}..{first + board.n_markers - 1} ({board.n_markers} markers) "
                       f"but {dict_name} holds ids 0..{size - 1}")
    return board


def _aprilgrid_from_dict(d: dict, name: str, key: str, err) -> Board:
    tags = _int_pair(_required(d, "tags", key, err, "[cols, rows] tags"), f"{key}.tags", 1, err)
    size = _metres(_required(d, "tag_size", key, err, "a length in metres"), f"{key}.tag_size", err)
    spacing = positive_number(_required(d, "tag_spacing", key, err, "the gap between tags / tag_size, e.g. 0.3"),
                        f"{key}.tag_spacing", err)
    if spacing > 1.0:
        raise err(f"{key}.tag_spacing", f"expected the gap as a fraction of tag_size (0 < spacing <= 1), got {spacing:g}")
    first = d.get("first_tag_id", 0)
    if isinstance(first, bool) or not isinstance(first, int) or first < 0:
        raise err(f"{key}.first_tag_id", f"expected a non-negative integer, got {describe(first)}")
    board = Board.aprilgrid(name, tags, size, spacing, first)
    n_codes = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, APRIL_DICTIONARY)).bytesList.shape[0]
    if first + board.n_markers > n_codes:
        raise err(key, f"needs tag ids {first}..{first + board.n_markers - 1} ({tags[0]}x{tags[1]} tags) "
                       f"but AprilTag 36h11 holds ids 0..{n_codes - 1}")
    return board


def _kalibr_board(doc: dict, err) -> Board:
    """A Kalibr target file as it is: target_type aprilgrid or checkerboard."""
    typ = doc["target_type"]

    def need(k: str, what: str) -> Any:
        if k not in doc:
            raise err(k, f"missing (expected {what})")
        return doc[k]

    if typ == "aprilgrid":
        refuse_unknown_keys(doc, KALIBR_APRILGRID_KEYS, "", err)
        d = {"name": KALIBR_GRID_NAME, "type": "aprilgrid",
             "tags": [need("tagCols", "the number of tag columns"),
                      need("tagRows", "the number of tag rows")],
             "tag_size": need("tagSize", "the tag size in metres"),
             "tag_spacing": need("tagSpacing", "the gap between tags / tagSize")}
        return _board_from_dict(d, "Kalibr aprilgrid", err)
    if typ == "checkerboard":
        refuse_unknown_keys(doc, KALIBR_CHECKER_KEYS, "", err)
        row = _metres(need("rowSpacingMeters", "the square size in metres"), "rowSpacingMeters", err)
        col = _metres(doc.get("colSpacingMeters", row), "colSpacingMeters", err)
        if abs(col - row) > 1e-9 * max(col, row):
            raise err("colSpacingMeters", f"expected square squares (rowSpacingMeters {row:g}), got {col:g}")
        d = {"type": "chessboard",
             "inner_corners": [need("targetCols", "inner corners along x"),
                               need("targetRows", "inner corners along y")],
             "square_length": row}
        return _board_from_dict(d, "Kalibr checkerboard", err)
    raise err("target_type", f"expected aprilgrid or checkerboard (Kalibr target types rigcal reads), got {describe(typ)}")


def _metres(v: Any, key: str, err) -> float:
    x = positive_number(v, key, err)
    if x > MAX_SQUARE_M:
        raise err(key, f"expected metres (at most {MAX_SQUARE_M:g}), got {x:g}; in millimetres that is {x / 1000:g} m")
    return x


def _check_together(boards: tuple[Board, ...], err) -> None:
    names = [b.name for b in boards]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise err(f"boards[{i}].name", f"board name {n!r} is already used by boards[{names.index(n)}]")
    if any(b.type == "chessboard" for b in boards) and len(boards) > 1:
        i = next(i for i, b in enumerate(boards) if b.type == "chessboard")
        raise err(f"boards[{i}]", f"a chessboard must be the only board of a target, got {len(boards)} boards")
    for i, a in enumerate(boards):
        for j in range(i):
            b = boards[j]
            if "aprilgrid" in (a.type, b.type) and a.dictionary != b.dictionary:
                continue  # different dictionaries are detected apart: their ids cannot clash
            lo = max(a.first_marker_id, b.first_marker_id)
            hi = min(a.first_marker_id + a.n_markers, b.first_marker_id + b.n_markers) - 1
            if lo <= hi:
                key = "first_tag_id" if a.type == "aprilgrid" else "first_marker_id"
                raise err(f"boards[{i}].{key}",
                          f"marker ids {lo}..{hi} of board {a.name!r} overlap those of board {b.name!r} "
                          f"(ids {b.first_marker_id}..{b.first_marker_id + b.n_markers - 1}); ids must be disjoint")


def _required(d: dict, k: str, key: str, err, what: str) -> Any:
    if k not in d:
        raise err(f"{key}.{k}", f"missing (expected {what})")
    return d[k]










def _int_pair(v: Any, key: str, least: int, err) -> tuple[int, int]:
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(isinstance(x, int) and not isinstance(x, bool) for x in v)):
        raise err(key, f"expected two integers [nx, ny], got {describe(v)}")
    if min(v) < least:
        raise err(key, f"expected at least {least} in each direction, got {list(v)}")
    return (int(v[0]), int(v[1]))


# ----------------------------------------------------------------------------- saving


def target_to_dict(target: Target) -> dict:
    boards = []
    for b in target.boards:
        if b.type == "chessboard":
            boards.append({"name": b.name, "type": "chessboard", "inner_corners": list(b.inner_corners),
                           "square_length": float(b.square_length)})
        elif b.type == "aprilgrid":
            boards.append({"name": b.name, "type": "aprilgrid", "tags": list(b.squares), "tag_size": b.tag_size,
                           "tag_spacing": float(b.tag_spacing), "first_tag_id": int(b.first_marker_id)})
        else:
            boards.append({"name": b.name, "type": "charuco", "dictionary": b.dictionary,
                           "squares": list(b.squares), "square_length": float(b.square_length),
                           "marker_length": float(b.marker_length), "first_marker_id": int(b.first_marker_id),
                           "legacy_pattern": bool(b.legacy_pattern)})
    return {"boards": boards}


def dump_target(target: Target) -> str:
    return yaml.safe_dump(target_to_dict(target), sort_keys=False, default_flow_style=None, width=120)


def save_target(target: Target, path: str | Path) -> None:
    atomic_write_text(path, dump_target(target))


# ----------------------------------------------------------------------------- printing


def board_label(board: Board) -> str:
    w, h = board.size_m
    if board.type == "chessboard":
        nx, ny = board.inner_corners
        what = f"chessboard {nx}x{ny} inner corners, squares {board.square_length * 1000:g} mm"
    elif board.type == "aprilgrid":
        what = (f"AprilGrid {board.squares[0]}x{board.squares[1]} tags {board.tag_size * 1000:g} mm, spacing "
                f"{board.tag_spacing:g}, 36h11 ids {board.first_marker_id}-{board.first_marker_id + board.n_markers - 1}")
    else:
        what = (f"ChArUco {board.squares[0]}x{board.squares[1]} squares {board.square_length * 1000:g} mm, "
                f"markers {board.marker_length * 1000:g} mm, {board.dictionary} ids "
                f"{board.first_marker_id}-{board.first_marker_id + board.n_markers - 1}"
                + (", legacy pattern" if board.legacy_pattern else ""))
    return f"{board.name}: {what}; {w * 1000:g} x {h * 1000:g} mm"


def print_image(board: Board, dpi: float, margin_in: float = 0.5) -> np.ndarray:
    """The board at exactly dpi / 0.0254 px per metre inside a white margin of margin_in
    inches, with its name, size and dictionary written in the bottom margin. uint8 (H, W)."""
    px_per_m = dpi / 0.0254
    margin_px = max(1, int(round(margin_in * dpi)))
    img = board.image(px_per_m, margin_px)
    text = board_label(board) + f"; print at {dpi:g} dpi, 100% scale"
    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, th), _ = cv2.getTextSize(text, font, 1.0, 2)
    avail_w = img.shape[1] - 2 * max(1, margin_px // 4)
    scale = min(0.35 * margin_px / th, avail_w / tw)
    thick = max(1, int(round(scale * 1.5)))
    (tw, th), base = cv2.getTextSize(text, font, scale, thick)
    org = (max(1, margin_px // 4), img.shape[0] - margin_px // 2 + th // 2)
    cv2.putText(img, text, org, font, scale, 0, thick, cv2.LINE_AA)
    return img


def png_bytes(img: np.ndarray, dpi: float) -> bytes:
    """PNG of a grey image, with a pHYs chunk so viewers and printers know the scale."""
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OutputError("cannot encode the board as PNG")
    data = buf.tobytes()
    ppm = int(round(dpi / 0.0254))
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    ihdr_end = 8 + 4 + 4 + 13 + 4  # signature, IHDR length, type, data, crc
    return data[:ihdr_end] + chunk + data[ihdr_end:]


def pdf_bytes(images: list[np.ndarray], dpi: float) -> bytes:
    """A PDF with one grey image per page, each page exactly the image's physical size
    (width_px * 72 / dpi points), so printing at 100 % reproduces the board to scale."""
    objs: list[bytes] = []

    def add(body: bytes) -> int:
        objs.append(body)
        return len(objs)

    catalog = add(b"")  # filled in once the page tree exists
    pages = add(b"")
    kids = []
    for img in images:
        h, w = img.shape
        w_pt, h_pt = w * 72.0 / dpi, h * 72.0 / dpi
        raw = zlib.compress(np.ascontiguousarray(img, dtype=np.uint8).tobytes(), 6)
        im = add(b"<< /Type /XObject /Subtype /Image /Width %d /Height %d /ColorSpace /DeviceGray "
                 b"/BitsPerComponent 8 /Filter /FlateDecode /Length %d >>\nstream\n" % (w, h, len(raw))
                 + raw + b"\nendstream")
        content = b"q %.6f 0 0 %.6f 0 0 cm /Im0 Do Q" % (w_pt, h_pt)
        cs = add(b"<< /Length %d >>\nstream\n" % len(content) + content + b"\nendstream")
        kids.append(add(b"<< /Type /Page /Parent %d 0 R /MediaBox [0 0 %.6f %.6f] /Resources << /XObject "
                        b"<< /Im0 %d 0 R >> >> /Contents %d 0 R >>" % (pages, w_pt, h_pt, im, cs)))
    objs[catalog - 1] = b"<< /Type /Catalog /Pages %d 0 R >>" % pages
    objs[pages - 1] = (b"<< /Type /Pages /Kids [" + b" ".join(b"%d 0 R" % k for k in kids)
                       + b"] /Count %d >>" % len(kids))
    out = bytearray(b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n")
    offsets = []
    for i, body in enumerate(objs, start=1):
        offsets.append(len(out))
        out += b"%d 0 obj\n" % i + body + b"\nendobj\n"
    xref = len(out)
    out += b"xref\n0 %d\n0000000000 65535 f \n" % (len(objs) + 1)
    out += b"".join(b"%010d 00000 n \n" % o for o in offsets)
    out += b"trailer\n<< /Size %d /Root %d 0 R >>\nstartxref\n%d\n%%%%EOF\n" % (len(objs) + 1, catalog, xref)
    return bytes(out)


def run_board(target_path: str | Path, out_path: str | Path, dpi: int) -> str:
    """`rigcal board`: write every board of a target to scale; returns the summary for stdout."""
    target = load_target(target_path)
    out_path = Path(out_path)
    suffix = out_path.suffix.lower()
    if suffix not in (".png", ".pdf"):
        raise InputError(f"{out_path}: --out must end in .png or .pdf, got {out_path.suffix or 'no extension'!r}")
    if not (isinstance(dpi, (int, float)) and math.isfinite(dpi) and dpi > 0):
        raise InputError(f"--dpi: expected a positive number, got {dpi!r}")
    for b in target.boards:
        w_px, h_px = (int(math.ceil(x * dpi / 0.0254)) + 2 * int(round(0.5 * dpi)) for x in b.size_m)
        if max(w_px, h_px) > MAX_PRINT_PX:
            raise InputError(f"--dpi: board {b.name} would be {w_px} x {h_px} px at {dpi} dpi "
                             f"(more than {MAX_PRINT_PX} px a side); lower --dpi")
    images = [print_image(b, dpi) for b in target.boards]
    lines = []
    if suffix == ".pdf":
        atomic_write_bytes(out_path, pdf_bytes(images, dpi))
        files = [out_path] * len(images)
    else:
        files = ([out_path] if len(images) == 1 else
                 [out_path.with_name(f"{out_path.stem}-{b.name}{out_path.suffix}") for b in target.boards])
        for f, img in zip(files, images):
            atomic_write_bytes(f, png_bytes(img, dpi))
    for b, f, img in zip(target.boards, files, images):
        lines.append(f"{f}: {board_label(b)}; {img.shape[1]} x {img.shape[0]} px at {dpi:g} dpi "
                     f"({img.shape[1] / dpi * 25.4:.1f} x {img.shape[0] / dpi * 25.4:.1f} mm page)")
    return "\n".join(lines)
