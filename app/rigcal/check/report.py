"""The HTML report of `rigcal check` (--report): per camera the status, the tests and the
smallest detectable change, and the residual map of the new views under the rig's
calibration (where in the image the rig no longer fits). One self-contained page."""

from __future__ import annotations

from html import escape

import numpy as np
import plotly.graph_objects as go

from rigcal.check.estimate import NewEstimate
from rigcal.core.rig import Rig

CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 2px 8px; text-align: right; }
td:first-child, th:first-child { text-align: left; } .ok { color: #176117; } .bad { color: #a11; font-weight: bold; }
p.caption { color: #555; font-size: 0.9em; max-width: 60em; }
"""
# residual arrows are drawn this many times their length
ARROW_SCALE = 20.0


def _e(x) -> str:
    return escape(str(x))


def _row(cells, header: bool = False) -> str:
    tag = "th" if header else "td"
    return "<tr>" + "".join(f"<{tag}>{c}</{tag}>" for c in cells) + "</tr>"


def summary_table(res) -> str:
    rows = [_row(["camera", "status", "rotation deg F L U", "1-sigma", "position mm F L U", "1-sigma",
                  "pose chi2 / threshold", "relative to", "intrinsics change px (1-sigma)", "image shift px",
                  "intrinsics chi2 / threshold", "detectable rotation deg", "detectable position mm",
                  "detectable intrinsics px"], header=True)]
    for v in res.verdicts:
        p, i = v.pose, v.intrinsics
        cls = "ok" if v.status == "ok" else "bad"
        rows.append(_row([
            _e(v.name), f"<span class=\"{cls}\">{_e(v.status)}</span>",
            " ".join(f"{x:+.4f}" for x in p.rotation_deg) if p else "-",
            " ".join(f"{x:.4f}" for x in p.rotation_sigma_deg) if p else "-",
            " ".join(f"{x:+.3f}" for x in p.translation_mm) if p else "-",
            " ".join(f"{x:.3f}" for x in p.translation_sigma_mm) if p else "-",
            f"{p.test.statistic:.2f} / {p.test.threshold:.2f}" if p else "-",
            _e(", ".join(p.relative_to)) if p else "-",
            _e(", ".join(f"{k} {x:+.3f} ({i.sigma[k]:.3f})" for k, x in i.change.items())) if i else "-",
            f"{i.displacement_px:.3f}" if i else "-",
            f"{i.test.statistic:.2f} / {i.test.threshold:.2f}" if i else "-",
            " ".join(f"{x:.4f}" for x in p.detectable_rotation_deg) if p else "-",
            " ".join(f"{x:.3f}" for x in p.detectable_translation_mm) if p else "-",
            _e(", ".join(f"{k} {x:.3f}" for k, x in i.detectable.items())) if i else "-"]))
    return "<table>" + "".join(rows) + "</table>"


def imu_table(res) -> str:
    """Per camera checked against the IMU: its pose change relative to the IMU and clock
    offset change with 1-sigma, both tests and the smallest changes they detect; '' when none."""
    rows = [_row(["camera", "IMU", "rotation deg F L U", "1-sigma", "position mm F L U", "1-sigma",
                  "pose chi2 / threshold", "clock offset change ms (1-sigma)", "clock chi2 / threshold",
                  "detectable rotation deg", "detectable position mm", "detectable clock ms"], header=True)]
    for v in res.verdicts:
        m = v.imu
        if m is None:
            continue
        rows.append(_row([
            _e(v.name), _e(m.imu), " ".join(f"{x:+.4f}" for x in m.rotation_deg),
            " ".join(f"{x:.4f}" for x in m.rotation_sigma_deg), " ".join(f"{x:+.3f}" for x in m.translation_mm),
            " ".join(f"{x:.3f}" for x in m.translation_sigma_mm),
            f"{m.pose_test.statistic:.2f} / {m.pose_test.threshold:.2f}",
            f"{m.offset_ms:+.3f} ({m.offset_sigma_ms:.3f})",
            f"{m.offset_test.statistic:.2f} / {m.offset_test.threshold:.2f}",
            " ".join(f"{x:.4f}" for x in m.detectable_rotation_deg),
            " ".join(f"{x:.3f}" for x in m.detectable_translation_mm), f"{m.detectable_offset_ms:.3f}"]))
    return "<table>" + "".join(rows) + "</table>" if len(rows) > 1 else ""


def residual_figure(rig: Rig, est: NewEstimate, r_old: np.ndarray, c: int) -> go.Figure:
    """Camera c's corners in the image, coloured by the distance px between where the new
    views show them and where the rig's calibration puts them, with the miss as an arrow
    (ARROW_SCALE times longer)."""
    name = est.names[c]
    m = rig.camera(name).intrinsics
    sel = (est.obs.cam == c) & np.all(np.isfinite(r_old), axis=1)
    uv, r = est.obs.uv[sel], r_old[sel]
    mag = np.linalg.norm(r, axis=1)
    fig = go.Figure()
    ends = uv - ARROW_SCALE * r  # the arrow points from where the rig puts the corner to where it is seen
    xs = np.column_stack([ends[:, 0], uv[:, 0], np.full(len(uv), np.nan)]).ravel()
    ys = np.column_stack([ends[:, 1], uv[:, 1], np.full(len(uv), np.nan)]).ravel()
    fig.add_trace(go.Scattergl(x=xs, y=ys, mode="lines", line={"width": 1, "color": "#888"}, hoverinfo="skip",
                               name=f"miss x{ARROW_SCALE:g}"))
    fig.add_trace(go.Scattergl(x=uv[:, 0], y=uv[:, 1], mode="markers", name="corners",
                               marker={"size": 5, "color": mag, "colorscale": "Viridis", "showscale": True,
                                       "colorbar": {"title": {"text": "px"}}},
                               text=[f"{x:.3f} px" for x in mag], hoverinfo="text"))
    rms = float(np.sqrt(np.mean(mag**2))) if len(mag) else float("nan")
    fig.update_layout(title=f"{name}: new views under the rig's calibration (RMS {rms:.3f} px)", height=520,
                      xaxis={"range": [-0.5, m.width - 0.5], "title": {"text": "u (px)"}},
                      yaxis={"range": [m.height - 0.5, -0.5], "scaleanchor": "x", "title": {"text": "v (px)"}},
                      margin={"l": 40, "r": 10, "t": 50, "b": 40})
    return fig


def build_report(res, rig: Rig, est: NewEstimate | None, r_old: np.ndarray | None) -> str:
    """The whole page as one HTML string (plotly.js embedded once)."""
    body = [f"<h1>rigcal check: {_e(rig.name)} against {_e(res.dataset)}</h1>",
            f"<p>rig {_e(res.rig_path)}; false-alarm rate {res.level:g} for the whole check: {res.n_tests} "
            f"chi-square tests at {res.level_each:.4g} each (Sidak). The new rig is placed on the old by "
            f"{_e(', '.join(res.aligned_by) or '-')}; each camera's pose is tested against the cameras listed "
            f"beside it. Detectable: the smallest change along one axis or parameter that this recording "
            f"flags in 80 % of recordings like it.</p>",
            "<h2>Cameras</h2>", summary_table(res)]
    if any(v.imu is not None for v in res.verdicts):
        body += ["<h2>Cameras against the IMU (pose relative to it, clock offset)</h2>", imu_table(res)]
    notes = [n for v in res.verdicts for n in v.notes] + list(res.notes)
    if notes:
        body += ["<h2>Notes</h2>", "<ul>" + "".join(f"<li>{_e(n)}</li>" for n in notes) + "</ul>"]
    if est is not None and r_old is not None:
        body.append("<h2>Residuals of the new views under the rig's calibration</h2><p class=\"caption\">Each "
                    "corner of the new recording, coloured by how far (px) the rig's calibration puts it from "
                    "where it is seen; the frames and boards are placed by the new views, carried into the "
                    "rig's body frame by the unchanged cameras. A turned camera shows one direction "
                    "everywhere, a changed focal length arrows pointing out of or into the centre.</p>")
        for c in range(len(est.names)):
            html = residual_figure(rig, est, r_old, c).to_html(full_html=False, include_plotlyjs=c == 0,
                                                                div_id=f"fig-check-{c}",
                                                                config={"displaylogo": False})
            body.append(html)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>rigcal check: {_e(rig.name)}</title><style>{CSS}</style></head>\n<body>\n"
            + "\n".join(body) + "\n</body></html>\n")
