"""The part of `rigcal calibrate --report` for free-running cameras without an IMU
(rigcal.imucal.visual_motion): the continuous-time estimate's clock offsets and pose
sigmas per camera (with where the sigmas come from: formal, or raised to what the
recording's halves show), how the estimate was made (knots, smoothness prior, corner RMS),
and the rig's motion as the spline gives it with every image placed at its own time on the
reference camera's clock. The page's pose table shows this estimate's poses and sigmas
(rigcal.results.report.imu_step_sigma); the per-frame poses and residual figures above it
are the camera-only start's (images grouped by time)."""

from __future__ import annotations

import html

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rigcal.core import spline as spl
from rigcal.core.rig import Rig
from rigcal.imucal.visual_motion import VisualMotionResult
from rigcal.results.visual_outputs import sigma_source

MAX_SAMPLES = 4000  # spline samples per trace
AXES = ("x", "y", "z")
COLOURS = ("#1f77b4", "#2ca02c", "#d62728")


def clocks_table(out_rig: Rig, vm: VisualMotionResult, names: list[str]) -> str:
    """Per camera: clock offset to the reference camera and pose 1-sigma, with their source."""
    ref = names[vm.reference]
    rows = []
    for cam in out_rig.cameras:
        k = names.index(cam.name)
        s = vm.sigma[k]
        src = "held (the time base)" if k == vm.reference else sigma_source(vm, k)
        rows.append(f"<tr><td class=\"name\">{html.escape(cam.name)}</td><td>{1000 * vm.time_offset_s[k]:+.4f}</td>"
                    f"<td>{1000 * s[6]:.4f}</td><td>{' '.join(f'{1000 * x:.3f}' for x in s[3:6])}</td>"
                    f"<td>{' '.join(f'{np.degrees(x):.4f}' for x in s[:3])}</td><td>{html.escape(src)}</td></tr>")
    return ("<div class=\"table\"><table><tr><th class=\"name\">camera</th>"
            f"<th>time offset ms (t_{html.escape(ref)} = t_cam + offset)</th><th>1-sigma ms</th>"
            "<th>1-sigma position F L U (mm)</th><th>1-sigma rotation about F L U (deg)</th><th>sigmas from</th></tr>"
            + "".join(rows) + "</table></div>")


def caption(vm: VisualMotionResult, names: list[str]) -> str:
    a, al = vm.prior_sigma
    check = (vm.subsets.line(names) if vm.subsets is not None
             else "the sigmas are the formal ones (the recording's halves could not each be estimated)")
    text = (f"The rig's motion is a spline with knots every {1000 * vm.knot_dt:.0f} ms shaped by the views alone and "
            f"a smoothness prior (1-sigma {a:.3g} m/s^2, {al:.3g} rad/s^2 per knot); every image sits at its own "
            f"time plus its camera's clock offset. Corner RMS {vm.corner_rms_px:.3f} px, {vm.iterations} iterations, "
            f"{vm.seconds:.1f} s. Formal 1-sigma from the estimate's normal equations, corners weighted by their "
            f"measured noise; {check}.")
    return f"<p class=\"caption\">{html.escape(text)}</p>"


def trajectory_figure(vm: VisualMotionResult, names: list[str]) -> go.Figure:
    """The body position along the estimated spline (world axes) and, below, each camera's
    images with a board at their own times on the reference camera's clock."""
    sp_ = vm.state.spline
    n = int(min(MAX_SAMPLES, max(2, (sp_.t_end - sp_.t0) / sp_.dt * 8)))
    t = np.linspace(sp_.t0, sp_.t_end, n)
    p = spl.evaluate(sp_, t).p_world
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.08, row_heights=[0.7, 0.3],
                        subplot_titles=("body position, m (the estimate's world frame)",
                                        f"images with a board, on {names[vm.reference]}'s clock"))
    for k, (axis, colour) in enumerate(zip(AXES, COLOURS)):
        fig.add_trace(go.Scatter(x=t, y=p[:, k], mode="lines", line=dict(color=colour, width=1.5),
                                 name=f"position {axis}"), row=1, col=1)
    if vm.image_t is not None:
        for c, name in enumerate(names):
            tc = vm.image_t[vm.image_cam == c]
            fig.add_trace(go.Scatter(x=tc, y=[name] * len(tc), mode="markers", marker=dict(size=4),
                                     name=f"{name} images"), row=2, col=1)
    fig.update_xaxes(title_text=f"t, s on {names[vm.reference]}'s clock from the recording's first image", row=2, col=1)
    return fig.update_layout(height=560, margin=dict(l=50, r=20, t=40, b=40))


def visual_section(out_rig: Rig, vm: VisualMotionResult, names: list[str]) -> str:
    """The section's HTML (plotly.js is the page's, embedded once by rigcal.results.report)."""
    cfg = {"displaylogo": False, "responsive": True}
    return "\n".join([
        "<h2>Free-running cameras: clock offsets and poses of the continuous-time estimate</h2>",
        clocks_table(out_rig, vm, names), caption(vm, names),
        "<h2>Free-running cameras: the rig's motion and every image's time</h2>",
        trajectory_figure(vm, names).to_html(full_html=False, include_plotlyjs=False, div_id="fig-visual-motion",
                                             config=cfg)])


def with_visual_section(page: str, out_rig: Rig, vm: VisualMotionResult, names: list[str]) -> str:
    """The report page with the free-running section before its end."""
    end = page.rindex("</body>")
    return page[:end] + visual_section(out_rig, vm, names) + "\n" + page[end:]
