"""Rendering planar boards through a full camera model, exactly in geometry.

How a pixel gets its value:

1. Once per camera, every sub-pixel sample gets the unit ray through the *true*
   camera model (`ray_map`): an ss x ss grid per pixel at offsets (k + 0.5) / ss - 0.5
   around the pixel centre (OpenCV's convention: integer pixel = pixel centre).
   For a pinhole camera the rays are kept as normalised (x/z, y/z) (`sample_rays`).
2. Per image and board, the ray d meets the board plane where
   (x_board, y_board, 1) / s = G^-1 d, with G = [r1 r2 t] of T_cam_board and s the
   distance along the ray: one 3x3 matrix per board maps every sample to texture
   coordinates (`cv2.perspectiveTransform`), and its last row gives 1 / s for the
   depth test (nearest board wins; s <= 0 is behind the camera and never renders).
   Only the board's bounding box in the image is computed (the board clipped to the
   part in front of the camera, its outline projected through the model).
3. The texture is the printed face's exact area-coverage raster convolved with a
   Gaussian in closed form (`Board.black_fraction`), at a half-octave level whose
   texel is a third of the sample footprint, read with `cv2.remap`. Each sample thus
   sees the print through a smooth symmetric filter of half its footprint, the
   ss x ss samples are averaged (the pixel's area), and nothing depends on where an
   edge falls between texels or pixels: corners are not biased.
4. Nuisances on top (`finish`): cluttered background, lens blur, vignetting, optional
   linear motion blur, Gaussian noise, 8-bit rounding; brightness and contrast per
   image and board come in through the grey levels given to `render_boards`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel, fisheye_theta_d, pad12
from rigcal.core.target import Board, pixel_weights

SS = 2  # sub-samples per pixel side
PAPER_SQUARES = 0.5  # white paper around the printed pattern, in squares
MAX_TEXTURE_PX = 2048  # finest texture level, longest side (closer boards get a little extra blur)
TEXELS_PER_SAMPLE = 3.0  # texels across one sample's footprint on the board
BLUR_TEXELS = 1.5  # Gaussian pre-filter of every texture level, sigma in texels (half a sample)
FOOTPRINT_PERCENTILE = 75.0  # which sample footprint over a board picks its texture level
BACK_GREY = 0.55  # the unprinted back of a board, as a fraction of white
OUTSIDE = -1.0e5  # texture coordinate for rays that miss: far outside every texture


# ----------------------------------------------------------------------------- rays


def sample_grid(width: int, height: int, ss: int = SS) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel sample coordinates: u (W*ss,), v (H*ss,), in OpenCV pixel units."""
    u = (np.arange(width * ss) + 0.5) / ss - 0.5
    v = (np.arange(height * ss) + 0.5) / ss - 0.5
    return u, v


def ray_map(model: CameraModel, ss: int = SS, chunk: int = 65536) -> np.ndarray:
    """Unit rays (H*ss, W*ss, 3) float32 in the camera frame for every sub-pixel sample.

    Samples with no valid preimage (past the model's fold-back limit) get a zero ray,
    which the renderer treats as a miss. Equal to CameraModel.unproject (a slow,
    general Newton) to ~1e-12; this one uses the analytic Jacobian, in cache-sized
    chunks, because a 640x480 camera at ss=2 has 1.2 million samples."""
    u, v = sample_grid(model.width, model.height, ss)
    xd = np.broadcast_to(((u - model.cx) / model.fx)[None, :], (len(v), len(u))).ravel()
    yd = np.broadcast_to(((v - model.cy) / model.fy)[:, None], (len(v), len(u))).ravel()
    out = np.zeros((len(xd), 3), dtype=np.float32)
    solve = _rays_fisheye if model.model == "fisheye" else _rays_pinhole
    limit = model._valid_limit
    for i in range(0, len(xd), chunk):
        out[i:i + chunk] = solve(xd[i:i + chunk], yd[i:i + chunk], model.D, limit)
    return out.reshape(len(v), len(u), 3)


def _rays_pinhole(xd: np.ndarray, yd: np.ndarray, dist: np.ndarray, limit: float, iters: int = 12) -> np.ndarray:
    """Newton on OpenCV's 12-coefficient distortion with its analytic Jacobian."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = pad12(dist)

    def residual(x, y, jacobian):
        # OpenCV's forward model (camera.distort_pinhole), fused with its Jacobian
        r2 = x * x + y * y
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        radial = num / den
        xy2 = 2 * x * y
        fx = x * radial + p1 * xy2 + p2 * (r2 + 2 * x * x) + r2 * (s1 + s2 * r2) - xd
        fy = y * radial + p1 * (r2 + 2 * y * y) + p2 * xy2 + r2 * (s3 + s4 * r2) - yd
        if not jacobian:
            return fx, fy
        # d radial / d r2, then the chain through r2 = x^2 + y^2
        drad = ((k1 + r2 * (2 * k2 + 3 * k3 * r2)) * den - (k4 + r2 * (2 * k5 + 3 * k6 * r2)) * num) / (den * den)
        a = 2 * (s1 + 2 * s2 * r2)
        b = 2 * (s3 + 2 * s4 * r2)
        cross = xy2 * drad + 2 * p1 * x + 2 * p2 * y
        jxx = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + x * a
        jyy = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + y * b
        return fx, fy, jxx, cross + y * a, cross + x * b, jyy

    x, y = xd.copy(), yd.copy()
    with np.errstate(all="ignore"):
        for _ in range(iters):
            fx, fy, jxx, jxy, jyx, jyy = residual(x, y, True)
            if not ((np.abs(fx) >= 1e-15).any() or (np.abs(fy) >= 1e-15).any()):
                break
            det = jxx * jyy - jxy * jyx
            x = x - (jyy * fx - jxy * fy) / det
            y = y - (jxx * fy - jyx * fx) / det
        fx, fy = residual(x, y, False)
        ok = (np.maximum(np.abs(fx), np.abs(fy)) < 1e-10) & (np.hypot(x, y) < limit)
        norm = np.sqrt(x * x + y * y + 1.0)
    rays = np.stack([x / norm, y / norm, 1.0 / norm], axis=-1)
    rays[~ok] = 0.0
    return rays


def _rays_fisheye(xd: np.ndarray, yd: np.ndarray, dist: np.ndarray, limit: float, iters: int = 12) -> np.ndarray:
    """Newton on theta_d(theta) = |xd| (equidistant Kannala-Brandt)."""
    d = np.asarray(dist, dtype=float)
    theta_d = np.hypot(xd, yd)
    th = theta_d.copy()
    with np.errstate(all="ignore"):
        for _ in range(iters):
            t2 = th * th
            f = fisheye_theta_d(th, d) - theta_d
            step = f / (1 + t2 * (3 * d[0] + t2 * (5 * d[1] + t2 * (7 * d[2] + t2 * 9 * d[3]))))
            th = th - step
            if not (np.abs(step) >= 1e-15).any():
                break
        resid = np.abs(fisheye_theta_d(th, d) - theta_d)
        ok = (resid < 1e-10) & (th >= 0) & (th < limit)
        safe = np.where(theta_d > 0, theta_d, 1.0)
        s = np.sin(th) / safe
    rays = np.stack([xd * s, yd * s, np.cos(th)], axis=-1)
    rays[~ok] = 0.0
    return rays


# ----------------------------------------------------------------------------- textures


@dataclass
class BoardTexture:
    """A board's printed face with a white paper border, pre-filtered, at half-octave
    scales built on demand.

    Level k has px_per_m = top_ppm * 2^(-k/2) and is the exact area-coverage raster
    blurred by a Gaussian of BLUR_TEXELS texels. A sample whose footprint on the board
    is about TEXELS_PER_SAMPLE texels thus sees the pattern through a smooth, symmetric
    filter of about half its footprint, and bilinear lookups of the smooth texture are
    accurate at any sub-texel phase: the filter is shift-invariant, so corners are not
    biased (a sharp texture read by bilinear lookups is biased by up to 1/12 texel,
    depending on where the edge falls between texel centres).

    Two uint16 planes: the white fraction (the paper is white), and 1 on the paper, 0
    outside, so `remap`'s zero border gives the paper's edge."""

    board: Board
    levels: dict = field(default_factory=dict)

    @property
    def paper_m(self) -> float:
        return PAPER_SQUARES * self.board.square_length

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """The paper in board metres: x0, y0, x1, y1."""
        w, h = self.board.size_m
        return (-self.paper_m, -self.paper_m, w + self.paper_m, h + self.paper_m)

    @property
    def top_ppm(self) -> float:
        w, h = self.board.size_m
        return MAX_TEXTURE_PX / (max(w, h) + 2 * self.paper_m)

    def level_for(self, footprint_m: float) -> int:
        """The level whose texel is closest to footprint / TEXELS_PER_SAMPLE."""
        if not (footprint_m > 0 and math.isfinite(footprint_m)):
            return 0
        k = 2.0 * math.log2(self.top_ppm * footprint_m / TEXELS_PER_SAMPLE)
        return max(0, int(math.floor(k + 0.5)))

    def get(self, level: int) -> tuple[tuple[np.ndarray, np.ndarray], float, int]:
        """((white coverage, paper) (h, w) uint16 each, px_per_m, margin_px) of one level."""
        if level not in self.levels:
            ppm = self.top_ppm * 2.0 ** (-level / 2.0)
            # room for the blur to fade out beyond the paper
            margin = int(math.ceil(self.paper_m * ppm + 4 * BLUR_TEXELS))
            black = self.board.black_fraction(ppm, margin, blur_px=BLUR_TEXELS)
            h, w = black.shape
            pw, ph = self.board.size_m
            pad = self.paper_m * ppm
            ax = pixel_weights(w, np.array([margin - pad, margin + pw * ppm + pad]), BLUR_TEXELS)
            ay = pixel_weights(h, np.array([margin - pad, margin + ph * ppm + pad]), BLUR_TEXELS)
            paper = ay.astype(np.float32) * ax.T.astype(np.float32)  # separable: the blurred paper rectangle
            # The paper is white, the print lies on it: white = paper - black. Two one-channel
            # uint16 planes (cv2.remap is several times faster on one channel than on two).
            white16 = cv2.addWeighted(paper, 65535.0, black, -65535.0, 0.0, dtype=cv2.CV_16U)
            paper16 = cv2.addWeighted(paper, 65535.0, paper, 0.0, 0.0, dtype=cv2.CV_16U)
            self.levels[level] = ((white16, paper16), ppm, margin)
        return self.levels[level]


# ----------------------------------------------------------------------------- one image


@dataclass(frozen=True)
class Look:
    """How one image looks apart from geometry (drawn from the image's own seed)."""

    noise: float  # Gaussian sigma, grey levels
    blur_px: float  # motion blur length
    blur_angle: float  # radians
    optics_sigma_px: float  # the lens's blur (Gaussian), pixels


def board_bbox(model: CameraModel, T_cam_board: np.ndarray, board: Board, paper_m: float,
               pad_px: float = 3.0) -> tuple[int, int, int, int] | None:
    """Pixel box (x0, y0, x1, y1) (half-open) that holds the board's image, None when it
    cannot be seen. For a pinhole camera the board is first clipped to the part in front
    of the camera; a fisheye whose outline is partly outside the lens's field gets the
    whole image (conservative)."""
    w, h = board.size_m
    lo, hx, hy = -paper_m, w + paper_m, h + paper_m
    corners = geo.transform(T_cam_board, np.array([[lo, lo, 0.0], [hx, lo, 0.0], [hx, hy, 0.0], [lo, hy, 0.0]]))
    if model.model == "fisheye":
        # Convex test on the vertices: the whole board outside the lens's cone.
        theta = np.arctan2(np.hypot(corners[:, 0], corners[:, 1]), corners[:, 2])
        if model._valid_limit >= np.pi / 2 and np.all(theta >= model._valid_limit):
            return None
        poly = corners
    else:
        poly = _clip_front(corners, 1e-3)
        if len(poly) < 3:
            return None
    t = np.linspace(0.0, 1.0, 33)[:-1, None]
    outline = np.concatenate([poly[i] + t * (poly[(i + 1) % len(poly)] - poly[i]) for i in range(len(poly))])
    uv, valid = model.project(outline)
    if not valid.all():
        return (0, 0, model.width, model.height)
    x0 = max(0, int(math.floor(uv[:, 0].min() - pad_px)))
    y0 = max(0, int(math.floor(uv[:, 1].min() - pad_px)))
    x1 = min(model.width, int(math.ceil(uv[:, 0].max() + pad_px)) + 1)
    y1 = min(model.height, int(math.ceil(uv[:, 1].max() + pad_px)) + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    return (x0, y0, x1, y1)


def _clip_front(poly: np.ndarray, z_min: float) -> np.ndarray:
    """The part of a convex polygon (N, 3) with z >= z_min (Sutherland-Hodgman, one plane)."""
    out = []
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        a_in, b_in = a[2] >= z_min, b[2] >= z_min
        if a_in:
            out.append(a)
        if a_in != b_in:
            out.append(a + (z_min - a[2]) / (b[2] - a[2]) * (b - a))
    return np.array(out).reshape(-1, 3)


@dataclass(frozen=True)
class SampleRays:
    """A camera's sample rays in the form render_boards uses. `grid` is (H, W, 2) float32
    normalised coordinates (x/z, y/z) when every ray points forward (any valid pinhole
    model: board lookups are then one homography), else the unit rays (H, W, 3);
    `chans` holds the same numbers as separate contiguous planes."""

    grid: np.ndarray
    chans: tuple[np.ndarray, ...]

    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape[:2]

    @classmethod
    def from_grid(cls, grid: np.ndarray) -> "SampleRays":
        return cls(grid=grid, chans=tuple(np.ascontiguousarray(grid[..., i]) for i in range(grid.shape[-1])))

    def __reduce__(self):
        # the planes are a copy of the grid: ship the grid only (to worker processes)
        return (SampleRays.from_grid, (self.grid,))


def sample_rays(rays: np.ndarray) -> SampleRays:
    """SampleRays from ray_map's output."""
    z = rays[..., 2]
    grid = np.ascontiguousarray(rays[..., :2] / z[..., None], dtype=np.float32) if np.all(z > 1e-6) else rays
    return SampleRays.from_grid(grid)


def field_mask(rays: SampleRays, ss: int = SS) -> np.ndarray:
    """(H, W) float32: the fraction of each pixel's samples that have a ray (0 outside a
    fisheye's image circle, where a real lens delivers no light)."""
    if rays.grid.shape[-1] == 2:
        return np.ones((rays.shape[0] // ss, rays.shape[1] // ss), np.float32)
    has_ray = (np.abs(rays.grid).sum(axis=-1) > 0).astype(np.float32)
    return cv2.resize(has_ray, (rays.shape[1] // ss, rays.shape[0] // ss), interpolation=cv2.INTER_AREA)


def _homogeneous(sub: np.ndarray) -> np.ndarray:
    """(h, w, 2) normalised coordinates or (h, w, 3) rays -> (h, w, 3) float64 directions."""
    if sub.shape[-1] == 3:
        return sub.astype(np.float64)
    return np.concatenate([sub.astype(np.float64), np.ones(sub.shape[:-1] + (1,))], axis=-1)


def _footprint(sub: np.ndarray, Ginv: np.ndarray, extent: tuple[float, float, float, float], step: int) -> float:
    """Sample footprint on the board (metres): the larger singular value of d(board)/d(sample),
    at the 75th percentile over a sparse grid of the box's samples (every `step`) that land
    on the board (extent: x0, y0, x1, y1 in board metres).
    Larger rather than typical, so a board at a grazing angle is filtered for its coarsest
    direction and far side: over-filtering only softens, under-filtering aliases."""
    step = max(1, min(step, (sub.shape[0] - 1) // 2, (sub.shape[1] - 1) // 2))
    r = _homogeneous(sub[::step, ::step])
    if r.shape[0] < 2 or r.shape[1] < 2:
        return float("nan")
    q = r @ Ginv.T
    with np.errstate(all="ignore"):
        ok = q[..., 2] > 0
        bx, by = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
        ok &= (bx >= extent[0]) & (bx <= extent[2]) & (by >= extent[1]) & (by <= extent[3])
        a, c = np.diff(bx, axis=1)[:-1] / step, np.diff(by, axis=1)[:-1] / step
        b, d = np.diff(bx, axis=0)[:, :-1] / step, np.diff(by, axis=0)[:, :-1] / step
        S = a * a + b * b + c * c + d * d
        det = a * d - b * c
        s_max = np.sqrt(0.5 * (S + np.sqrt(np.maximum(S * S - 4 * det * det, 0.0))))
    good = ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & np.isfinite(s_max) & (s_max > 0)
    return float(np.percentile(s_max[good], FOOTPRINT_PERCENTILE)) if good.any() else float("nan")


def _texture_map(sub: np.ndarray, chans: list[np.ndarray], M: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Texture coordinates (h, w, 2) float32 of every sample in a box, and where the ray meets
    the board's plane in front of the camera ((h, w) float32 1/0), None when everywhere.

    M maps a ray (or (x, y, 1)) to homogeneous texture coordinates; its last row gives
    1 / distance along the ray, times the ray's (positive) norm."""
    M32 = M.astype(np.float32)
    if sub.shape[-1] == 2:
        tmap = cv2.perspectiveTransform(sub, M32)
        # the plane's horizon crosses the box unless w > 0 all round its border (w is affine)
        edge = np.concatenate([sub[0], sub[-1], sub[:, 0], sub[:, -1]]).astype(np.float64)
        if (edge @ M[2, :2] + M[2, 2]).min() > 0:
            return tmap, None
    else:
        xyw = cv2.transform(sub, M32)
        w = xyw[..., 2:3]
        tmap = np.full(sub.shape[:-1] + (2,), OUTSIDE, np.float32)
        np.divide(xyw[..., :2], w, out=tmap, where=w > 0)
        return tmap, None
    _, front = cv2.threshold(_inv_depth(chans, M32[2:3]), 0.0, 1.0, cv2.THRESH_BINARY)
    return tmap, front


def render_boards(model: CameraModel, rays: SampleRays, T_cam_boards: list[np.ndarray],
                  textures: list[BoardTexture], grey: list[tuple[float, float]], ss: int = SS
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Boards seen by one camera: (premultiplied grey (H, W), coverage alpha (H, W)) float32,
    already averaged over each pixel's ss x ss samples. rays: sample_rays(ray_map(model, ss));
    grey[i] = (black, white) grey levels of board i. Where boards overlap, the nearest wins."""
    H, W = model.height, model.width
    # everything below works in each board's print frame (the texture's)
    T_cam_boards = [T @ tex.board.T_board_print for T, tex in zip(T_cam_boards, textures)]
    boxes = [board_bbox(model, T, tex.board, tex.paper_m) for T, tex in zip(T_cam_boards, textures)]
    shown = [i for i, b in enumerate(boxes) if b is not None]
    out_val = np.zeros((H, W), np.float32)
    out_alpha = np.zeros((H, W), np.float32)
    if not shown:
        return out_val, out_alpha
    # sample-level work happens inside the union of the boards' boxes only
    ux0, uy0 = min(boxes[i][0] for i in shown), min(boxes[i][1] for i in shown)
    ux1, uy1 = max(boxes[i][2] for i in shown), max(boxes[i][3] for i in shown)
    val = np.zeros(((uy1 - uy0) * ss, (ux1 - ux0) * ss), np.float32)
    alpha = np.zeros_like(val)
    inv_depth = None  # 1 / distance of the nearest board so far, built once boards overlap
    drawn: list[tuple[tuple[int, int, int, int], list[np.ndarray], np.ndarray, np.ndarray]] = []
    for i in shown:
        x0, y0, x1, y1 = (c * ss for c in boxes[i])
        chans = [c[y0:y1, x0:x1] for c in rays.chans]
        v, a, Mw = _board_layer(rays.grid[y0:y1, x0:x1], chans, T_cam_boards[i], textures[i], grey[i])
        box_s = (x0, y0, x1, y1)
        lx0, ly0, lx1, ly1 = x0 - ux0 * ss, y0 - uy0 * ss, x1 - ux0 * ss, y1 - uy0 * ss  # in the union
        if not any(_overlap(box_s, d[0]) for d in drawn):
            val[ly0:ly1, lx0:lx1] = v
            alpha[ly0:ly1, lx0:lx1] = a
        else:
            if inv_depth is None:
                inv_depth = np.zeros_like(val)
                for (bx0, by0, bx1, by1), bchans, bMw, ba in drawn:
                    region = inv_depth[by0 - uy0 * ss:by1 - uy0 * ss, bx0 - ux0 * ss:bx1 - ux0 * ss]
                    np.copyto(region, _inv_depth(bchans, bMw), where=ba > 0)
            w = _inv_depth(chans, Mw)
            nearer = (a > 0) & (w > inv_depth[ly0:ly1, lx0:lx1])
            np.copyto(val[ly0:ly1, lx0:lx1], v, where=nearer)
            np.copyto(alpha[ly0:ly1, lx0:lx1], a, where=nearer)
            np.copyto(inv_depth[ly0:ly1, lx0:lx1], w, where=nearer)
        drawn.append((box_s, chans, Mw, a))
    if ss > 1:
        val = cv2.resize(val, (ux1 - ux0, uy1 - uy0), interpolation=cv2.INTER_AREA)
        alpha = cv2.resize(alpha, (ux1 - ux0, uy1 - uy0), interpolation=cv2.INTER_AREA)
    out_val[uy0:uy1, ux0:ux1] = val
    out_alpha[uy0:uy1, ux0:ux1] = alpha
    return out_val, out_alpha


def _board_layer(sub: np.ndarray, chans: list[np.ndarray], T_cam_board: np.ndarray, tex: BoardTexture,
                 grey: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One board over the samples `sub` of its box (rays and their channels, render_boards):
    (premultiplied grey, coverage alpha) float32 at sample resolution, and Mw (1, 3): ray ->
    1 / distance to the board plane (times a positive factor), for the nearest-board test."""
    black, white = grey
    G = np.column_stack([T_cam_board[:3, 0], T_cam_board[:3, 1], T_cam_board[:3, 3]])
    Ginv = np.linalg.inv(G)
    (tex_white, tex_paper), ppm, margin = tex.get(tex.level_for(_footprint(sub, Ginv, tex.extent, 16)))
    # board metres -> texture pixel (OpenCV centre convention), composed with G^-1
    A = np.array([[ppm, 0.0, margin - 0.5], [0.0, ppm, margin - 0.5], [0.0, 0.0, 1.0]])
    M = A @ Ginv
    tmap, front = _texture_map(sub, chans, M)
    white16 = cv2.remap(tex_white, tmap, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    paper16 = cv2.remap(tex_paper, tmap, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # The printed face is seen when the camera centre lies on the face's side (board z < 0).
    facing = geo.inv_T(T_cam_board)[2, 3] < 0
    k = 1.0 / 65535.0
    # premultiplied grey: black * paper + (white - black) * white coverage
    if facing:
        v = cv2.addWeighted(white16, (white - black) * k, paper16, black * k, 0.0, dtype=cv2.CV_32F)
    else:
        v = cv2.addWeighted(paper16, white * BACK_GREY * k, paper16, 0.0, 0.0, dtype=cv2.CV_32F)
    a = cv2.addWeighted(paper16, k, paper16, 0.0, 0.0, dtype=cv2.CV_32F)
    if front is not None:  # rays that meet the plane behind the camera see nothing
        v = cv2.multiply(v, front)
        a = cv2.multiply(a, front)
    return v, a, M[2:3].astype(np.float32)


def _inv_depth(chans: list[np.ndarray], Mw: np.ndarray) -> np.ndarray:
    """1 / distance to the board plane along each sample's ray (up to a positive factor per
    sample that is the same for every board), (h, w) float32; <= 0 behind the camera.
    chans: the box's x, y(, z) planes."""
    m = Mw.reshape(-1).astype(np.float64)
    w = cv2.addWeighted(chans[0], m[0], chans[1], m[1], 0.0 if len(chans) == 3 else m[2])
    if len(chans) == 3:
        w = cv2.scaleAdd(chans[2], m[2], w)
    return w


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def background(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """Cluttered grey background (H, W) float32: a smooth shading plus random blurred
    shapes and lines, so nothing is flat and edges appear that are not the board's."""
    low = rng.uniform(40, 200, size=(4, 5)).astype(np.float32)
    img = cv2.resize(low, (width, height), interpolation=cv2.INTER_CUBIC)
    scale = max(width, height)
    for _ in range(int(rng.integers(18, 32))):
        g = float(rng.uniform(0, 255))
        kind = rng.integers(0, 3)
        c = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        if kind == 0:
            axes = (int(rng.uniform(0.01, 0.12) * scale), int(rng.uniform(0.01, 0.12) * scale))
            cv2.ellipse(img, c, axes, float(rng.uniform(0, 180)), 0, 360, g, -1, cv2.LINE_AA)
        elif kind == 1:
            pts = (np.array(c) + rng.normal(0, 0.08 * scale, size=(int(rng.integers(3, 6)), 2))).astype(np.int32)
            cv2.fillPoly(img, [pts], g, cv2.LINE_AA)
        else:
            d = (int(rng.integers(0, width)), int(rng.integers(0, height)))
            cv2.line(img, c, d, g, int(rng.integers(1, 6)), cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.8, 2.5)))


def vignetting(model: CameraModel, strength: float = 0.25) -> np.ndarray:
    """Multiplicative fall-off (H, W) float32: 1 at the principal point, 1 - strength at the
    farthest image corner, quadratic in the radius."""
    u = np.arange(model.width, dtype=np.float32) - model.cx
    v = np.arange(model.height, dtype=np.float32) - model.cy
    r2 = u[None, :] ** 2 + v[:, None] ** 2
    return (1.0 - strength * r2 / r2.max()).astype(np.float32)


def motion_kernel(length_px: float, angle: float) -> np.ndarray:
    """Normalised linear motion-blur kernel of the given length (px) and direction."""
    half = int(math.ceil(length_px / 2.0)) + 1
    k = np.zeros((2 * half + 1, 2 * half + 1), np.float64)
    n = max(2, int(math.ceil(length_px * 8)))
    t = np.linspace(-length_px / 2.0, length_px / 2.0, n)
    x, y = half + t * math.cos(angle), half + t * math.sin(angle)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (y0 + dy, x0 + dx), wgt)
    return (k / k.sum()).astype(np.float32)


def finish(fg: np.ndarray, alpha: np.ndarray, bg: np.ndarray, vignette: np.ndarray, look: Look,
           rng: np.random.Generator) -> np.ndarray:
    """Boards over the background, then lens blur, vignetting, motion blur, noise -> uint8 (H, W)."""
    img = fg + (1.0 - alpha) * bg
    if look.optics_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), look.optics_sigma_px)
    img *= vignette
    if look.blur_px > 0:
        img = cv2.filter2D(img, -1, motion_kernel(look.blur_px, look.blur_angle), borderType=cv2.BORDER_REFLECT)
    if look.noise > 0:
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(look.noise)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
