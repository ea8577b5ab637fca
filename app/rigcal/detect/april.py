"""AprilGrid (Kalibr's target) detection: tags -> corner ids and first pixel estimates.

Kalibr's grid is AprilTag 36h11 with a 2-bit black border. OpenCV's ArucoDetector with
DICT_APRILTAG_36h11 and `markerBorderBits = 2` decodes its tags (AprilTag 3 does not:
the corner squares break its quad detection). Each tag's four corners become corner ids
`4 * (tag - first_tag_id) + k` with k = bottom-left, bottom-right, top-right, top-left
in Kalibr's board frame (target.Board.corners). Kalibr draws every code turned by 180
degrees from OpenCV's marker image, so OpenCV's corners as decoded (top-left, top-right,
bottom-right, bottom-left of the code) are Kalibr's k = 1, 0, 3, 2.

The corner squares make every tag corner an X-junction (tag border and corner square
black, the two gaps white), point-symmetric in a box of min(0.2, tag_spacing) tag sizes
(the 2-bit border is 0.2 of the tag) and, along the tag's edges, for a gap's length
(`symmetric_box`, `symmetric_cross`). corner_refine.refine_corners refines them with the same
point-symmetry estimator as ChArUco corners, along the axes `corner_axes` gives, checks
them (`looks_like_a_tag_corner`), restarts the odd ones (`neighbour_predictions`) and
bends the cross with the lens (`lattice_bends`).

Beyond the corner square a tag corner's arms go on as point-ANTIsymmetric pairs: the own
tag's edge against the collinear edge of the tag across the corner square
(`junction_pattern`, `collinear_neighbours`), placed by a per-view map of the board
(`view_map`). That "long-arm" pass is off by default (LONG_ARMS_BELOW_PX, README).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from rigcal.detect.corner_fit import cell_px
from rigcal.core.target import APRIL_BORDER_BITS, APRIL_DICTIONARY, Board

# OpenCV's corner j of a decoded tag is Kalibr's corner CV_TO_KALIBR[j].
CV_TO_KALIBR = np.array([1, 0, 3, 2])
# How much of the 2-bit border (0.2 tag) the symmetric box may use: the bits' blurred
# edges sit just inside it.
BORDER_FRACTION = 0.2
BOX_MARGIN_PX = 1.5
# The arm stops this far short of the corner square's far edge: that edge is not mirrored
# (the tag's border goes on), and perspective and blur bring it nearer than the affine
# cross assumes. Measured on rendered grids: 3 px left 0.013 px RMS on close boards, 5 px 0.008.
ARM_MARGIN_PX = 5.0
# The cross's arms reach no further than this (tag sizes) whatever the spacing: Kalibr's usual
# 0.3 is where the pass was measured, and longer arms along bigger corner squares cost
# accuracy (spacing 1.0, 3 frames: pinhole board 0.058 -> 0.0078 px RMS, fisheye board
# 0.159 -> 0.041; spacing 0.5: 0.0106 -> 0.0076, 0.0303 -> 0.0245, room 0.0066 -> 0.0072).
MAX_ARM = 0.3
# Below this tag_spacing the corner squares' gaps close under blur: OpenCV's tag outline runs
# into a square and its quad corner lands on the square's far corner, and corners can then be
# refined onto the squares' centres (3 rendered frames, pinhole room: spacing 0.15, 7 px off;
# 0.1, up to 29 px; 0.18-1.0 clean). calibrate warns (spacing_warnings).
MIN_RELIABLE_SPACING = 0.17
# The last pass's pairs keep this far off every blurred edge that is not mirrored: the
# bits inside the border (across the arms), the corner square's far edge and the next
# corner (along them). Measured on the fisheye room (tags ~22 px): 1.0 px let the blur in
# (0.0145 px RMS noise-free), 1.5 and 2.0 px gave 0.0039 and 0.0035 with the true lens.
PAIR_MARGIN_PX = 1.5
# The view's map from the board to the image: a homography (perspective, exactly) plus a
# polynomial of this degree in board coordinates (the lens). Degree 3 missed the fisheye's
# bends (0.017 px RMS), 5 followed the corners' noise (0.017), 4 gave 0.0095 (noise 2; fisheye
# room, before the edge offset was fitted).
MAP_DEGREE = 4
# Tags smaller than this (px) take the long arms (corner_refine._aprilgrid_mapped): OFF (0). On
# renders they halve the small tags' error (fisheye room, ~22 px tags: 0.0215 -> 0.0098 px
# RMS, ChArUco 0.0115), but on the real EuRoC print (28-34 px tags) they move every corner
# 0.05 px per axis towards its own tag's inside and PnP with EuRoC's intrinsics gets worse
# (0.157 -> 0.192 px): the tag edges are not where the junction's symmetry puts them (ink
# spread or loss moves an edge, not a point-symmetric junction's centre), and that bias does
# not average out. On larger rendered tags (45-150 px) they were worse than the box too
# (0.0087 -> 0.0117 px noise-free). docs/accuracy.md, AprilGrid; bench/aprilgrid_excess.py.
LONG_ARMS_BELOW_PX = 0.0
# The long arms fit, per view, how far the printed edges lie from the junctions (towards
# each own tag; ink spread is the print's): the edges alone place the corners, the median
# offset from the box's corners moves the antisymmetric pairs. On EuRoC it takes the mean
# move from +0.05 to -0.01 px (PnP 0.192 -> 0.168 / 0.159 px), but the corners stay rougher
# than the box's (a smooth map of the board leaves 0.068 / 0.070 px against 0.032 / 0.034):
# the real edges are worse than their junctions over a whole tag. Renders: unchanged. The real
# frames averaged down to 23 and 17 px tags (the fisheye room's): still no better than the box
# (map residual 0.044 against 0.027 px; 0.028 against 0.025).
FIT_EDGE_SHIFT = True
MAP_MIN_CORNERS = 40  # fewer refined corners in a view: no map, the affine cross instead
MAP_MAX_RMS_PX = 0.3  # a map fitting the corners worse than this is not trusted
# A tag corner's X-junction contrast (gaps against border and square) under this share of
# the typical corner's is no tag corner (looks_like_a_tag_corner).
MIN_CONTRAST = 0.25
INVERTED_UNLESS = 4  # tags found as printed, below which the inverted image is searched too


# Adaptive-threshold offsets of the detection passes: OpenCV's default first; a tag it
# misses (its border merges with the corner squares' blurred tips) is looked for again
# with a stricter threshold. On the real EuRoC frames the two passes together find all 36
# tags where either alone finds 29-36.
THRESH_CONSTANTS = (7.0, 10.0)
# Small tags (a 36h11 bit under ~2 px: tags under ~20 px) are decoded in an image upsampled
# UPSAMPLE times (bicubic), only while some tag is still missing and only around the missing
# tags the found ones predict (upsampled_regions). There the blur of the corner squares' tips
# joins more tag outlines, so both passes threshold stricter than at full size. Fisheye room,
# third frame (13-16 px tags): 6 of 36 tags at full size, 31 / 35 with this pass.
UPSAMPLE = 2
UPSAMPLED_THRESH_CONSTANTS = (10.0, 14.0)
# How far past the missing tags an upsampled region reaches, in tag pitches: the map of a
# few found tags (board_to_image) misses the lens, and the affine one the perspective.
REGION_MARGIN_PITCHES = 1.0
# Only missing tags predicted smaller than this (px, sqrt of the area) are searched upsampled:
# larger ones are missing for other reasons (cut by the image's edge, occluded) and the
# pass costs four times the region's detection.
UPSAMPLE_BELOW_PX = 32.0
# For a board with no tag decoded at full size, the undecoded quads of this size (px, sqrt of
# the area) point at small tags (the gaps between 20 px tags: 11 px): a crowd of at least
# CANDIDATES_MIN distinct ones is searched upsampled (candidate_regions).
CANDIDATE_PX = (4.0, 0.6 * UPSAMPLE_BELOW_PX)
CANDIDATES_MIN = 3
# Quads closer than this many of their sizes belong to one crowd (the gaps of a Kalibr grid,
# spacing 0.3, are 0.55 tag in size at a pitch of 1.3: neighbours ~2.4 sizes apart).
CANDIDATE_LINK = 3.0


def spacing_warnings(boards: Sequence[Board]) -> list[str]:
    """One warning per AprilGrid whose tag_spacing is under MIN_RELIABLE_SPACING."""
    return [f"board {b.name}: tag_spacing {b.tag_spacing:g} is under {MIN_RELIABLE_SPACING:g}: the gaps "
            f"between tags and corner squares close under blur, and some corners may be found on the corner "
            f"squares' centres, pixels off (docs/accuracy.md, AprilGrid)"
            for b in boards if b.type == "aprilgrid" and b.tag_spacing < MIN_RELIABLE_SPACING]


def detector_parameters(thresh_constant: float = THRESH_CONSTANTS[0]) -> "cv2.aruco.DetectorParameters":
    """ArUco parameters for Kalibr's tags: the 2-bit border; every bit error the code
    distance allows is corrected (the dictionary is cut to the target's ids, so a wrong
    decode would need more than 5 of 36 bits wrong *and* land on one of them)."""
    p = cv2.aruco.DetectorParameters()
    p.markerBorderBits = APRIL_BORDER_BITS
    p.errorCorrectionRate = 1.0
    p.adaptiveThreshConstant = float(thresh_constant)
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE  # rigcal refines (corner_refine.refine_corners)
    return p


class AprilGridGroup:
    """The AprilGrid boards of a target: tags are found once for all of them."""

    def __init__(self, boards: Sequence[Board]):
        full = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, APRIL_DICTIONARY))
        self.boards = list(boards)
        # A dictionary cut to the boards' own ids: faster, and a stray tag of another id is ignored.
        self.ids = np.unique(np.concatenate([b.marker_ids for b in self.boards])).astype(np.int64)
        sub = cv2.aruco.Dictionary(np.ascontiguousarray(full.bytesList[self.ids]), full.markerSize,
                                   full.maxCorrectionBits)
        self.passes = [cv2.aruco.ArucoDetector(sub, detector_parameters(c)) for c in THRESH_CONSTANTS]
        self.upsampled_passes = [cv2.aruco.ArucoDetector(sub, detector_parameters(c))
                                 for c in UPSAMPLED_THRESH_CONSTANTS]

    def tags(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tag ids (M,) in the full dictionary and their corners (M, 4, 2) in OpenCV's order.
        Later passes run only while some tag is missing, and add only tags not yet found:
        THRESH_CONSTANTS on the image, then UPSAMPLED_THRESH_CONSTANTS on it upsampled
        around the boards already seen (upsampled_regions) and, while some board has no tag
        found, around crowds of small quads the passes saw but could not decode away from
        the boards found (candidate_regions, away_from)."""
        ids, quads, rejected = np.zeros(0, np.int64), np.zeros((0, 4, 2)), []
        for aruco in self.passes:
            ids, quads = self._add(aruco, gray, ids, quads, np.zeros(2), 1, rejected)
            if self._complete(ids):
                return ids, quads
        regions = upsampled_regions(self.boards, ids, quads, gray.shape)
        if not self._some_tag_of_every_board(ids):
            regions += candidate_regions(away_from(np.concatenate(rejected), self.boards, ids, quads), gray.shape)
        for x0, y0, x1, y1 in regions:
            big = cv2.resize(gray[y0:y1, x0:x1], None, fx=UPSAMPLE, fy=UPSAMPLE, interpolation=cv2.INTER_CUBIC)
            for aruco in self.upsampled_passes:
                ids, quads = self._add(aruco, big, ids, quads, np.array([x0, y0], float), UPSAMPLE)
                if self._complete(ids):
                    return ids, quads
        return ids, quads

    def _complete(self, ids: np.ndarray) -> bool:
        return len(np.unique(ids)) == len(self.ids)

    def _some_tag_of_every_board(self, ids: np.ndarray) -> bool:
        return all(np.any(of_board(b, ids)) for b in self.boards)

    def _add(self, aruco: "cv2.aruco.ArucoDetector", image: np.ndarray, ids: np.ndarray, quads: np.ndarray,
             origin: np.ndarray, scale: int, rejected: list | None = None) -> tuple[np.ndarray, np.ndarray]:
        """ids, quads with the tags one detector pass finds in `image` that are not in ids
        yet; image is the original's pixels from origin (x, y) upsampled `scale` times. The
        quads it could not decode are appended to `rejected` (a list of (R, 4, 2)), if given."""
        corners, idx, rej = aruco.detectMarkers(image)
        if rejected is not None:
            rejected.append(np.asarray(rej, np.float64).reshape(-1, 4, 2))
        if idx is None or not len(idx):
            return ids, quads
        new_ids = self.ids[np.asarray(idx).reshape(-1)]
        new = ~np.isin(new_ids, ids)
        q = np.asarray(corners, np.float64).reshape(-1, 4, 2)[new]
        # cv2.resize puts pixel centres at (x + 0.5) * scale - 0.5
        q = origin + (q + 0.5) / scale - 0.5
        return np.concatenate([ids, new_ids[new]]), np.concatenate([quads, q])

    def detect(self, gray: np.ndarray) -> list[tuple[Board, np.ndarray, np.ndarray]]:
        """(board, corner ids (N,), uv (N, 2)) per board seen, unrefined, ids ascending."""
        ids, corners = self.tags(gray)
        if len(ids) < INVERTED_UNLESS:
            # maybe printed inverted (white tags on black): search the inverted image too
            inv_ids, inv_corners = self.tags(cv2.bitwise_not(gray))
            if len(inv_ids) > len(ids):
                ids, corners = inv_ids, inv_corners
        out = []
        for b in self.boards:
            keep = of_board(b, ids)
            if not keep.any():
                continue
            cid, uv = tag_corners_to_ids(ids[keep] - b.first_marker_id, corners[keep])
            out.append((b, cid, uv))
        return out


def of_board(board: Board, ids: np.ndarray) -> np.ndarray:
    """(M,) bool: which tag ids (full dictionary) are this board's."""
    return (ids >= board.first_marker_id) & (ids < board.first_marker_id + board.n_markers)


def upsampled_regions(boards: Sequence[Board], ids: np.ndarray, quads: np.ndarray, shape: tuple[int, ...]
                      ) -> list[tuple[int, int, int, int]]:
    """Pixel boxes (x0, y0, x1, y1) worth searching upsampled, one per board at most: around
    the board's missing tags that its found tags (ids (M,), quads (M, 4, 2) as
    AprilGridGroup.tags gives them) put inside the image (shape) and smaller than
    UPSAMPLE_BELOW_PX, each grown by REGION_MARGIN_PITCHES. A board none of whose tags was
    found has none: the pass would cost four times a full detection on every image without a
    board; nor one whose missing tags are large or outside the image (a close board cut by
    the image's edge)."""
    out = []
    h, w = shape[:2]
    for b in boards:
        keep = of_board(b, ids)
        missing = np.setdiff1d(np.arange(b.n_markers), ids[keep] - b.first_marker_id)
        if not keep.any() or not len(missing):
            continue
        cid, uv = tag_corners_to_ids(ids[keep] - b.first_marker_id, quads[keep])
        if not len(cid):
            continue
        to_px = board_to_image(b.corners[cid, :2], uv)
        corners = b.corners[:, :2].reshape(-1, 4, 2)[missing]  # (T, 4, 2) metres, k order
        quad = to_px(corners.reshape(-1, 2)).reshape(-1, 4, 2)
        centre = quad.mean(axis=1)
        size = np.sqrt(np.abs(_quad_area(quad)))
        want = (np.all((centre >= 0) & (centre < [w, h]), axis=1) & (size < UPSAMPLE_BELOW_PX))
        if not want.any():
            continue
        grow = REGION_MARGIN_PITCHES * b.square_length
        lo, hi = corners[want].min(axis=1) - grow, corners[want].max(axis=1) + grow  # (T, 2) each
        box = np.stack([lo, np.column_stack([hi[:, 0], lo[:, 1]]), hi, np.column_stack([lo[:, 0], hi[:, 1]])], 1)
        px = to_px(box.reshape(-1, 2))
        x0, y0 = np.clip(np.floor(px.min(0)), 0, [w, h]).astype(int)
        x1, y1 = np.clip(np.ceil(px.max(0)) + 1, 0, [w, h]).astype(int)
        if x1 - x0 >= 8 and y1 - y0 >= 8:
            out.append((int(x0), int(y0), int(x1), int(y1)))
    return out


def candidate_regions(rejected: np.ndarray, shape: tuple[int, ...]) -> list[tuple[int, int, int, int]]:
    """Pixel boxes (x0, y0, x1, y1) worth searching upsampled for a board none of whose tags
    decoded at full size: around each crowd of quads (R, 4, 2) the detector found but could
    not decode that could belong to small tags (CANDIDATE_PX; a print of 20 px tags at blur
    0.5 gives 60, the white gaps between its tags, 20 x 6 px): CANDIDATES_MIN or more
    distinct ones, each within CANDIDATE_LINK of its size from another, grown by two of
    their sizes. Scattered quads (clutter, a board's corner squares cut by the image's edge)
    make none, so an image of no board costs an upsampled search only where it shows a
    crowd of small squares."""
    if not len(rejected):
        return []
    size = np.sqrt(np.abs(_quad_area(rejected)))
    small = (size >= CANDIDATE_PX[0]) & (size < CANDIDATE_PX[1])
    quads, size = rejected[small], size[small]
    c = quads.mean(axis=1)
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    # each detector pass reports the same quads: one of each
    first = ~np.any(np.tril(d < 0.5 * size[None], k=-1), axis=1)
    quads, size, c, d = quads[first], size[first], c[first], d[np.ix_(first, first)]
    if len(quads) < CANDIDATES_MIN:
        return []
    link = d < CANDIDATE_LINK * np.maximum(size[:, None], size[None])
    n, label = connected_components(csr_matrix(link), directed=False)
    h, w = shape[:2]
    out = []
    for k in range(n):
        crowd = label == k
        if crowd.sum() < CANDIDATES_MIN:
            continue
        pts, grow = quads[crowd].reshape(-1, 2), 2.0 * float(np.median(size[crowd]))
        x0, y0 = np.clip(np.floor(pts.min(0) - grow), 0, [w, h]).astype(int)
        x1, y1 = np.clip(np.ceil(pts.max(0) + grow) + 1, 0, [w, h]).astype(int)
        if x1 - x0 >= 8 and y1 - y0 >= 8:
            out.append((int(x0), int(y0), int(x1), int(y1)))
    return out


def away_from(rejected: np.ndarray, boards: Sequence[Board], ids: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """The undecoded quads (R, 4, 2) that are none of the found boards' tags: whose centres
    lie over a tag size away from every tag of each board with a tag found (ids (M,), quads
    (M, 4, 2)), as its found tags put them (board_to_image). Those near are that board's
    missing tags (upsampled_regions looks for them) or its tags cut by the image's edge."""
    if not len(rejected) or not len(ids):
        return rejected
    c = rejected.mean(axis=1)
    keep = np.ones(len(rejected), bool)
    for b in boards:
        mine = of_board(b, ids)
        if not mine.any():
            continue
        cid, uv = tag_corners_to_ids(ids[mine] - b.first_marker_id, quads[mine])
        quad = board_to_image(b.corners[cid, :2], uv)(b.corners[:, :2]).reshape(-1, 4, 2)
        centre, size = quad.mean(axis=1), np.sqrt(np.abs(_quad_area(quad)))  # (T, 2), (T,)
        d = np.linalg.norm(c[:, None, :] - centre[None], axis=-1)  # (R, T)
        keep &= ~np.any(d < size[None], axis=1)
    return rejected[keep]


def _quad_area(q: np.ndarray) -> np.ndarray:
    d1, d2 = q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def board_to_image(xy: np.ndarray, uv: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """A map (M, 2) board metres -> (M, 2) px through corners xy (N, 2) seen at uv (N, 2): their
    homography where it holds over the board (two or more tags, no horizon crossing the
    board), else their affine fit (one tag, or a fit that would extrapolate wildly)."""
    A = np.linalg.lstsq(np.column_stack([xy, np.ones(len(xy))]), uv, rcond=None)[0]  # (3, 2)

    def affine(p: np.ndarray) -> np.ndarray:
        return np.column_stack([p, np.ones(len(p))]) @ A

    if len(xy) < 8:
        return affine
    H, _ = cv2.findHomography(xy, uv, 0)
    if H is None:
        return affine
    lo, hi = xy.min(0), xy.max(0)
    span = hi - lo
    corners = np.array([lo - span, [hi[0] + span[0], lo[1] - span[1]], hi + span, [lo[0] - span[0], hi[1] + span[1]]])
    wz = np.column_stack([corners, np.ones(4)]) @ H[2]
    if np.any(wz <= 0) or wz.max() > 2.0 * wz.min():
        return affine

    def homography(p: np.ndarray) -> np.ndarray:
        return cv2.perspectiveTransform(np.ascontiguousarray(p, np.float64).reshape(-1, 1, 2), H).reshape(-1, 2)

    return homography


def tag_corners_to_ids(tag_index: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalibr corner ids (4M,) ascending and their pixels (4M, 2) from tags (index from the
    board's first id, (M,)) and OpenCV's corners (M, 4, 2). A tag decoded twice (two
    detections of one id) is dropped: which one is right cannot be told here."""
    uniq, counts = np.unique(tag_index, return_counts=True)
    once = np.isin(tag_index, uniq[counts == 1])
    tag_index, corners = tag_index[once], corners[once]
    cid = (4 * tag_index[:, None] + CV_TO_KALIBR[None, :]).ravel()
    uv = corners.reshape(-1, 2)
    order = np.argsort(cid, kind="stable")
    return cid[order].astype(np.int64), uv[order]


def corner_axes(ids: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ax, ay (N, 2): the image of one tag size along board x and y at each corner, from the
    homography of its own tag's four corners (NaN where the tag has fewer than four). The
    signs do not matter to the point-symmetry fit."""
    ax = np.full((len(ids), 2), np.nan)
    ay = np.full((len(ids), 2), np.nan)
    tags, first, counts = np.unique(ids // 4, return_index=True, return_counts=True)
    full = tags[counts == 4]
    if not len(full):
        return ax, ay
    start = first[counts == 4]
    quad = uv[start[:, None] + np.arange(4)[None, :]]  # (T, 4, 2) in k order (ids ascending within a tag)
    unit = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])  # k's place in tag sizes
    H = _quad_homographies(unit, quad)  # (T, 3, 3) tag units -> px
    # Jacobian of the homography at each corner
    xy1 = np.concatenate([unit, np.ones((4, 1))], 1)  # (4, 3)
    w = np.einsum("tj,kj->tk", H[:, 2], xy1)  # (T, 4)
    p = quad
    jx = (H[:, None, :2, 0] - p * H[:, None, 2, 0, None]) / w[..., None]
    jy = (H[:, None, :2, 1] - p * H[:, None, 2, 1, None]) / w[..., None]
    rows = (start[:, None] + np.arange(4)[None, :]).ravel()
    ax[rows] = jx.reshape(-1, 2)
    ay[rows] = jy.reshape(-1, 2)
    return ax, ay


def _quad_homographies(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(T, 3, 3) homographies mapping the 4 points src (4, 2) onto each dst (T, 4, 2), by a
    batched 8x8 solve (h33 = 1)."""
    T = dst.shape[0]
    A = np.zeros((T, 8, 8))
    b = dst.reshape(T, 8)
    x, y = src[:, 0], src[:, 1]
    for k in range(4):  # four point pairs, two rows each (fixed size: not a loop over data)
        u, v = dst[:, k, 0], dst[:, k, 1]
        A[:, 2 * k, :3] = [x[k], y[k], 1.0]
        A[:, 2 * k, 6] = -u * x[k]
        A[:, 2 * k, 7] = -u * y[k]
        A[:, 2 * k + 1, 3:6] = [x[k], y[k], 1.0]
        A[:, 2 * k + 1, 6] = -v * x[k]
        A[:, 2 * k + 1, 7] = -v * y[k]
    h = np.linalg.solve(A, b[..., None])[..., 0]
    return np.concatenate([h, np.ones((T, 1))], 1).reshape(T, 3, 3)


def symmetric_cross(board: Board, ax: np.ndarray, ay: np.ndarray) -> tuple[float, float]:
    """(half-width, arm) in tag sizes of the point-symmetric cross around a tag corner, for
    corner_fit.refine_symmetric: along a tag edge the corner square mirrors the border for a
    gap's length (the arm, at most MAX_ARM, less ARM_MARGIN_PX), across it only as far as
    the 2-bit border reaches (the half-width; refine_symmetric takes its own blur margin off
    it)."""
    half = min(BORDER_FRACTION, board.tag_spacing)
    size_px = cell_px(ax, ay)
    size_px = size_px[np.isfinite(size_px)]
    margin = ARM_MARGIN_PX / float(np.median(size_px)) if len(size_px) else 0.0
    reach = min(board.tag_spacing, MAX_ARM)
    return half, max(reach - margin, 0.5 * reach)


def symmetric_box(board: Board, ax: np.ndarray, ay: np.ndarray) -> float:
    """Half-side, in tag sizes, of the point-symmetric box around a corner: the 2-bit border
    or the corner square, whichever is narrower, less BOX_MARGIN_PX of blur at the median
    tag's scale (never below half of it)."""
    reach = min(BORDER_FRACTION, board.tag_spacing)
    size_px = cell_px(ax, ay)
    size_px = size_px[np.isfinite(size_px)]
    if not len(size_px):
        return reach
    return float(max(reach - BOX_MARGIN_PX / float(np.median(size_px)), 0.5 * reach))


def neighbour_predictions(ids: np.ndarray, uv: np.ndarray, board: Board, trusted: np.ndarray) -> np.ndarray:
    """(N, 2) each corner as the homography of the trusted corners of the tags around its own
    (within one tag each way, its own tag left out) predicts it; NaN with fewer than 8 such
    corners. A start for corners whose own tag's quad was too far off (OpenCV's quad of a
    tag merged with its corner squares' tips): within a pixel or two even through a fisheye."""
    pred = np.full((len(ids), 2), np.nan)
    cols = board.squares[0]
    tag = ids // 4
    col, row = tag % cols, tag // cols
    xy = board.corners[ids, :2]
    for t in np.unique(tag[~trusted]):  # one small fit per tag (<= a few hundred), not per pixel
        near = trusted & (np.abs(col - t % cols) <= 1) & (np.abs(row - t // cols) <= 1) & (tag != t)
        if near.sum() < 8:
            continue
        H, _ = cv2.findHomography(xy[near], uv[near], 0)
        if H is None:
            continue
        mine = tag == t
        pred[mine] = cv2.perspectiveTransform(xy[mine].reshape(-1, 1, 2), H).reshape(-1, 2)
    return pred


# Kalibr's corner k seen from the corner: the direction (board x, y) of its own tag's inside
TOWARDS_TAG = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def junction_contrast(gray: np.ndarray, ids: np.ndarray, uv: np.ndarray, ax: np.ndarray, ay: np.ndarray,
                      box: float, normal: bool | None = None) -> tuple[np.ndarray, bool]:
    """((N,) contrast, normal): how much the image around each corner is the X-junction of a
    tag corner, sampled half-way across the symmetric box: the two gaps on either side
    against the tag's border (towards the tag) and the corner square (away from it), grey
    levels, > 0 for a tag corner. A corner the refinement placed on another junction (a
    bit's corner, the border's inner corner) gets < 0: there a side quadrant is the
    border's black. normal: the print's polarity (False: inverted, white tags on black),
    the majority's when None."""
    t = TOWARDS_TAG[ids % 4] * (0.5 * box)  # (N, 2) board units (tag sizes)
    offs = np.stack([t, -t, t * [1.0, -1.0], t * [-1.0, 1.0]], axis=1)  # in, out, side, side: (N, 4, 2)
    pts = uv[:, None, :] + offs[..., :1] * ax[:, None, :] + offs[..., 1:] * ay[:, None, :]
    pts = np.nan_to_num(pts, nan=-1e5).astype(np.float32)
    v = cv2.remap(gray.astype(np.float32), pts[..., 0], pts[..., 1], cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)  # (N, 4)
    gap = np.minimum(v[:, 2], v[:, 3]) - np.maximum(v[:, 0], v[:, 1])  # > 0: gaps white, diagonal black
    inv = np.minimum(v[:, 0], v[:, 1]) - np.maximum(v[:, 2], v[:, 3])  # > 0: printed inverted
    if normal is None:
        normal = bool(np.nansum(gap > 0) >= np.nansum(inv > 0))
    return (gap if normal else inv), normal


def contrast_reference(contrast: np.ndarray) -> float:
    """The typical tag corner's contrast among junction_contrast's: the median of the
    positive ones (0 when none is)."""
    pos = contrast[contrast > 0]
    return float(np.median(pos)) if len(pos) else 0.0


def looks_like_a_tag_corner(gray: np.ndarray, ids: np.ndarray, uv: np.ndarray, ax: np.ndarray, ay: np.ndarray,
                            box: float, normal: bool | None = None, reference: float | None = None
                            ) -> np.ndarray:
    """(N,) bool: the image around each corner is a tag corner's X-junction
    (junction_contrast > 0) with at least MIN_CONTRAST of the typical corner's contrast
    (`reference`, contrast_reference of these corners' when None). The centre of a corner
    square squashed to a few pixels is point-symmetric too, and there all four samples fall
    on the square: a contrast of noise, where a tag corner has the print's (a rendered
    fisheye room, a board near the image's edge: 0.1-1.5 grey levels at three corners 3 px
    off, 40-100 at the others)."""
    g, _ = junction_contrast(gray, ids, uv, ax, ay, box, normal)
    ref = contrast_reference(g) if reference is None else reference
    return g > max(MIN_CONTRAST * ref, 0.0)


@dataclass(frozen=True, eq=False)
class ViewMap:
    """A smooth map from a board (metres, board frame) to one image: the homography of the
    view's corners plus a polynomial of degree MAP_DEGREE (in tag sizes about the corners'
    centre) fitted to what the homography leaves (lens distortion). Built by view_map."""

    H: np.ndarray  # (3, 3) board metres -> px
    coef: np.ndarray  # (terms, 2) the polynomial's coefficients, px
    centre: np.ndarray  # (2,) metres
    scale: float  # metres per polynomial unit (the tag size)

    @staticmethod
    def _terms(xy: np.ndarray) -> np.ndarray:
        powers = [(i, j) for i in range(MAP_DEGREE + 1) for j in range(MAP_DEGREE + 1 - i)]
        return np.stack([xy[:, 0] ** i * xy[:, 1] ** j for i, j in powers], axis=1)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """(M, 2) pixels of board points xy (M, 2) metres."""
        h = cv2.perspectiveTransform(np.ascontiguousarray(xy, np.float64).reshape(-1, 1, 2), self.H).reshape(-1, 2)
        return h + self._terms((xy - self.centre) / self.scale) @ self.coef


def view_map(ids: np.ndarray, uv: np.ndarray, board: Board) -> ViewMap | None:
    """The ViewMap of a view's refined corners (ids (N,), uv (N, 2)); None with fewer than
    MAP_MIN_CORNERS, terms the corners cannot hold (all on few lines) or a fit worse than
    MAP_MAX_RMS_PX (a corner on the wrong junction, or a lens no quartic follows)."""
    if len(ids) < MAP_MIN_CORNERS:
        return None
    xy = board.corners[ids, :2]
    H, _ = cv2.findHomography(xy, uv, 0)
    if H is None:
        return None
    centre, scale = xy.mean(axis=0), board.tag_size
    A = ViewMap._terms((xy - centre) / scale)
    res = uv - cv2.perspectiveTransform(xy.reshape(-1, 1, 2), H).reshape(-1, 2)
    coef, _, rank, _ = np.linalg.lstsq(A, res, rcond=None)
    if rank < A.shape[1]:
        return None
    m = ViewMap(H, coef, centre, scale)
    if np.sqrt(np.mean(np.sum((m(xy) - uv) ** 2, axis=1))) > MAP_MAX_RMS_PX:
        return None
    return m


def junction_pattern(ids: np.ndarray, board: Board, cross: np.ndarray, size_px: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Which pairs (+-d, cross (P, 2) in tag sizes) of a tag corner's surroundings a
    symmetry fit may use: (w (N, P) bool, anti (N, P) bool, True where the pair is
    point-antisymmetric).

    Across the corner the pattern is point-symmetric out to the corner square's far edge
    (tag_spacing; across the arms, the 2-bit border). Beyond it, along each board axis, the
    own tag's edge goes on for the rest of the tag and, opposite, the edge of the tag
    across the corner square (collinear with it: the gap between them runs along it):
    black against white, point-antisymmetric, out to the next corner (1 tag). Where that
    neighbour does not exist (the grid's edge) the arm stops at the corner square. Every
    blurred end keeps PAIR_MARGIN_PX (at each corner's own scale size_px (N,))."""
    half, g = min(BORDER_FRACTION, board.tag_spacing), board.tag_spacing
    U, V = np.abs(cross[None, :, 0]), np.abs(cross[None, :, 1])
    along, across = np.maximum(U, V), np.minimum(U, V)
    mk = (PAIR_MARGIN_PX / size_px)[:, None]
    in_cross = across <= half - mk
    along_u, along_v = collinear_neighbours(ids, board)
    has = np.where(U >= V, along_u[:, None], along_v[:, None])
    anti = in_cross & has & (along >= g + mk) & (along <= 1.0 - mk)
    return (in_cross & (along <= g - mk)) | anti, anti


def collinear_neighbours(ids: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """along_u, along_v (N,) bool: whether the tag across the corner square from each
    corner's own tag along board x (y) exists (junction_pattern)."""
    cols, rows = board.squares
    tag = ids // 4
    away = -TOWARDS_TAG[ids % 4]
    col, row = tag % cols + away[:, 0], tag // cols + away[:, 1]
    return (col >= 0) & (col < cols), (row >= 0) & (row < rows)


def lattice_bends(ids: np.ndarray, uv: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How the board-x and board-y lines through each corner bend (lens distortion): bend_u,
    bend_v (N,) px per tag size^2 along each line's normal, as corner_grid.local_grid gives them
    for a uniform grid, here from the lattice of tag corners, whose spacing alternates
    between a tag and a gap (second divided differences on uneven steps). NaN where a
    neighbour along the line is missing."""
    nx, ny = 2 * board.squares[0], 2 * board.squares[1]
    k = ids % 4
    tag = ids // 4
    i = 2 * (tag % board.squares[0]) + np.isin(k, (1, 2))
    j = 2 * (tag // board.squares[0]) + np.isin(k, (2, 3))
    G = np.full((ny + 2, nx + 2, 2), np.nan)  # one ring of padding
    G[j + 1, i + 1] = uv
    s, g = 1.0, board.tag_spacing  # tag units

    def bend(index: np.ndarray, di: int, dj: int) -> np.ndarray:
        ahead = np.where(index % 2 == 0, s, g)  # the step to the next lattice point along the line
        back = np.where(index % 2 == 0, g, s)
        f0, fp, fm = G[j + 1, i + 1], G[j + 1 + dj, i + 1 + di], G[j + 1 - dj, i + 1 - di]
        h1, h2 = back[:, None], ahead[:, None]
        d1 = (h1 * h1 * fp - h2 * h2 * fm + (h2 * h2 - h1 * h1) * f0) / (h1 * h2 * (h1 + h2))
        d2 = 2.0 * (h1 * fp - (h1 + h2) * f0 + h2 * fm) / (h1 * h2 * (h1 + h2))
        n = np.column_stack([-d1[:, 1], d1[:, 0]])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return 0.5 * np.einsum("nk,nk->n", d2, n)

    return bend(i, 1, 0), bend(j, 0, 1)
