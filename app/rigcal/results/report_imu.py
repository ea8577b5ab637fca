"""The camera-IMU part of `rigcal calibrate --report`: the IMU's gyroscope and
accelerometer as measured and as the estimate predicts them over the recording, the
residual histograms against the Gaussian the declared noise densities predict, and the
cameras' clock offsets (and line delays) with their 1-sigma.

Predicted = the residual blocks' model at the final estimate (rigcal.imucal.residuals:
spline motion, R_body_imu, biases, gravity), so measured minus predicted is exactly what
the estimator minimised. Long recordings are thinned to MAX_SAMPLES per trace (every k-th
sample: the page stays light); the histograms use every sample.
"""

from __future__ import annotations

import html
import math

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rigcal.imucal import residuals as ir
from rigcal.imucal.step import ImuCalibration, imu_input
from rigcal.data.imu_csv import ImuSamples
from rigcal.core.rig import Rig

MAX_SAMPLES = 4000  # per time-series trace
HIST_BINS = 60
AXES = ("x", "y", "z")
COLOURS = ("#1f77b4", "#2ca02c", "#d62728")


def readings(res: ImuCalibration, samples: ImuSamples) -> dict:
    """The samples the estimator used: t (N,) seconds since the first IMU sample, measured
    and predicted gyroscope (rad/s) and accelerometer (m/s^2) (N, 3) each, and the declared
    discrete noise (density * sqrt(rate)) of both."""
    state = res.result.state
    imu = imu_input(samples, res.imu, int(samples.t_ns[0]))
    sp_ = state.spline
    use = (imu.t >= sp_.t0 + 0.5 * sp_.dt) & (imu.t <= sp_.t_end - 0.5 * sp_.dt)
    t = imu.t[use]
    lay = ir.layout_for(state)
    mj = ir.motion_jacobian(state, t)
    g = ir.gyro_block(state, lay, t, imu.gyro[use], 1.0, mj).r  # predicted - measured, unweighted
    a = ir.accel_block(state, lay, t, imu.accel[use], 1.0, mj).r
    return {"t": t, "gyro": imu.gyro[use], "gyro_pred": imu.gyro[use] + g, "accel": imu.accel[use],
            "accel_pred": imu.accel[use] + a, "gyro_sigma": res.gyro_predicted, "accel_sigma": res.accel_predicted}


def series_figure(r: dict) -> go.Figure:
    """Measured (thin) and predicted (dashed) gyroscope and accelerometer, per axis."""
    step = max(1, math.ceil(len(r["t"]) / MAX_SAMPLES))
    t = r["t"][::step]
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.07,
                        subplot_titles=("gyroscope, rad/s (IMU axes)", "accelerometer, m/s^2 (IMU axes)"))
    for row, key in ((1, "gyro"), (2, "accel")):
        for k, (axis, colour) in enumerate(zip(AXES, COLOURS)):
            fig.add_trace(go.Scattergl(x=t, y=r[key][::step, k], mode="lines", line=dict(color=colour, width=1),
                                       opacity=0.55, name=f"{key} {axis} measured", legendgroup=f"{key}{axis}"),
                          row=row, col=1)
            fig.add_trace(go.Scattergl(x=t, y=r[key + "_pred"][::step, k], mode="lines",
                                       line=dict(color=colour, width=1, dash="dash"), name=f"{key} {axis} predicted",
                                       legendgroup=f"{key}{axis}"), row=row, col=1)
    fig.update_xaxes(title_text="t, s since the first IMU sample", row=2, col=1)
    return fig.update_layout(height=620, margin=dict(l=50, r=20, t=40, b=40))


def histogram_figure(r: dict) -> go.Figure:
    """Measured minus predicted, every axis pooled, in units of the declared noise, beside
    the unit Gaussian the declared densities predict."""
    fig = make_subplots(rows=1, cols=2, subplot_titles=("gyroscope residual / declared noise",
                                                        "accelerometer residual / declared noise"))
    x = np.linspace(-5, 5, 201)
    for col, key in ((1, "gyro"), (2, "accel")):
        z = ((r[key] - r[key + "_pred"]) / r[key + "_sigma"]).ravel()
        fig.add_trace(go.Histogram(x=np.clip(z, -5, 5), xbins=dict(start=-5, end=5, size=10 / HIST_BINS),
                                   histnorm="probability density", name=f"{key} residuals",
                                   marker_color="#1f77b4", opacity=0.7), row=1, col=col)
        fig.add_trace(go.Scatter(x=x, y=np.exp(-0.5 * x * x) / math.sqrt(2 * math.pi), mode="lines",
                                 line=dict(color="#d62728"), name="declared noise (unit Gaussian)",
                                 showlegend=col == 1), row=1, col=col)
    return fig.update_layout(height=380, bargap=0.02, margin=dict(l=50, r=20, t=40, b=40))


def clocks_table(out_rig: Rig, res: ImuCalibration) -> str:
    """Per camera: time offset and line delay with their 1-sigma; then the IMU's residuals."""
    rows = []
    for cam in out_rig.cameras:
        s = (cam.calibration or {}).get("sigma", {})
        delay = "-" if cam.line_delay_s is None else f"{1e6 * cam.line_delay_s:.3f}"
        delay_sd = f"{s['line_delay_us']:.3f}" if "line_delay_us" in s else "-"
        rows.append(f"<tr><td class=\"name\">{html.escape(cam.name)}</td><td>{1000 * (cam.time_offset_s or 0):+.4f}"
                    f"</td><td>{s.get('time_offset_ms', float('nan')):.4f}</td><td>{delay}</td><td>{delay_sd}</td></tr>")
    cams = ("<div class=\"table\"><table><tr><th class=\"name\">camera</th><th>time offset ms "
            "(t_imu = t_cam + offset)</th><th>1-sigma ms</th><th>line delay us/row</th><th>1-sigma us</th></tr>"
            + "".join(rows) + "</table></div>")
    imu = ("<div class=\"table\"><table><tr><th class=\"name\">" + html.escape(res.imu.name) + "</th><th>residual RMS"
           "</th><th>declared noise predicts</th><th>ratio</th></tr>"
           f"<tr><td class=\"name\">gyroscope, rad/s</td><td>{res.gyro_rms:.4g}</td><td>{res.gyro_predicted:.4g}</td>"
           f"<td>{res.gyro_rms / res.gyro_predicted:.2f}</td></tr>"
           f"<tr><td class=\"name\">accelerometer, m/s^2</td><td>{res.accel_rms:.4g}</td>"
           f"<td>{res.accel_predicted:.4g}</td><td>{res.accel_rms / res.accel_predicted:.2f}</td></tr></table></div>")
    return cams + imu


def model_caption(res: ImuCalibration) -> str:
    """The IMU model kept (`--imu-model`) and the test behind it; for scale-misalignment
    each sensor's M - I (scales on the diagonal, misalignments below it)."""
    t = res.model_test
    why = (f"likelihood ratio {t.statistic:.1f}, {t.imu_statistic:.1f} of it in the IMU's residuals, on 12 "
           f"parameters; both need {t.threshold:.1f} at p = {t.level:g}"
           if t is not None else f"--imu-model {res.imu_model}, not tested")
    text = f"IMU model: {res.imu_model} ({why})."
    if res.imu_model == "scale-misalignment":
        st = res.result.state
        for label, M in (("gyroscope", st.M_gyro), ("accelerometer", st.M_accel)):
            rows = "; ".join(" ".join(f"{x:+.5f}" for x in row[:k + 1]) for k, row in enumerate(M - np.eye(3)))
            text += f" {label} M - I (lower triangle, rows): {rows}."
    return f"<p class=\"caption\">{html.escape(text)}</p>"


def imu_section(out_rig: Rig, res: ImuCalibration, samples: ImuSamples) -> str:
    """The section's HTML (plotly.js is the page's, embedded once by rigcal.results.report)."""
    r = readings(res, samples)
    cfg = {"displaylogo": False, "responsive": True}
    parts = ["<h2>Camera-IMU: clocks and IMU residuals</h2>", clocks_table(out_rig, res),
             "<p class=\"caption\">1-sigma from the camera-IMU estimate's normal equations, corners weighted by "
             "their measured noise, the IMU by its declared densities.</p>", model_caption(res),
             f"<h2>IMU {html.escape(res.imu.name)}: measured and predicted</h2>",
             series_figure(r).to_html(full_html=False, include_plotlyjs=False, div_id="fig-imu-series", config=cfg),
             f"<h2>IMU {html.escape(res.imu.name)}: residuals against the declared noise</h2>",
             histogram_figure(r).to_html(full_html=False, include_plotlyjs=False, div_id="fig-imu-hist", config=cfg)]
    return "\n".join(parts)


def with_imu_section(page: str, out_rig: Rig, res: ImuCalibration, samples: ImuSamples) -> str:
    """The report page with the camera-IMU section before its end."""
    end = page.rindex("</body>")
    return page[:end] + imu_section(out_rig, res, samples) + "\n" + page[end:]
