"""`rigcal calibrate --report`: one self-contained HTML page that says whether to trust a calibration.

Tables (per camera intrinsics with 1-sigma, pose and its 1-sigma about the body axes,
per stereo pair baseline and depth check, detection, timings, warnings) and plotly
figures: the rig in FLU, per camera the corner coverage over the image, residual
scatter and histogram, per-frame RMS, depth error versus distance per stereo pair,
and the board and body poses of the solve. Plotly's JavaScript is embedded once, so
the page works offline. No timestamps: the same calibration gives the same page.

Residuals are predicted minus measured pixels (the solver's `Problem.residuals`) at
the solution, for every observation; outliers are the corners the solver rejected
(`Calibration.inliers` False).
"""

from __future__ import annotations

import html
import io
from collections.abc import Mapping

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rigcal import __version__
from rigcal.core import geometry as geo
from rigcal.camcal.stereo_checks import depth_samples as checks_depth_samples
from rigcal.camcal.pipeline import Calibration
from rigcal.results.outputs import structure_text, warnings_for
from rigcal.core.rig import Rig
from rigcal.camcal.solve import Problem
from rigcal.results.view import BODY_COLOURS, rig_figure

MAX_POINTS = 5000  # drawn per scatter trace; beyond it a seeded subset (the page stays light)
INLIER_COLOUR = "#1f77b4"
OUTLIER_COLOUR = "#d62728"
HIST_BINS = 40
PLOT_CONFIG = {"displaylogo": False, "responsive": True}
AXES = ("F", "L", "U")

CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
div.table { overflow-x: auto; max-width: 100%; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.88em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: right; white-space: nowrap; }
th { background: #f2f2f2; white-space: normal; } td.name, th.name { text-align: left; }
td.wrap { white-space: normal; max-width: 16em; }
ul.warn li { color: #a00; } ul.note li { color: #444; }
pre { background: #f7f7f7; padding: 0.5em; font-size: 0.85em; overflow-x: auto; }
.caption { color: #555; font-size: 0.88em; max-width: 70em; }
"""


# ----------------------------------------------------------------------------- data


def all_residuals(cal: Calibration) -> np.ndarray:
    """(M, 2) predicted minus measured pixels at the solution for every observation in
    cal.obs, outliers included (the solver's own problem holds the inliers only)."""
    pb = Problem(cal.obs, cal.state, cal.problem.gauge_cam, cal.problem.gauge_board, cal.problem.fix_intr)
    return pb.residuals(pb.x0()).reshape(-1, 2)


def frame_rms(cal: Calibration, e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per (camera, frame): inlier RMS (px; NaN where the camera saw no inlier corner),
    inlier count and outlier count, each (C, F)."""
    C, F = len(cal.cam_names), len(cal.frames)
    key = cal.obs.cam * F + cal.obs.frame
    inl = cal.inliers
    sq = np.bincount(key[inl], weights=np.sum(e[inl] ** 2, axis=1), minlength=C * F)
    n_in = np.bincount(key[inl], minlength=C * F)
    n_out = np.bincount(key[~inl], minlength=C * F)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(n_in > 0, np.sqrt(sq / np.maximum(n_in, 1)), np.nan)
    return rms.reshape(C, F), n_in.reshape(C, F), n_out.reshape(C, F)


def depth_samples(cal: Calibration, left: str, right: str):
    """(z_pose, rel, frames) of the depth check's corners (checks.depth_samples); None when
    the pair shares no usable corner or cannot be rectified."""
    try:
        ds = checks_depth_samples(cal, left, right)
    except ValueError:
        return None
    if ds is None:
        return None
    return ds.z_pose, ds.rel, ds.frames


def _subset(n: int, cap: int = MAX_POINTS, seed: int = 0) -> np.ndarray:
    """Indices of at most `cap` of n items: all of them, or a seeded sorted random subset."""
    if n <= cap:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, cap, replace=False))


def _clip_radial(d: np.ndarray, limit: float) -> np.ndarray:
    """Vectors (N, 2) longer than `limit` shortened to it, direction kept."""
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d * np.minimum(1.0, limit / np.maximum(n, 1e-300))


def nearest_axes(R_body_cam: np.ndarray) -> tuple[str, float]:
    """The axis-aligned mounting closest to R_body_cam, as rig-yaml `axes` tokens for the
    camera's x, y, z, and the angle (deg) between the two; ("-", nan) when two camera axes
    are nearest the same body axis (exactly halfway between mountings). A proper rotation
    whose columns pick distinct axes always gives a proper signed permutation."""
    idx = np.argmax(np.abs(R_body_cam), axis=0)
    if len(set(idx.tolist())) < 3:
        return "-", float("nan")
    sign = np.sign(R_body_cam[idx, np.arange(3)])
    R_near = np.zeros((3, 3))
    R_near[idx, np.arange(3)] = sign
    tokens = [("-" if s < 0 else "") + AXES[i] for i, s in zip(idx, sign)]
    return "[" + ", ".join(tokens) + "]", geo.rotation_angle_deg(R_near.T @ R_body_cam)


# ----------------------------------------------------------------------------- html helpers


def _e(x) -> str:
    return html.escape(str(x))


def _f(x, nd: int) -> str:
    if x is None:
        return "-"
    x = float(x)
    return f"{x:.{nd}f}" if np.isfinite(x) else "-"


def _vec(v, nd: int) -> str:
    return "-" if v is None else " ".join(_f(x, nd) for x in v)


def _table(header: list[str], rows: list[list[str]], name_cols: int = 1, wrap: tuple[int, ...] = ()) -> str:
    """An HTML table; cells are already-escaped strings; the first name_cols columns align
    left, columns in `wrap` may break across lines."""
    def cell(tag, k, text):
        cls = "name" if k < name_cols else "wrap" if (k in wrap and tag == "td") else ""
        return f"<{tag} class=\"{cls}\">{text}</{tag}>" if cls else f"<{tag}>{text}</{tag}>"

    head = "".join(cell("th", k, _e(h)) for k, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell("td", k, c) for k, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<div class=\"table\"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>"


# ----------------------------------------------------------------------------- tables


def summary_html(cal: Calibration, out_rig: Rig) -> str:
    """The page's opening line: rig, cameras, frames, boards, RMS, reference."""
    top = out_rig.calibration or {}
    n_in = int(cal.inliers.sum())
    return (f"<p>rig <b>{_e(out_rig.name)}</b>, {len(cal.cam_names)} cameras, {len(cal.frames)} frames, "
            f"{len(cal.boards)} boards; reprojection RMS <b>{_f(cal.rms_px, 3)} px</b> over {n_in} corners "
            f"({len(cal.inliers) - n_in} outliers rejected), residual sigma {_f(cal.sigma_px, 3)} px; "
            f"body frame reference {_e(top.get('reference', cal.reference))}; "
            f"{_e(top.get('tool', 'rigcal ' + __version__))}"
            + (f"; dataset {_e(top['dataset'])}" if top.get("dataset") else "") + ".</p>")


def messages_html(cal: Calibration) -> str:
    """The calibration's warnings (outputs.warnings_for) and notes as lists."""
    warns = warnings_for(cal)
    parts = []
    if warns:
        parts.append("<ul class=\"warn\">" + "".join(f"<li>warning: {_e(w)}</li>" for w in warns) + "</ul>")
    else:
        parts.append("<p>No warnings: every extrinsic 1-sigma is within the thresholds.</p>")
    if cal.notes:
        parts.append("<ul class=\"note\">" + "".join(f"<li>note: {_e(n)}</li>" for n in cal.notes) + "</ul>")
    return "".join(parts)


def _pm(value: float, sigma: dict | None, key: str, nd: int) -> str:
    s = sigma.get(key) if sigma else None
    return _f(value, nd) + (f" &plusmn; {_f(s, nd)}" if s is not None else "")


def imu_step_sigma(out_rig: Rig, cam) -> dict | None:
    """The camera's 1-sigma block when the rig came through the camera-IMU step or the
    free-running cameras' continuous-time estimate (its poses, and intrinsics where that step
    estimated them, are that step's, and so are their sigmas), else None: the camera-only
    step's CameraStats hold them."""
    if not {"camera_imu", "free_running"} & set(out_rig.calibration or {}):
        return None
    return (cam.calibration or {}).get("sigma")


def intrinsics_table(cal: Calibration, out_rig: Rig) -> str:
    """Per camera its intrinsics and distortion with their 1-sigma."""
    rows = []
    for cam in out_rig.cameras:
        m, st = cam.intrinsics, cal.stats[cam.name]
        sig = (imu_step_sigma(out_rig, cam) or {}).get("intrinsics") or st.sigma_intrinsics
        rows.append([_e(cam.name), _e(m.model), _e(st.distortion_model), f"{m.width}x{m.height}",
                     _pm(m.fx, sig, "fx", 3), _pm(m.fy, sig, "fy", 3), _pm(m.cx, sig, "cx", 3),
                     _pm(m.cy, sig, "cy", 3), _e(_vec(m.dist, 5)), _f(st.rms_px, 3), str(st.observations),
                     str(st.frames), str(st.outliers)])
    return _table(["camera", "model", "distortion model", "size", "fx px", "fy px", "cx px", "cy px",
                   "distortion", "RMS px", "observations", "frames", "outliers"], rows, name_cols=3, wrap=(8,))


def model_choice_html(cal: Calibration, out_rig: Rig) -> str:
    """Why each camera has its distortion model and intrinsics structure: the tests pipeline.py ran, per camera."""
    items = [f"<li>{_e(cam.name)}: {_e(cal.stats[cam.name].distortion_model)}"
             + (f"; intrinsics {_e(structure_text(cal.stats[cam.name].intrinsics_model))}"
                if cal.stats[cam.name].intrinsics_model else "")
             + "".join(f"<br>{_e(line)}" for line in cal.stats[cam.name].model_selection) + "</li>"
             for cam in out_rig.cameras]
    return "<ul class=\"model\">" + "".join(items) + "</ul>"


def extrinsics_table(cal: Calibration, out_rig: Rig) -> str:
    """Per camera its pose in the body frame with its 1-sigma about and along F, L, U."""
    rows = []
    for cam in out_rig.cameras:
        st = cal.stats[cam.name]
        T = cam.T_body_cam
        axes, off = nearest_axes(T[:3, :3])
        imu_sig = imu_step_sigma(out_rig, cam)
        pos, rot = ((imu_sig["position_mm"], imu_sig["rotation_deg"]) if imu_sig and "position_mm" in imu_sig
                    else (st.sigma_position_mm, st.sigma_rotation_deg))
        rows.append([_e(cam.name), _e(_vec(T[:3, 3], 4)), _e(axes), _f(off, 3),
                     _e(_vec(geo.quat_from_R(T[:3, :3]), 5)), _e(_vec(pos, 3)), _e(_vec(rot, 4))])
    return _table(["camera", "position F L U (m)", "nearest axes (cam x, y, z)", "off axes (deg)",
                   "quaternion w x y z", "1-sigma position F L U (mm)", "1-sigma rotation about F L U (deg)"],
                  rows)


def stereo_table(out_rig: Rig, pairs: dict) -> str:
    """Per stereo pair its baseline and depth check (checks.stereo_checks)."""
    rows = []
    for p in out_rig.stereo_pairs:
        chk = pairs.get((p.left, p.right)) or {}
        dc = chk.get("depth_check") or {}
        overall = dc.get("overall") or {}
        s10 = chk.get("sanity_10m") or {}
        base = chk.get("baseline_m", p.baseline_m)
        rows.append([_e(f"{p.left} / {p.right}"), _f(None if base is None else 1000 * base, 3),
                     _f(dc.get("vertical_disparity_rms_px"), 4), str(dc.get("corners", "-")),
                     str(dc.get("frames", "-")), _f(overall.get("median_rel_error_pct"), 3),
                     _f(overall.get("p95_rel_error_pct"), 3), _f(s10.get("disparity_px"), 3),
                     _f(s10.get("depth_m"), 3)])
    return _table(["pair", "baseline mm", "vertical disparity RMS px", "corners", "frames",
                   "depth error median %", "depth error p95 %", "10 m ahead: disparity px",
                   "10 m ahead: depth m"], rows)


def bands_table(pair: tuple[str, str], chk: dict) -> str:
    """One pair's depth errors per distance band, against the board poses and the truth."""
    dc = (chk or {}).get("depth_check") or {}
    rows = []
    for kind, block in (("vs calibrated board pose", dc), ("vs truth", dc.get("vs_truth") or {})):
        for b in block.get("bands", []):
            lo, hi = b["range_m"]
            rows.append([_e(kind), f"{lo:g} - {'inf' if hi is None else f'{hi:g}'}", str(b["count"]),
                         _f(b["median_rel_error_pct"], 3), _f(b["p95_rel_error_pct"], 3)])
    if not rows:
        return f"<p>{_e(pair[0])} / {_e(pair[1])}: no corner seen by both cameras; no depth check.</p>"
    return (f"<p>{_e(pair[0])} / {_e(pair[1])}: relative depth error per depth band</p>"
            + _table(["against", "depth m", "corners", "median %", "p95 %"], rows))


def _per_camera(value, cam: str) -> str:
    """A detection count for one camera from a mapping of counts or lists; '-' when absent."""
    if isinstance(value, Mapping):
        v = value.get(cam)
        if v is None:
            return "-"
        return str(len(v)) if isinstance(v, (list, tuple, set)) else _e(v)
    return "-"


def detection_html(det, cal: Calibration) -> str:
    """Detection summary: the detector's own text plus per camera images and views."""
    if det is None:
        return "<p>No detection step: this calibration was built from given corners.</p>"
    parts = []
    summary = det.summary() if hasattr(det, "summary") else ""
    if summary:
        parts.append(f"<pre>{_e(summary if isinstance(summary, str) else _rich_text(summary))}</pre>")
    views = getattr(det, "views", []) or []
    rows = []
    for cam in cal.cam_names:
        rows.append([_e(cam), _per_camera(getattr(det, "n_images", {}), cam),
                     str(sum(1 for v in views if v.camera == cam)),
                     _per_camera(getattr(det, "no_board", {}), cam), _per_camera(getattr(det, "dropped", {}), cam)])
    parts.append(_table(["camera", "images", "board views", "no board", "dropped"], rows))
    unreadable = getattr(det, "unreadable", []) or []
    if unreadable:
        parts.append("<ul class=\"warn\">" + "".join(f"<li>{_e(p)}: skipped ({_e(r)})</li>" for p, r in unreadable)
                     + "</ul>")
    return "".join(parts)


def _rich_text(renderable) -> str:
    from rich.console import Console

    console = Console(width=120, record=True, file=io.StringIO())
    console.print(renderable)
    return console.export_text()


def timings_table(timings: dict) -> str:
    """Seconds per step of the command."""
    rows = [[_e(k.removesuffix("_s")), _f(v, 2)] for k, v in timings.items() if isinstance(v, (int, float))]
    return _table(["step", "seconds"], rows)


# ----------------------------------------------------------------------------- figures


def camera_figure(cal: Calibration, c: int, e: np.ndarray) -> go.Figure:
    """One camera: detected corners over the image (coverage), residual (dx, dy) scatter and
    the histogram of residual norms; inliers blue, rejected corners red."""
    name = cal.cam_names[c]
    m = cal.obs.cam == c
    inl = cal.inliers[m]
    uv, d = cal.obs.uv[m], e[m]
    norm = np.linalg.norm(d, axis=1)
    limit = 1.1 * float(norm[inl].max()) if inl.any() else float(norm.max(initial=1.0))
    n_out = int((~inl).sum())
    beyond = int((norm[~inl] > limit).sum())
    fig = make_subplots(rows=1, cols=3, column_widths=[0.42, 0.29, 0.29], horizontal_spacing=0.07, subplot_titles=(
        f"coverage: {int(m.sum())} corners<br>{n_out} rejected",
        f"residuals dx, dy<br>inlier RMS {_f(cal.stats[name].rms_px, 3)} px"
        + (f"; {beyond} rejected drawn at the edge" if beyond else ""),
        "|residual| histogram" + (f"<br>{beyond} rejected beyond the axis: last bin" if beyond else "")))
    _coverage(fig, cal.rig.camera(name).intrinsics, uv, inl)
    _residual_scatter(fig, d, inl, limit, [cal.frames[f] for f in cal.obs.frame[m]])
    _residual_histogram(fig, norm, inl, limit)
    fig.update_layout(title=f"camera {name}", height=440, margin={"l": 50, "r": 20, "t": 90, "b": 50},
                      legend={"orientation": "h", "y": -0.18}, bargap=0.05)
    return fig


def _coverage(fig: go.Figure, model, uv: np.ndarray, inl: np.ndarray) -> None:
    """Corners in image coordinates (y down) inside the drawn image border."""
    for mask, label, colour in ((inl, "inlier corners", INLIER_COLOUR), (~inl, "rejected corners", OUTLIER_COLOUR)):
        k = np.nonzero(mask)[0][_subset(int(mask.sum()))]
        if len(k) == 0:
            continue
        fig.add_trace(go.Scatter(x=uv[k, 0], y=uv[k, 1], mode="markers", name=label, legendgroup=label,
                                 marker={"size": 3 if colour == INLIER_COLOUR else 6, "color": colour},
                                 hoverinfo="x+y"), row=1, col=1)
    w, h = model.width, model.height
    fig.add_shape(type="rect", x0=-0.5, y0=-0.5, x1=w - 0.5, y1=h - 0.5, line={"color": "black"}, row=1, col=1)
    fig.update_xaxes(range=[-0.5 - 0.02 * w, w - 0.5 + 0.02 * w], title_text="u (px)", row=1, col=1)
    fig.update_yaxes(range=[h - 0.5 + 0.02 * h, -0.5 - 0.02 * h], title_text="v (px)", scaleanchor="x",
                     row=1, col=1)


def _residual_scatter(fig: go.Figure, d: np.ndarray, inl: np.ndarray, limit: float, frames: list[str]) -> None:
    """(dx, dy) per corner; rejected corners beyond the inliers' extent are drawn on its edge,
    their true values in the hover text."""
    k = np.nonzero(inl)[0][_subset(int(inl.sum()))]
    fig.add_trace(go.Scatter(x=d[k, 0], y=d[k, 1], mode="markers", name="inlier corners", legendgroup="inlier corners",
                             showlegend=False, marker={"size": 3, "color": INLIER_COLOUR, "opacity": 0.6},
                             hoverinfo="x+y"), row=1, col=2)
    k = np.nonzero(~inl)[0][_subset(int((~inl).sum()))]
    if len(k):
        shown = _clip_radial(d[k], limit)
        text = [f"frame {frames[i]}: dx {d[i, 0]:.2f}, dy {d[i, 1]:.2f} px" for i in k]
        fig.add_trace(go.Scatter(x=shown[:, 0], y=shown[:, 1], mode="markers", name="rejected corners",
                                 legendgroup="rejected corners", showlegend=False, text=text, hoverinfo="text",
                                 marker={"size": 6, "color": OUTLIER_COLOUR, "symbol": "x"}), row=1, col=2)
    fig.update_xaxes(range=[-limit, limit], title_text="dx (px)", row=1, col=2)
    fig.update_yaxes(range=[-limit, limit], title_text="dy (px)", scaleanchor="x2", row=1, col=2)


def _residual_histogram(fig: go.Figure, norm: np.ndarray, inl: np.ndarray, limit: float) -> None:
    """Counts of |residual| in shared bins up to the inliers' extent; rejected corners beyond
    it are counted in the last bin."""
    edges = np.linspace(0.0, limit, HIST_BINS + 1)
    centres = 0.5 * (edges[1:] + edges[:-1])
    for mask, label, colour in ((inl, "inlier corners", INLIER_COLOUR), (~inl, "rejected corners", OUTLIER_COLOUR)):
        if not mask.any():
            continue
        counts, _ = np.histogram(np.minimum(norm[mask], limit * (1 - 1e-12)), bins=edges)
        fig.add_trace(go.Bar(x=centres, y=counts, width=edges[1] - edges[0], name=label, legendgroup=label,
                             showlegend=False, marker={"color": colour}), row=1, col=3)
    fig.update_layout(barmode="stack")
    fig.update_xaxes(range=[0, limit], title_text="|residual| (px)", row=1, col=3)
    fig.update_yaxes(title_text="corners", row=1, col=3)


def frame_rms_figure(cal: Calibration, e: np.ndarray) -> go.Figure:
    """Heatmap camera x frame of the inlier RMS; a bad frame is a bright column, a bad
    camera a bright row. Hover gives corner and rejected counts."""
    rms, n_in, n_out = frame_rms(cal, e)
    text = np.char.add(np.char.add(n_in.astype(str), " corners, "), np.char.add(n_out.astype(str), " rejected"))
    fig = go.Figure(go.Heatmap(z=rms, x=list(cal.frames), y=list(cal.cam_names), text=text, colorscale="Viridis",
                               colorbar={"title": {"text": "RMS px"}}, xgap=1, ygap=1,
                               hovertemplate="camera %{y}, frame %{x}: RMS %{z:.3f} px, %{text}<extra></extra>"))
    fig.update_layout(title="per-frame reprojection RMS (inliers; blank: camera saw no board in that frame)",
                      height=max(260, 60 + 40 * len(cal.cam_names)), xaxis={"title": {"text": "frame"},
                                                                            "type": "category"},
                      margin={"l": 110, "r": 20, "t": 50, "b": 60})
    return fig


def depth_figure(cal: Calibration, left: str, right: str, chk: dict | None) -> go.Figure | None:
    """Relative depth error (%) of Z = B f / d per shared corner against its depth from the
    calibrated board pose, with the band medians and 95th percentiles of the depth check."""
    s = depth_samples(cal, left, right)
    if s is None or len(s[0]) == 0:
        return None
    z, rel, frames = s
    k = _subset(len(z))
    fig = go.Figure(go.Scatter(x=z[k], y=100 * rel[k], mode="markers", name="corners",
                               marker={"size": 3, "color": INLIER_COLOUR, "opacity": 0.5},
                               text=[cal.frames[f] for f in frames[k]],
                               hovertemplate="frame %{text}: depth %{x:.3f} m, error %{y:.3f} %<extra></extra>"))
    bands = ((chk or {}).get("depth_check") or {}).get("bands", [])
    if bands:
        mid = [_band_centre(b["range_m"], z) for b in bands]
        for key, label, dash in (("median_rel_error_pct", "band median |error|", "solid"),
                                 ("p95_rel_error_pct", "band p95 |error|", "dash")):
            fig.add_trace(go.Scatter(x=mid, y=[b[key] for b in bands], mode="lines+markers", name=label,
                                     line={"color": "black", "dash": dash}))
    fig.update_layout(title=f"stereo {left} / {right}: depth from disparity vs calibrated board-pose depth",
                      xaxis={"title": {"text": "depth (m, rectified left axis)"}},
                      yaxis={"title": {"text": "relative depth error (%)"}}, height=420,
                      margin={"l": 60, "r": 20, "t": 50, "b": 50})
    return fig


def _band_centre(range_m: list, z: np.ndarray) -> float:
    """Where to draw a band's statistic: the median depth of the corners inside it."""
    lo, hi = range_m
    inside = z[(z >= lo) & (z < (np.inf if hi is None else hi))]
    return float(np.median(inside)) if len(inside) else float(lo)


def poses_figure(cal: Calibration) -> go.Figure:
    """Boards (rectangles spanned by their observed corners) and the body pose of every
    frame (F, L, U axes), in the solver's world frame, which is the gauge board's frame."""
    fig = go.Figure()
    for b, name in enumerate(cal.boards):
        p = cal.obs.p_board[cal.obs.board == b]
        if len(p) == 0:
            continue
        (x0, y0), (x1, y1) = p[:, :2].min(0), p[:, :2].max(0)
        rect = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0], [x0, y0, 0]])
        q = geo.transform(cal.state.T_world_board[b], rect)
        fig.add_trace(go.Scatter3d(x=q[:, 0], y=q[:, 1], z=q[:, 2], mode="lines+text", name=f"board {name}",
                                   text=[name, "", "", "", ""], line={"color": "#444", "width": 4}))
    seen = np.unique(cal.obs.frame[cal.inliers])
    # frame poses of the output body (FLU), not the solver's gauge camera
    T_world_body = np.array([geo.inv_T(cal.state.T_body_world[f]) @ geo.inv_T(cal.T_body_solve) for f in seen])
    centres = T_world_body[:, :3, 3]
    extent = np.ptp(np.vstack([centres, cal.state.T_world_board[:, :3, 3]]), axis=0).max()
    length = 0.08 * max(extent, 0.1)
    for i, axis in enumerate(AXES):
        ends = centres + length * T_world_body[:, :3, i]
        seg = np.stack([centres, ends, np.full_like(centres, np.nan)], axis=1).reshape(-1, 3)
        fig.add_trace(go.Scatter3d(x=seg[:, 0], y=seg[:, 1], z=seg[:, 2], mode="lines", name=f"body {axis}",
                                   line={"color": BODY_COLOURS[axis], "width": 4}, hoverinfo="skip"))
    fig.add_trace(go.Scatter3d(x=centres[:, 0], y=centres[:, 1], z=centres[:, 2], mode="markers", name="frames",
                               marker={"size": 3, "color": "black"}, text=[cal.frames[f] for f in seen],
                               hovertemplate="frame %{text}<extra></extra>"))
    up = T_world_body[:, :3, 2].mean(0)  # the rig's mean U axis: draw it upwards, look from the side
    up = up / max(np.linalg.norm(up), 1e-12)
    side = np.cross(up, [0.0, 0.0, 1.0] if abs(up[2]) < 0.9 else [1.0, 0.0, 0.0])
    eye = 1.7 * side / np.linalg.norm(side) + 0.8 * up
    fig.update_layout(title=f"boards and body poses per frame in the solve's world frame (board "
                            f"{cal.boards[cal.problem.gauge_board]}'s frame)",
                      scene={"aspectmode": "data", "camera": {"up": dict(zip("xyz", map(float, up))),
                                                              "eye": dict(zip("xyz", map(float, eye)))},
                             "xaxis": {"title": {"text": "x (m)"}},
                             "yaxis": {"title": {"text": "y (m)"}}, "zaxis": {"title": {"text": "z (m)"}}},
                      height=600, margin={"l": 0, "r": 0, "t": 50, "b": 0})
    return fig


# ----------------------------------------------------------------------------- page


def _figure_html(fig: go.Figure, div_id: str, first: bool) -> str:
    return fig.to_html(full_html=False, include_plotlyjs=first, div_id=div_id, config=PLOT_CONFIG)


def figures(cal: Calibration, out_rig: Rig, pairs: dict) -> list[tuple[str, str, go.Figure]]:
    """(section heading, div id, figure) in page order."""
    e = all_residuals(cal)
    rig_fig = rig_figure(out_rig).update_layout(height=560)
    out = [("Rig in the body frame (FLU)", "fig-rig", rig_fig)]
    for c, name in enumerate(cal.cam_names):
        if (cal.obs.cam == c).any():
            out.append((f"Camera {name}: coverage and residuals", f"fig-camera-{c}", camera_figure(cal, c, e)))
    out.append(("Per-frame RMS", "fig-frame-rms", frame_rms_figure(cal, e)))
    for k, p in enumerate(out_rig.stereo_pairs):
        fig = depth_figure(cal, p.left, p.right, pairs.get((p.left, p.right)))
        if fig is not None:
            out.append((f"Depth error versus distance: {p.left} / {p.right}", f"fig-depth-{k}", fig))
    out.append(("Board and frame poses", "fig-poses", poses_figure(cal)))
    return out


def _sigma_origin(out_rig: Rig) -> str:
    """Which estimate the pose table's poses and sigmas are from."""
    top = out_rig.calibration or {}
    if "free_running" in top:
        return ("the free-running cameras' continuous-time estimate (see its section below; the figures of frame "
                "poses and residuals are the camera-only start's, images grouped by time)")
    if "camera_imu" in top:
        return "the camera-IMU estimate"
    return "the bundle adjustment's covariance"


def build_report(cal: Calibration, out_rig: Rig, det, pairs: dict, timings: dict) -> str:
    """The whole report page as one HTML string (plotly.js embedded once, no network)."""
    pairs = pairs or {}
    body = [f"<h1>rigcal calibration report: {_e(out_rig.name)}</h1>", summary_html(cal, out_rig),
            "<h2>Warnings and notes</h2>", messages_html(cal),
            "<h2>Cameras: intrinsics</h2>", intrinsics_table(cal, out_rig),
            "<h3>Distortion model choice</h3>", model_choice_html(cal, out_rig),
            "<h2>Cameras: pose in the body frame (FLU) and its uncertainty</h2>", extrinsics_table(cal, out_rig),
            "<p class=\"caption\">1-sigma from " + _sigma_origin(out_rig) + ", in the output body frame; "
            "rotation sigmas are about the body F, L, U axes.</p>"]
    if out_rig.stereo_pairs:
        body += ["<h2>Stereo pairs</h2>", stereo_table(out_rig, pairs)]
        body += [bands_table((p.left, p.right), pairs.get((p.left, p.right))) for p in out_rig.stereo_pairs]
    body += ["<h2>Detection</h2>", detection_html(det, cal), "<h2>Timings</h2>", timings_table(timings)]
    for k, (heading, div_id, fig) in enumerate(figures(cal, out_rig, pairs)):
        body += [f"<h2>{_e(heading)}</h2>", _figure_html(fig, div_id, first=k == 0)]
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>rigcal report: {_e(out_rig.name)}</title><style>{CSS}</style></head>\n<body>\n"
            + "\n".join(body) + "\n</body></html>\n")
