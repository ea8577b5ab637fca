"""A synthetic calibration and its HTML report, shared by the report and browser tests."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

import rigcal
from rigcal.camcal import stereo_checks as checks
from rigcal.camcal.pipeline import calibrate_views
from rigcal.results import outputs, report
from tests.support.synthetic_obs import noisy_room, perturb

RIG = "rigs/drone-stereo-back.yaml"
N_FRAMES = 15
PLANTED = 3  # corners per spoiled view
FIGURE_IDS = ["fig-rig", "fig-camera-0", "fig-camera-1", "fig-camera-2", "fig-frame-rms", "fig-depth-0", "fig-poses"]


@functools.lru_cache(maxsize=1)
def synthetic_calibration():
    """(cal, out_rig, pairs, n_spoiled) for drone-stereo-back seen in the room scene, with
    gross errors planted in every 7th view (n_spoiled views) so the report has rejected
    corners to draw. Cached: the browser test reuses it."""
    rig = rigcal.load_rig(RIG)
    rng = np.random.default_rng(5)
    truth = perturb(rig, rng)
    views, corners = noisy_room(truth, rng, 0.1, n_frames=N_FRAMES)
    spoiled = range(0, len(views), 7)
    for k in spoiled:
        uv = views[k].uv.copy()
        uv[:PLANTED] += [12.0, -9.0]
        views[k] = dataclasses.replace(views[k], uv=uv)
    cal = calibrate_views(views, rig, corners)
    pairs = checks.stereo_checks(cal)
    return cal, outputs.calibrated_rig(cal, pairs, dataset="synthetic"), pairs, len(spoiled)


def synthetic_report_html() -> str:
    cal, out_rig, pairs, _ = synthetic_calibration()
    return report.build_report(cal, out_rig, None, pairs, dict(cal.timings, total_s=1.0))
