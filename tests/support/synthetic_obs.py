"""Test-only helpers on top of rigcal.sim.synthetic (which holds the scene generator).

`perturb` is the tests' own true-rig perturbation: unlike rigcal.sim.simulate.perturb_rig
(what `rigcal simulate` applies), its knobs let a test choose the lens errors, and a
pinhole truth gets a full 5-coefficient distortion drawn from zero."""

from __future__ import annotations

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.observations import BoardView
from rigcal.core.rig import Camera, Rig
from rigcal.sim.synthetic import room_scene, with_noise


def perturb(rig: Rig, rng, mm=5.0, deg=1.0, focal=0.02, pp=5.0, dist=True) -> Rig:
    cams = []
    for c in rig.cameras:
        m = c.intrinsics
        T = c.T_body_cam.copy()
        T[:3, :3] = geo.R_from_rotvec(rng.normal(0, np.radians(deg), 3)) @ T[:3, :3]
        T[:3, 3] += rng.normal(0, mm / 1000, 3)
        if m.model == "fisheye":
            d = tuple(np.array(m.dist) + rng.normal(0, [0.01, 0.005, 0.002, 0.001]))
        else:
            d = (rng.normal(0, 0.05), rng.normal(0, 0.02), rng.normal(0, 5e-4), rng.normal(0, 5e-4),
                 rng.normal(0, 0.002)) if dist else m.dist
        f = 1 + rng.normal(0, focal)
        mm_ = m.with_(fx=m.fx * f, fy=m.fy * f * (1 + rng.normal(0, 0.001)), cx=m.cx + rng.uniform(-pp, pp),
                      cy=m.cy + rng.uniform(-pp, pp), dist=tuple(float(x) for x in d))
        cams.append(Camera(c.name, mm_, T))
    return rig.with_cameras(cams)


def noisy_room(truth: Rig, rng, noise_px: float, **scene) -> tuple[list[BoardView], dict[str, np.ndarray]]:
    """(views, corners by board) of rigcal.sim.synthetic.room_scene(truth, rng, **scene) with
    noise_px Gaussian pixel noise drawn from the same rng after the scene."""
    sc = room_scene(truth, rng, **scene)
    return with_noise(sc.views, noise_px, rng), dict(sc.corners)


def central_jacobian(fun, x: np.ndarray) -> np.ndarray:
    """(len(fun(x)), len(x)) central-difference Jacobian of fun at x, step 1e-6 relative
    (absolute below 1): the tests' reference for analytic Jacobians."""
    J = np.empty((len(fun(x)), len(x)))
    for k in range(len(x)):
        h = 1e-6 * max(1.0, abs(x[k]))
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        J[:, k] = (fun(xp) - fun(xm)) / (2 * h)
    return J
