"""`rigcal imu-noise --report`: one HTML page (plotly embedded, works offline) with, per IMU
and sensor, the Allan deviation of each axis on log-log axes, its 95 % confidence band
(chi-square with the edf used in the fit), the fitted lines of the white noise (slope
-1/2), random walk (+1/2) and bias instability (flat, 0.664 B), drawn over the tau range
each was fitted on, and those ranges shaded."""

from __future__ import annotations

import html

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots
from scipy.stats import chi2

from rigcal.imunoise.estimate import AXES, UNITS, ImuNoise
from rigcal.imunoise.terms import CONFIDENCE, FLAT

COLOURS = ("#1f77b4", "#2ca02c", "#d62728")
RANGE_FILL = {"white": "rgba(31,119,180,0.08)", "random_walk": "rgba(214,39,40,0.08)",
              "bias_instability": "rgba(44,160,44,0.08)"}


def _band(adev: np.ndarray, nu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo_q, hi_q = chi2.ppf((1 + CONFIDENCE) / 2, nu), chi2.ppf((1 - CONFIDENCE) / 2, nu)
    return adev * np.sqrt(nu / lo_q), adev * np.sqrt(nu / hi_q)


def figure(noise: ImuNoise) -> go.Figure:
    fig = make_subplots(rows=1, cols=2, subplot_titles=[f"{noise.name} gyroscope (rad/s)",
                                                         f"{noise.name} accelerometer (m/s^2)"])
    for col, sensor in enumerate(noise.sensors(), start=1):
        for k, (ax, a) in enumerate(zip(AXES, sensor.axes)):
            c, colour, group = a.curve, COLOURS[k], f"{sensor.sensor}-{ax}"
            lo, hi = _band(c.adev, a.edf)
            fig.add_trace(go.Scatter(x=np.concatenate([c.tau, c.tau[::-1]]), y=np.concatenate([hi, lo[::-1]]),
                                     fill="toself", fillcolor=colour, opacity=0.15, line=dict(width=0),
                                     hoverinfo="skip", legendgroup=group, showlegend=False), row=1, col=col)
            fig.add_trace(go.Scatter(x=c.tau, y=c.adev, mode="lines+markers", line=dict(color=colour),
                                     name=f"{sensor.sensor} {ax}", legendgroup=group), row=1, col=col)
            for term, shape in (("white", lambda t, v: v / np.sqrt(t)),
                                ("random_walk", lambda t, v: v * np.sqrt(t / 3)),
                                ("bias_instability", lambda t, v: np.full_like(t, v * np.sqrt(FLAT)))):
                f = getattr(a, term)
                t = np.geomspace(f.tau_lo, f.tau_hi, 20) if f.tau_hi > f.tau_lo else np.array([f.tau_lo / 1.5,
                                                                                                f.tau_lo * 1.5])
                fig.add_trace(go.Scatter(x=t, y=shape(t, f.value), mode="lines", line=dict(color=colour, dash="dash"),
                                         name=f"{ax} {term.replace('_', ' ')} {f.value:.3g}", legendgroup=group,
                                         showlegend=False, hovertemplate=f"{ax} {term}: {f.value:.3g}<extra></extra>"),
                              row=1, col=col)
        for term in ("white", "random_walk", "bias_instability"):
            f = getattr(sensor, term)
            fig.add_vrect(x0=f.tau_lo, x1=max(f.tau_hi, f.tau_lo * 1.05), fillcolor=RANGE_FILL[term], line_width=0,
                          row=1, col=col)
        fig.update_xaxes(type="log", title_text="tau (s)", row=1, col=col)
        fig.update_yaxes(type="log", title_text="Allan deviation", row=1, col=col)
    fig.update_layout(height=520, margin=dict(l=60, r=20, t=60, b=50))
    return fig


def _summary(noise: ImuNoise) -> str:
    rows = []
    for s in noise.sensors():
        units = UNITS[s.sensor]
        for term, unit in zip(("white", "random_walk", "bias_instability"), units):
            f = getattr(s, term)
            rows.append(f"<tr><td>{s.sensor}</td><td>{term.replace('_', ' ')}</td><td>{f.value:.4g} {unit}</td>"
                        f"<td>[{f.lo:.3g}, {f.hi:.3g}]</td><td>{f.tau_lo:.3g}-{f.tau_hi:.3g} s</td></tr>")
    return ("<table><tr><th>sensor</th><th>figure</th><th>value (largest axis)</th><th>95 % interval</th>"
            "<th>tau range fitted</th></tr>" + "".join(rows) + "</table>")


def page(noises: list[ImuNoise]) -> str:
    parts = []
    for i, n in enumerate(noises):
        c = n.checked
        parts.append(f"<h2>{html.escape(n.name)}</h2><p>{html.escape(c.recording.source)}: "
                     f"{len(c.recording.t_ns)} samples at {c.rate_hz:.2f} Hz; shaded: the tau ranges of the white "
                     f"noise (blue), bias instability (green) and random walk (red) of the largest axis; dashed: "
                     f"each axis' fitted lines; bands: 95 % intervals.</p>" + _summary(n))
        parts.append(figure(n).to_html(full_html=False, include_plotlyjs=(i == 0), div_id=f"allan-{n.name}"))
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>rigcal imu-noise</title>"
            "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:3px 8px}</style></head><body><h1>IMU noise: Allan deviation</h1>"
            + "".join(parts) + "</body></html>\n")
