"""An independent renderer of calibration datasets: a check of rigcal that shares no code with it.

rigcal's own round-trip tests render with rigcal.sim.render / rigcal.sim.simulate, which use the
same board geometry (target.py) and projection (camera.py) as the calibrator, so a
convention error there could cancel out. This module imports nothing from rigcal. It
builds every scene from the contract alone (../shared/spec/dataset.md, rig-yaml.md)
and OpenCV:

* Board texture: ``cv2.aruco.CharucoBoard(...).generateImage`` (legacy layout via
  ``setLegacyPattern``, first marker id via the ``ids`` argument), with a white paper
  margin. Board frame: origin at the top-left outer corner of the squares, x right, y
  down the print, z into the print (OpenCV's ``getChessboardCorners``).
* Rig: rig.yaml as rig-yaml.md writes it (FLU body, cameras declared with ``look:`` or
  ``axes:``); the true rig differs from the declared one by known mounting, focal,
  principal-point and lens errors.
* Cameras: OpenCV pinhole with radtan distortion (ray per pixel from
  ``cv2.undistortPoints`` with 100 iterations) and OpenCV fisheye (equidistant, inverted here by Newton so
  rays beyond 90 degrees are right). Pixel centres at integer coordinates.
* Per output pixel S x S sub-pixel rays are intersected with every board plane (nearest
  hit wins), the texture is sampled bilinearly and the samples are averaged (a box filter
  over the pixel's area).
* Photometry: a lighting gradient on the scene, optical blur, vignetting, gain, gamma,
  noise, colour tint; images as png / jpg / bmp / tif, grey or colour, some behind
  symbolic links, some missing for some cameras, frame stems that are not zero-padded,
  and one corrupt file.

Truth goes to truth.yaml in dataset.md's layout and is returned as arrays.

    scene = room_scene(n_frames=16, seed=0)      # or waved_scene(...)
    truth = write_dataset(scene, out_dir, seed=0)
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

# Body (FLU) axes by token, and the `look:` shorthand of rig-yaml.md.
AXIS = {"F": (1, 0, 0), "L": (0, 1, 0), "U": (0, 0, 1)}
LOOK = {"forward": ("-L", "-U", "F"), "backward": ("L", "-U", "-F"), "left": ("F", "-U", "L"),
        "right": ("-F", "-U", "-L"), "down": ("-L", "-F", "-U"), "up": ("L", "-F", "U")}
TEXELS_PER_SQUARE = 96
PAPER_MARGIN_SQUARES = 0.5  # white paper around the squares, as a board is printed
INK, PAPER, WALL = 0.05, 0.88, 0.42  # reflectances


# ----------------------------------------------------------------------------- geometry


def axes_R(tokens) -> np.ndarray:
    """R_body_cam (3, 3) from rig-yaml.md's `axes: [X, Y, Z]` tokens: columns are the camera axes."""
    cols = [(-1 if t.startswith("-") else 1) * np.array(AXIS[t.lstrip("-")], float) for t in tokens]
    return np.stack(cols, axis=1)


def rotvec_R(w) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (3,) in radians (OpenCV's Rodrigues)."""
    return cv2.Rodrigues(np.asarray(w, float).reshape(3, 1))[0]


def pose(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def inv(T: np.ndarray) -> np.ndarray:
    return pose(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3])


def quat_wxyz(R: np.ndarray) -> list[float]:
    """Unit quaternion [w, x, y, z] of a rotation matrix (Shepperd's method)."""
    tr = np.trace(R)
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2 * np.sqrt(1 + tr)
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        s = 2 * np.sqrt(1 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        s = 2 * np.sqrt(1 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2 * np.sqrt(1 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4]
    q = np.array(q)
    return list(q * np.sign(q[0]) if q[0] != 0 else q)


# ----------------------------------------------------------------------------- scene objects


@dataclass(frozen=True)
class Board:
    """A ChArUco board as target.yaml declares it."""

    name: str
    squares: tuple[int, int]
    square_length: float
    marker_length: float
    first_marker_id: int
    legacy: bool = False
    dictionary: str = "DICT_5X5_1000"

    @property
    def n_markers(self) -> int:
        return self.squares[0] * self.squares[1] // 2

    def cv_board(self):
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        ids = np.arange(self.first_marker_id, self.first_marker_id + self.n_markers, dtype=np.int32)
        b = cv2.aruco.CharucoBoard(self.squares, self.square_length, self.marker_length, d, ids)
        b.setLegacyPattern(self.legacy)
        return b

    def texture(self) -> tuple[np.ndarray, float, float]:
        """Reflectance (H, W) float32 of the printed sheet, texels per metre, and the margin
        in texels: board point (x, y) sits at texel x * ppm + margin (edge convention)."""
        m = int(round(PAPER_MARGIN_SQUARES * TEXELS_PER_SQUARE))
        size = (self.squares[0] * TEXELS_PER_SQUARE + 2 * m, self.squares[1] * TEXELS_PER_SQUARE + 2 * m)
        img = self.cv_board().generateImage(size, marginSize=m, borderBits=1)
        tex = np.where(img > 127, PAPER, INK).astype(np.float32)
        return tex, TEXELS_PER_SQUARE / self.square_length, float(m)

    def yaml_entry(self) -> dict:
        return {"name": self.name, "type": "charuco", "dictionary": self.dictionary,
                "squares": list(self.squares), "square_length": self.square_length,
                "marker_length": self.marker_length, "first_marker_id": self.first_marker_id,
                "legacy_pattern": self.legacy}


@dataclass(frozen=True)
class Camera:
    """A true camera: OpenCV model, image size (w, h), K (3, 3), distortion, T_body_cam (4, 4)."""

    name: str
    model: str  # pinhole | fisheye
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray
    T_body_cam: np.ndarray
    # a fisheye's field is cut at this angle from the axis (None: wherever the model inverts);
    # past where theta_d(theta) stops increasing the ray field is singular
    max_theta_deg: float | None = None


@dataclass(frozen=True)
class Photometry:
    """How one camera turns radiance into 8-bit values."""

    blur_sigma_px: float = 0.7
    noise_dn: float = 2.0
    gain: float = 1.0
    gamma: float = 2.2
    vignetting: float = 0.25  # relative fall-off at the image corner
    tint_bgr: tuple[float, float, float] = (0.85, 1.0, 1.1)


@dataclass(frozen=True)
class Scene:
    """Everything to render: declared rig (as the YAML dict), true cameras, boards, and per
    frame stem T_world_body and T_world_board (board name -> pose; moving boards per frame)."""

    declared: dict
    cameras: tuple[Camera, ...]
    boards: tuple[Board, ...]
    stems: tuple[str, ...]
    T_world_body: dict
    T_world_board: dict  # stem -> {board: (4, 4)}
    static_boards: bool
    photometry: dict = field(default_factory=dict)  # camera -> Photometry


# ----------------------------------------------------------------------------- cameras


def pixel_rays(cam: Camera, S: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (H*S, W*S, 3) float32 in the camera frame of the S x S sub-pixel sample
    points of every pixel, and a validity mask (H*S, W*S). Pixel (u, v) is centred at
    integer u, v; its samples sit at u + (s + 0.5) / S - 0.5.

    The model is inverted exactly on a one-pixel grid and the (smooth) ray field is
    interpolated to the samples with Catmull-Rom weights in float64 (cv2.remap's cubic
    kernel is not exact for linear fields); a random subset of samples is projected back
    through OpenCV to bound what that costs (asserted < 1e-3 px)."""
    if cam.max_theta_deg is not None:
        return _exact_rays(cam, S)
    w, h = cam.size
    pad = 2
    ug, vg = np.meshgrid(np.arange(-pad, w + pad, dtype=float), np.arange(-pad, h + pad, dtype=float))
    grid = np.column_stack([ug.ravel(), vg.ravel()])
    rays_g = unproject(cam, grid)
    ok_g = np.linalg.norm(project(cam, rays_g) - grid, axis=1) < 1e-3
    rays_g = rays_g.reshape(ug.shape + (3,))
    ok_g = ok_g.reshape(ug.shape)
    off = (np.arange(S) + 0.5) / S - 0.5
    rays = np.empty((h, S, w, S, 3))
    valid = np.empty((h, S, w, S), bool)
    for sx, ox in enumerate(off):
        base, wts = int(np.floor(ox)), _catmull_rom(ox - np.floor(ox))
        cols = sum(wk * rays_g[:, pad + base + k - 1: pad + base + k - 1 + w] for k, wk in enumerate(wts))
        ok_c = ok_g[:, pad - 1:pad - 1 + w] & ok_g[:, pad:pad + w] & ok_g[:, pad + 1:pad + 1 + w]
        for sy, oy in enumerate(off):
            base_y, wts_y = int(np.floor(oy)), _catmull_rom(oy - np.floor(oy))
            rays[:, sy, :, sx] = sum(wk * cols[pad + base_y + k - 1: pad + base_y + k - 1 + h]
                                     for k, wk in enumerate(wts_y))
            valid[:, sy, :, sx] = ok_c[pad - 1:pad - 1 + h] & ok_c[pad:pad + h] & ok_c[pad + 1:pad + 1 + h]
    rays = rays.reshape(h * S, w * S, 3)
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    valid = valid.reshape(h * S, w * S)
    # self-check on a sample of sub-pixel positions
    rng = np.random.default_rng(0)
    r, c = rng.integers(0, h * S, 20000), rng.integers(0, w * S, 20000)
    keep = valid[r, c]
    uv = np.column_stack([c // S + off[c % S], r // S + off[r % S]])[keep]
    err = np.abs(project(cam, rays[r, c][keep]) - uv).max()
    assert err < 1e-3, f"{cam.name}: interpolated rays are {err:.2g} px off"
    return rays.astype(np.float32), valid


def _exact_rays(cam: Camera, S: int) -> tuple[np.ndarray, np.ndarray]:
    """pixel_rays for a fisheye cut at max_theta_deg: every sample's ray by the model's own
    inversion (no interpolation: near the cut theta_d(theta) flattens, and the ray field
    bends too fast for a one-pixel grid), valid where it projects back within 1e-3 px."""
    w, h = cam.size
    off = (np.arange(S) + 0.5) / S - 0.5
    u = (np.arange(w)[:, None] + off[None, :]).ravel()
    v = (np.arange(h)[:, None] + off[None, :]).ravel()
    rays = np.empty((h * S, w * S, 3), np.float32)
    valid = np.empty((h * S, w * S), bool)
    for r0 in range(0, h * S, 256):  # in bands: bounded float64 temporaries
        uu, vv = np.meshgrid(u, v[r0:r0 + 256])
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        ray = unproject(cam, uv)
        ok = np.linalg.norm(project(cam, ray) - uv, axis=1) < 1e-3
        ok &= ray[:, 2] > np.cos(np.radians(cam.max_theta_deg))
        rays[r0:r0 + 256] = ray.reshape(uu.shape + (3,))
        valid[r0:r0 + 256] = ok.reshape(uu.shape)
    return rays, valid


def _catmull_rom(t: float) -> tuple[float, float, float, float]:
    """Weights of the samples at -1, 0, 1, 2 for a point at t in [0, 1) (exact for quadratics)."""
    return (((-t + 2) * t - 1) * t / 2, ((3 * t - 5) * t * t + 2) / 2,
            ((-3 * t + 4) * t + 1) * t / 2, (t - 1) * t * t / 2)


def unproject(cam: Camera, uv: np.ndarray) -> np.ndarray:
    """Unit rays (N, 3) of pixels (N, 2)."""
    if cam.model == "pinhole":
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
        xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist, criteria=crit).reshape(-1, 2)
        rays = np.column_stack([xy, np.ones(len(xy))])
    else:
        rays = _fisheye_unproject(uv, cam.K, cam.dist)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _fisheye_unproject(uv: np.ndarray, K: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Rays (N, 3) of pixels (N, 2) through OpenCV's equidistant fisheye model; theta from
    theta_d by Newton's method, so rays past 90 degrees come out right (no x/z division)."""
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * (uv[:, 1] - K[1, 2]) / K[1, 1]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    th_d = np.hypot(x, y)
    th = th_d.copy()
    for _ in range(30):
        t2 = th * th
        f = th * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) - th_d
        df = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
        th = th - f / df
    s = np.where(th_d > 1e-12, np.sin(th) / np.maximum(th_d, 1e-12), 1.0)
    return np.column_stack([x * s, y * s, np.cos(th)])


def project(cam: Camera, p_cam: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of camera-frame points (N, 3) by OpenCV's own projection functions."""
    p = np.ascontiguousarray(p_cam, dtype=np.float64).reshape(-1, 1, 3)
    z = np.zeros(3)
    if cam.model == "pinhole":
        uv = cv2.projectPoints(p, z, z, cam.K, cam.dist)[0]
    else:
        # cv2.fisheye divides by z, so rays past 90 degrees are projected by hand
        uv = cv2.fisheye.projectPoints(p, z, z, cam.K, cam.dist)[0]
        back = p[:, 0, 2] <= 0
        if back.any():
            q = p[back, 0]
            r = np.hypot(q[:, 0], q[:, 1])
            th = np.arctan2(r, q[:, 2])
            t2 = th * th
            k = cam.dist
            th_d = th * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
            xd = q[:, :2] * (th_d / np.maximum(r, 1e-12))[:, None]
            uv[back, 0] = np.column_stack([cam.K[0, 0] * xd[:, 0] + cam.K[0, 1] * xd[:, 1] + cam.K[0, 2],
                                           cam.K[1, 1] * xd[:, 1] + cam.K[1, 2]])
    return uv.reshape(-1, 2)


# ----------------------------------------------------------------------------- rendering


def render_radiance(rays: np.ndarray, valid: np.ndarray, S: int, hits: list) -> np.ndarray:
    """Scene radiance (H, W) float32, the box-filtered mean of S x S samples per pixel.

    rays: (H*S, W*S, 3) from pixel_rays; hits: per board (texture, ppm, margin, T_board_cam).
    Each board is intersected only inside the bounding box of its hits on a coarse grid."""
    HS, WS = valid.shape
    depth = np.full((HS, WS), np.inf, np.float32)
    value = np.full((HS, WS), WALL, np.float32)
    step = 4 * S
    for tex, ppm, margin, T_board_cam in hits:
        box = _board_box(rays, T_board_cam, tex.shape, ppm, margin, step)
        if box is None:
            continue
        r0, r1, c0, c1 = box
        d = rays[r0:r1, c0:c1] @ T_board_cam[:3, :3].T.astype(np.float32)
        o = T_board_cam[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (-o[2] / d[..., 2]).astype(np.float32)
        x = (o[0] + s * d[..., 0]) * ppm + margin - 0.5  # texel-centre coordinates for remap
        y = (o[1] + s * d[..., 1]) * ppm + margin - 0.5
        th, tw = tex.shape
        hit = (s > 0) & (x >= -0.5) & (x <= tw - 0.5) & (y >= -0.5) & (y <= th - 0.5) & valid[r0:r1, c0:c1]
        hit &= s < depth[r0:r1, c0:c1]
        x = np.where(hit, x, -1).astype(np.float32)
        y = np.where(hit, y, -1).astype(np.float32)
        sample = cv2.remap(tex, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        depth[r0:r1, c0:c1] = np.where(hit, s, depth[r0:r1, c0:c1])
        value[r0:r1, c0:c1] = np.where(hit, sample, value[r0:r1, c0:c1])
    value[~valid] = 0.0
    return value.reshape(HS // S, S, WS // S, S).mean(axis=(1, 3))


def _board_box(rays, T_board_cam, tex_shape, ppm, margin, step):
    """Sample rows/cols (r0, r1, c0, c1) covering the board's sheet, from a coarse grid of
    rays grown by one cell; None when no coarse ray hits it."""
    coarse = rays[step // 2::step, step // 2::step]
    d = coarse @ T_board_cam[:3, :3].T.astype(np.float32)
    o = T_board_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[2] / d[..., 2]
    x = (o[0] + s * d[..., 0]) * ppm + margin
    y = (o[1] + s * d[..., 1]) * ppm + margin
    th, tw = tex_shape
    hit = (s > 0) & (x >= 0) & (x <= tw) & (y >= 0) & (y <= th)
    if not hit.any():
        return None
    rr, cc = np.nonzero(hit)
    HS, WS = rays.shape[:2]
    return (max(0, (rr.min() - 1) * step), min(HS, (rr.max() + 2) * step),
            max(0, (cc.min() - 1) * step), min(WS, (cc.max() + 2) * step))


def develop(radiance: np.ndarray, ph: Photometry, colour: bool, lighting: np.ndarray,
            rng: np.random.Generator) -> np.ndarray:
    """8-bit image (H, W) or BGR (H, W, 3) from radiance (H, W): lighting, blur, vignetting,
    gain, noise, gamma."""
    h, w = radiance.shape
    img = radiance * lighting
    if ph.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), ph.blur_sigma_px)
    v, u = np.mgrid[0:h, 0:w]
    r2 = ((u - w / 2) ** 2 + (v - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    img = img * ph.gain * (1 - ph.vignetting * r2)
    if colour:
        img = img[..., None] * np.array(ph.tint_bgr, np.float32)
    img = np.clip(img, 0, 1) ** (1 / ph.gamma) * 255
    img = img + rng.normal(0, ph.noise_dn, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def lighting_field(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A smooth illumination (H, W): a linear gradient in a random direction, 0.6 .. 1.15."""
    w, h = size
    v, u = np.mgrid[0:h, 0:w]
    a = rng.uniform(0, 2 * np.pi)
    g = ((u - w / 2) * np.cos(a) + (v - h / 2) * np.sin(a)) / np.hypot(w, h) * 2
    return (0.875 + 0.275 * g).astype(np.float32)


# ----------------------------------------------------------------------------- scenes


def _pinhole(name, f, cx, cy, dist, T, size=(640, 480)):
    K = np.array([[f[0], 0, cx], [0, f[1], cy], [0, 0, 1.0]])
    return Camera(name, "pinhole", size, K, np.array(dist, float), T)


def _perturbed(T: np.ndarray, rng: np.random.Generator, mm: float, deg: float) -> np.ndarray:
    """A mounting error: T (4, 4) moved by ~mm millimetres and turned by ~deg degrees."""
    w = rng.normal(size=3)
    R = rotvec_R(w / np.linalg.norm(w) * np.radians(deg)) @ T[:3, :3]
    return pose(R, T[:3, 3] + rng.normal(size=3) * mm / 1000)


def _board_facing(centre, normal_in, right, tilt_deg, rng) -> np.ndarray:
    """T_world_board of a sheet whose print faces away from `normal_in` (its z, into the
    print), x along `right`, centred at `centre`, tilted randomly by up to tilt_deg."""
    z = np.asarray(normal_in, float) / np.linalg.norm(normal_in)
    x = np.asarray(right, float) - np.dot(right, z) * z
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    R = R @ rotvec_R(np.radians(rng.uniform(-tilt_deg, tilt_deg, 3) * [1, 1, 0.3]))
    return pose(R, centre)


def _centred(T_world_board: np.ndarray, b: Board) -> np.ndarray:
    """Shift a pose given for the sheet's centre to the board frame's origin (top-left corner)."""
    half = np.array([b.squares[0], b.squares[1], 0]) * b.square_length / 2
    return pose(T_world_board[:3, :3], T_world_board[:3, 3] - T_world_board[:3, :3] @ half)


def _stems(n: int) -> tuple[str, ...]:
    """Frame names a camera tool might write: no zero padding, mixed prefixes, a dot."""
    out = []
    for k in range(n):
        out.append(f"cap_a{k + 1}" if k % 5 else f"Shot.{k + 3}")
    return tuple(out)


def room_scene(n_frames: int = 16, seed: int = 0, headings: str = "all") -> Scene:
    """A forward pinhole stereo pair and a backward fisheye camera in a room of ChArUco boards
    (disjoint id ranges, one in the legacy layout) about 1.1 m away on the walls.

    headings "all": boards on all four walls; the rig turns through every heading, pitches
    and rolls by up to 12 degrees and moves by up to 0.25 m, so each board is seen by the
    front pair in some frames and by the back camera in others. "forward": boards on the
    front and back walls only, and the rig yaws by at most 20 degrees: no board is ever
    seen by both the back camera and a front one, and no frame shows a front camera a
    board of each wall. The back camera's pose then follows from the rig's rotations
    alone (a hand-eye problem, AX = ZB), which dataset.md allows."""
    rng = np.random.default_rng(seed)
    declared = {
        "rig": "indie-room", "body_frame": "FLU",
        "cameras": {
            "front_left": {"model": "pinhole", "resolution": [640, 480], "intrinsics": {"focal": 330.0},
                           "distortion": [0, 0, 0, 0, 0], "position": [0.12, 0.06, 0.02], "look": "forward"},
            "front_right": {"model": "pinhole", "resolution": [640, 480],
                            "intrinsics": {"fx": 330.0, "fy": 330.0, "cx": 320.0, "cy": 240.0},
                            "position": [0.12, -0.06, 0.02], "axes": ["-L", "-U", "F"]},
            "back": {"model": "fisheye", "resolution": [640, 480],
                     "intrinsics": {"fx": 240.0, "fy": 240.0, "cx": 320.0, "cy": 240.0},
                     "distortion": [0, 0, 0, 0], "position": [-0.10, 0.0, 0.04], "axes": ["L", "-U", "-F"]},
        },
        "stereo_pairs": [["front_left", "front_right"]],
    }
    T_fl = _perturbed(pose(axes_R(LOOK["forward"]), [0.12, 0.06, 0.02]), rng, 3.0, 0.8)
    T_fr = _perturbed(pose(axes_R(["-L", "-U", "F"]), [0.12, -0.06, 0.02]), rng, 3.0, 0.8)
    T_bk = _perturbed(pose(axes_R(["L", "-U", "-F"]), [-0.10, 0.0, 0.04]), rng, 3.0, 0.8)
    cameras = (
        _pinhole("front_left", (335.2, 334.6), 323.7, 236.1, [-0.11, 0.045, 6e-4, -4e-4, 0.0], T_fl),
        _pinhole("front_right", (327.9, 328.3), 316.2, 243.4, [-0.095, 0.03, -5e-4, 3e-4, 0.0], T_fr),
        Camera("back", "fisheye", (640, 480), np.array([[236.5, 0, 317.4], [0, 236.1, 242.8], [0, 0, 1.0]]),
               np.array([0.03, -0.012, 0.004, -0.0008]), T_bk),
    )
    F, L, U = np.eye(3)
    # centre of the sheet, direction into the print (away from the rig), the print's x
    walls = {
        "front_a": (Board("front_a", (8, 6), 0.12, 0.09, 0, legacy=True), [1.25, 0.55, 0.2], F, -L),
        "front_b": (Board("front_b", (7, 5), 0.13, 0.10, 24), [1.2, -0.55, 0.25], F, -L),
        "front_c": (Board("front_c", (9, 6), 0.10, 0.075, 60), [1.0, 0.0, -0.45], F - 0.6 * U, -L),
        "back_a": (Board("back_a", (8, 6), 0.12, 0.09, 100), [-1.0, -0.45, 0.1], -F, L),
        "back_b": (Board("back_b", (6, 5), 0.14, 0.105, 200), [-0.95, 0.5, 0.0], -F, L),
        "left_a": (Board("left_a", (8, 6), 0.12, 0.09, 300), [0.2, 1.1, 0.1], L, F),
        "right_a": (Board("right_a", (7, 5), 0.13, 0.10, 400), [-0.1, -1.1, 0.15], -L, -F),
    }
    if headings == "forward":
        walls = {k: v for k, v in walls.items() if k.startswith(("front", "back"))}
    boards = tuple(b for b, *_ in walls.values())
    T_world_board = {b.name: _centred(_board_facing(c, n, r, 25 if b.name != "front_c" else 15, rng), b)
                     for b, c, n, r in walls.values()}
    stems = _stems(n_frames)
    T_world_body = {}
    yaw_range = 180 if headings == "all" else 20
    for s in stems:
        ypr = np.radians([rng.uniform(-yaw_range, yaw_range), rng.uniform(-12, 12), rng.uniform(-12, 12)])
        R = rotvec_R([0, 0, ypr[0]]) @ rotvec_R([0, ypr[1], 0]) @ rotvec_R([ypr[2], 0, 0])
        T_world_body[s] = pose(R, rng.uniform([-0.25, -0.25, -0.12], [0.25, 0.25, 0.12]))
    photometry = {
        "front_left": Photometry(0.6, 2.0, 1.05, 2.2, 0.25),
        "front_right": Photometry(0.8, 2.5, 0.95, 1.8, 0.3, (0.95, 1.0, 0.9)),
        "back": Photometry(0.7, 3.0, 1.1, 2.0, 0.35, (1.1, 1.0, 0.8)),
    }
    return Scene(declared, cameras, boards, stems, T_world_body,
                 {s: dict(T_world_board) for s in stems}, True, photometry)


def waved_scene(n_frames: int = 12, seed: int = 0, fisheye: bool = False) -> Scene:
    """A forward pinhole stereo pair standing still while one board is waved in front of it.

    fisheye: instead a forward pair of ~180 degree equidistant fisheye cameras (800 x 800,
    f = 250 px, 0.08 m baseline) and a big board (11 x 8 squares of 0.216 m) waved at
    0.5-3 m, its poses spread over both image circles (_waved_fisheye)."""
    if fisheye:
        return _waved_fisheye(n_frames, seed)
    rng = np.random.default_rng(seed + 1000)
    declared = {
        "rig": "indie-waved", "body_frame": "FLU",
        "cameras": {
            "left": {"model": "pinhole", "resolution": [640, 480], "intrinsics": {"focal": 420.0},
                     "position": [0.0, 0.075, 0.0], "look": "forward"},
            "right": {"model": "pinhole", "resolution": [640, 480], "intrinsics": {"focal": 420.0},
                      "position": [0.0, -0.075, 0.0], "axes": ["-L", "-U", "F"]},
        },
        "stereo_pairs": [["left", "right"]],
    }
    T_l = _perturbed(pose(axes_R(LOOK["forward"]), [0.0, 0.075, 0.0]), rng, 2.0, 0.6)
    T_r = _perturbed(pose(axes_R(LOOK["forward"]), [0.0, -0.075, 0.0]), rng, 2.0, 0.6)
    cameras = (
        _pinhole("left", (426.0, 425.1), 318.2, 244.9, [-0.18, 0.09, 3e-4, -2e-4, 0.0], T_l),
        _pinhole("right", (415.3, 415.9), 324.6, 236.7, [-0.16, 0.07, -4e-4, 5e-4, 0.0], T_r),
    )
    board = Board("wand", (9, 7), 0.06, 0.045, 300)
    F, L, U = np.eye(3)
    stems = _stems(n_frames)
    moving = {}
    for s in stems:
        centre = [rng.uniform(0.6, 1.4), rng.uniform(-0.2, 0.2), rng.uniform(-0.15, 0.15)]
        T = _board_facing(centre, F, -L, 40, rng)
        moving[s] = {board.name: _centred(T, board)}
    photometry = {"left": Photometry(0.9, 2.0, 1.0, 2.2, 0.2), "right": Photometry(0.6, 1.5, 0.9, 2.0, 0.25)}
    return Scene(declared, cameras, (board,), stems, {s: np.eye(4) for s in stems}, moving, False, photometry)


FISHEYE_DECLARED = {
    "rig": "indie-waved-fisheye", "body_frame": "FLU",
    "cameras": {
        "left": {"model": "fisheye", "resolution": [800, 800],
                 "intrinsics": {"fx": 250.0, "fy": 250.0, "cx": 400.0, "cy": 400.0},
                 "distortion": [0.01, -0.005, 0.001, -0.0005], "position": [0.12, 0.04, 0.0], "look": "forward"},
        "right": {"model": "fisheye", "resolution": [800, 800],
                  "intrinsics": {"fx": 250.0, "fy": 250.0, "cx": 400.0, "cy": 400.0},
                  "distortion": [0.012, -0.004, 0.0008, -0.0004], "position": [0.12, -0.04, 0.0],
                  "axes": ["-L", "-U", "F"]},
    },
    "stereo_pairs": [["left", "right"]],
}
FISHEYE_GRID = 4  # image coverage cells per side when choosing board poses


def _waved_fisheye(n_frames: int, seed: int) -> Scene:
    """waved_scene(fisheye=True): true cameras off the declared ones by ~1 % focal, +-5 px
    principal point, a little lens and ~5 mm / ~1 deg mounting error. Each frame's board
    pose is the best of 40 random candidates (centred on a random pixel's ray, 0.3-1.3
    image widths across, tilted up to 50 and rolled up to 30 degrees), scored by the
    cameras that see >= 6 corners and the still-empty image cells they fill."""
    rng = np.random.default_rng(seed + 2000)
    cameras = []
    for name, d in FISHEYE_DECLARED["cameras"].items():
        it = d["intrinsics"]
        f = it["fx"] * (1 + rng.normal(0, 0.01, 2))
        c = np.array([it["cx"], it["cy"]]) + rng.uniform(-5, 5, 2)
        K = np.array([[f[0], 0, c[0]], [0, f[1], c[1]], [0, 0, 1.0]])
        k = np.array(d["distortion"]) * (1 + rng.normal(0, 0.2, 4))
        T = _perturbed(pose(axes_R(LOOK["forward"]), d["position"]), rng, 5.0, 1.0)
        cameras.append(Camera(name, "fisheye", tuple(d["resolution"]), K, k, T, _fisheye_limit_deg(k)))
    board = Board("wand", (11, 8), 0.216, 0.151, 0)
    stems = _stems(n_frames)
    hits = np.zeros((len(cameras), FISHEYE_GRID ** 2))
    moving = {}
    for s in stems:
        cand = [_fisheye_candidate(rng, cameras, board) for _ in range(40)]
        cells = np.array([[_cells_seen(cam, T, board) for cam in cameras] for T in cand])  # (40, C, G*G)
        seen = cells.sum(axis=2) >= 6
        score = (seen * (3.0 + ((cells > 0) / (1.0 + hits)).sum(axis=2))).sum(axis=1) + 3.0 * seen.all(axis=1)
        best = int(np.argmax(score))
        hits += (cells[best] > 0) * seen[best][:, None]
        moving[s] = {board.name: cand[best]}
    photometry = {"left": Photometry(0.6, 2.0, 1.0, 2.2, 0.25), "right": Photometry(0.6, 2.0, 0.95, 2.2, 0.25)}
    return Scene(FISHEYE_DECLARED, tuple(cameras), (board,), stems, {s: np.eye(4) for s in stems}, moving, False,
                 photometry)


def _fisheye_limit_deg(k: np.ndarray, cap_deg: float = 110.0) -> float:
    """Angle from the axis (deg) up to which theta_d(theta) increases, at most cap_deg."""
    th = np.linspace(0, np.radians(cap_deg), 4001)
    t2 = th * th
    td = th * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
    bad = np.nonzero(np.diff(td) <= 0)[0]
    return float(np.degrees(th[bad[0]] if len(bad) else th[-1]))


def _fisheye_candidate(rng: np.random.Generator, cameras, board: Board) -> np.ndarray:
    """T_body_board (4, 4) of one random board pose in front of a random camera."""
    cam = cameras[int(rng.integers(len(cameras)))]
    w_px, h_px = cam.size
    w, h = board.squares[0] * board.square_length, board.squares[1] * board.square_length
    uv = np.array([[rng.uniform(-0.1, 1.1) * w_px, rng.uniform(-0.1, 1.1) * h_px]])
    ray = unproject(cam, uv)[0]
    if not np.all(np.isfinite(ray)):
        ray = np.array([0.0, 0.0, 1.0])
    d = float(np.clip(w * cam.K[0, 0] / (rng.uniform(0.3, 1.3) * w_px), 0.5, 3.0))
    x = np.array([1.0, 0, 0]) - ray[0] * ray  # board x along the camera's x, z along the ray
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - ray[1] * ray
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(ray, x), ray])
    a = rng.normal(size=2)
    a /= np.linalg.norm(a)
    R = R @ rotvec_R(np.array([a[0], a[1], 0.0]) * np.radians(rng.uniform(0, 50))) \
        @ rotvec_R([0, 0, np.radians(rng.uniform(-30, 30))])
    T_cam_board = pose(R, d * ray - R @ np.array([w / 2, h / 2, 0.0]))
    return cam.T_body_cam @ T_cam_board


def _cells_seen(cam: Camera, T_body_board: np.ndarray, board: Board) -> np.ndarray:
    """(G*G,) inner corners of the board that `cam` sees well in each image cell: inside the
    image (3 px margin), printed face towards the camera, seen less obliquely than 75
    degrees, squares at least 10 px."""
    nx, ny = board.squares
    gx, gy = np.meshgrid(np.arange(1, nx), np.arange(1, ny))
    P = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]) * board.square_length
    T = inv(cam.T_body_cam) @ T_body_board
    p = P @ T[:3, :3].T + T[:3, 3]
    n = T[:3, 2]  # into the print: points away from a camera that sees the printed face
    cos_view = (p @ n) / np.linalg.norm(p, axis=1)
    uv = project(cam, p)
    uv_dx = project(cam, p + 0.5 * board.square_length * T[:3, 0])
    w, h = cam.size
    in_field = p[:, 2] / np.linalg.norm(p, axis=1) > np.cos(np.radians(cam.max_theta_deg or 180.0))
    ok = (in_field & (cos_view > np.cos(np.radians(75))) & (uv[:, 0] > 3) & (uv[:, 0] < w - 4) & (uv[:, 1] > 3)
          & (uv[:, 1] < h - 4) & (np.linalg.norm(uv_dx - uv, axis=1) >= 5.0) & (np.linalg.norm(p, axis=1) > 0.1))
    uv_ok = uv[ok]
    cell = (np.clip((uv_ok[:, 1] / h * FISHEYE_GRID).astype(int), 0, FISHEYE_GRID - 1) * FISHEYE_GRID
            + np.clip((uv_ok[:, 0] / w * FISHEYE_GRID).astype(int), 0, FISHEYE_GRID - 1))
    return np.bincount(cell, minlength=FISHEYE_GRID ** 2).astype(float)


# ----------------------------------------------------------------------------- writing


FORMATS = ((".png", False), (".jpg", True), (".bmp", False), (".tif", True), (".png", True),
           (".jpg", False), (".tif", False), (".bmp", True))


def write_dataset(scene: Scene, out: Path, seed: int = 0, S: int = 4, drop: int = 2, corrupt: bool = True,
                  formats: tuple = FORMATS) -> dict:
    """Render `scene` into the dataset layout of dataset.md under `out`; write truth.yaml.

    Image k of a camera is written in formats[k % len(formats)] (extension, colour; FORMATS
    by default, e.g. ((".png", False),) for lossless grey only); every third one
    sits in out/store/ behind a relative symbolic link; `drop` frames per camera are left
    out (different ones per camera); with `corrupt`, one image of the last camera is a PNG
    cut short. Returns the truth as arrays plus what was written:
    {"cameras": {name: Camera}, "files": {(camera, stem): (path, ext, colour, link)},
     "missing": [(camera, stem)], "corrupt": (camera, stem) or None}."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    (out / "images").mkdir(parents=True, exist_ok=True)
    _write_yaml(out / "rig.yaml", scene.declared)
    _write_yaml(out / "target.yaml", {"boards": [b.yaml_entry() for b in scene.boards]})
    textures = {b.name: b.texture() for b in scene.boards}
    files, missing = {}, []
    n = len(scene.stems)
    corrupt_at = None
    for ci, cam in enumerate(scene.cameras):
        folder = out / "images" / cam.name
        store = out / "store" / cam.name
        folder.mkdir(parents=True, exist_ok=True)
        store.mkdir(parents=True, exist_ok=True)
        rays, valid = pixel_rays(cam, S)
        ph = scene.photometry.get(cam.name, Photometry())
        skip = {(ci * 3 + 1 + 5 * j) % n for j in range(drop)}
        if corrupt and ci == len(scene.cameras) - 1:
            corrupt_at = next(k for k in range(n - 1, -1, -1) if k not in skip)
        for k, stem in enumerate(scene.stems):
            if k in skip:
                missing.append((cam.name, stem))
                continue
            T_world_cam = scene.T_world_body[stem] @ cam.T_body_cam
            hits = [(*textures[b], inv(scene.T_world_board[stem][b]) @ T_world_cam)
                    for b in scene.T_world_board[stem]]
            radiance = render_radiance(rays, valid, S, hits)
            ext, colour = formats[k % len(formats)]
            img = develop(radiance, ph, colour, lighting_field(cam.size, rng), rng)
            link = k % 3 == 2
            target = (store if link else folder) / f"{stem}{ext}"
            params = [cv2.IMWRITE_JPEG_QUALITY, 92] if ext == ".jpg" else []
            ok, buf = cv2.imencode(ext, img, params)
            assert ok, f"OpenCV cannot encode {ext}"
            data = buf.tobytes()
            if k == corrupt_at:
                ext, data, link = ".png", cv2.imencode(".png", img)[1].tobytes(), False
                data = data[: len(data) // 3]  # cut short: the IEND chunk and most pixels are gone
                target = folder / f"{stem}.png"
            target.write_bytes(data)
            if link:
                os.symlink(os.path.relpath(target, folder), folder / f"{stem}{ext}")
            files[(cam.name, stem)] = (folder / f"{stem}{ext}", ext, colour, link)
    truth = _truth_doc(scene)
    _write_yaml(out / "truth.yaml", truth)
    return {"cameras": {c.name: c for c in scene.cameras}, "files": files, "missing": missing,
            "corrupt": (scene.cameras[-1].name, scene.stems[corrupt_at]) if corrupt_at is not None else None,
            "T_world_body": scene.T_world_body, "T_world_board": scene.T_world_board}


def _pose_doc(T: np.ndarray) -> dict:
    return {"rotation": [[float(x) for x in r] for r in T[:3, :3]], "position": [float(x) for x in T[:3, 3]]}


def _truth_doc(scene: Scene) -> dict:
    cams = {}
    for c in scene.cameras:
        d = {"model": c.model, "resolution": list(c.size),
             "intrinsics": {"fx": float(c.K[0, 0]), "fy": float(c.K[1, 1]), "cx": float(c.K[0, 2]),
                            "cy": float(c.K[1, 2])},
             "distortion": [float(x) for x in c.dist], **_pose_doc(c.T_body_cam)}
        d["quaternion"] = [float(x) for x in quat_wxyz(c.T_body_cam[:3, :3])]
        cams[c.name] = d
    rig = {"rig": scene.declared["rig"] + "-truth", "body_frame": "FLU", "cameras": cams,
           "stereo_pairs": scene.declared.get("stereo_pairs", [])}
    doc = {"rig": rig, "frames": {}}
    if scene.static_boards:
        first = scene.T_world_board[scene.stems[0]]
        doc["boards"] = {b: _pose_doc(T) for b, T in first.items()}
    for s in scene.stems:
        f = _pose_doc(scene.T_world_body[s])
        if not scene.static_boards:
            f["boards"] = {b: _pose_doc(T) for b, T in scene.T_world_board[s].items()}
        doc["frames"][s] = f
    doc["render"] = {"renderer": "tests/support/indie_render.py", "samples_per_pixel": "S x S box filter"}
    return doc


def _write_yaml(path: Path, doc: dict) -> None:
    path.write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None), encoding="utf-8")
