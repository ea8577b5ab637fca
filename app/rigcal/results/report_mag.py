"""The magnetometers in `rigcal calibrate --report`: per magnetometer, the raw and the
calibrated readings on the sphere, and the heading error over the recording. A dataset of
imu/ and mag/ alone gets a page of its own (mag_report); one with images too gets the same
section at the end of the camera report (with_mag_section).

Heading error: each reading's field carried into the world with the estimated orientation
(the IMU's, from the joint fit) and, tilt-compensated, its angle from magnetic north. With
rigcal's calibration it scatters about 0 by the noise; with the ellipsoid fit alone and the
declared mount (the onboard calibrators' result) it shows what the chip's misalignment costs
at each attitude of the recording. Long recordings are thinned to MAX_POINTS per trace.
"""

from __future__ import annotations

import html

import numpy as np
import plotly.graph_objects as go

from rigcal.core.rig import Rig
from rigcal.mag.estimator import MagResult

MAX_POINTS = 3000


def _thin(n: int) -> np.ndarray:
    return np.arange(0, n, max(1, n // MAX_POINTS))


def heading_errors_deg(r: MagResult, m: np.ndarray, R_imu_mag: np.ndarray, hard_iron: np.ndarray,
                       soft_iron: np.ndarray) -> np.ndarray:
    """(N,) degrees: the tilt-compensated heading of each reading (calibrated by hard_iron,
    soft_iron, R_imu_mag) against magnetic north, along the estimated orientations."""
    b_imu = (m - hard_iron) @ (R_imu_mag @ soft_iron).T
    b_world = np.einsum("nij,nj->ni", r.R_world_imu, b_imu)
    return np.degrees(np.arctan2(b_world[:, 0], b_world[:, 1]))


def sphere_figure(name: str, r: MagResult, m: np.ndarray) -> go.Figure:
    k = _thin(len(m))
    raw = m[k]
    cal = (m[k] - r.hard_iron) @ r.soft_iron.T / r.field_uT
    fig = go.Figure([
        go.Scatter3d(x=raw[:, 0], y=raw[:, 1], z=raw[:, 2], mode="markers", marker={"size": 1.5}, name="raw (uT)"),
        go.Scatter3d(x=cal[:, 0] * r.field_uT, y=cal[:, 1] * r.field_uT, z=cal[:, 2] * r.field_uT, mode="markers",
                     marker={"size": 1.5}, name="calibrated (uT, chip axes)")])
    fig.update_layout(title=f"{name}: readings on the sphere", scene={"aspectmode": "data"},
                      margin={"l": 0, "r": 0, "t": 40, "b": 0})
    return fig


def heading_figure(name: str, r: MagResult, m: np.ndarray, R_imu_mag_declared: np.ndarray) -> go.Figure:
    k = _thin(len(m))
    ours = heading_errors_deg(r, m, r.R_imu_mag, r.hard_iron, r.soft_iron)
    onboard = heading_errors_deg(r, m, R_imu_mag_declared, r.start.hard_iron, r.start.soft_iron)
    fig = go.Figure([go.Scatter(x=r.t_mag[k], y=onboard[k], mode="lines", name="ellipsoid fit + declared mount"),
                     go.Scatter(x=r.t_mag[k], y=ours[k], mode="lines", name="rigcal")])
    fig.update_layout(title=f"{name}: heading error over the recording", xaxis_title="s",
                      yaxis_title="heading error (deg)", margin={"t": 40})
    return fig


def mag_section(rig: Rig, declared: Rig, results: dict[str, MagResult], readings: dict[str, np.ndarray],
                include_plotlyjs: bool = False) -> str:
    """Per magnetometer a heading, its figures and the sphere and heading-error plots (HTML;
    plotly.js inlined with the first figure when include_plotlyjs). `declared`: the rig the
    magnetometer step was given (its declared mounts, the IMUs it calibrated against)."""
    parts, first = [], include_plotlyjs
    for name, r in results.items():
        mag, imu = declared.magnetometer(name), declared.mag_imu(declared.magnetometer(name))
        R_decl = imu.T_body_imu[:3, :3].T @ mag.T_body_mag[:3, :3]
        cal = rig.magnetometer(name).calibration or {}
        parts.append(f"<h2>Magnetometer {html.escape(name)}</h2><p>residual RMS {r.residual_rms_uT:.3f} uT (declared "
                     f"{r.residual_rms_declared_uT:.3f} uT); field {r.field_uT:.2f} uT, inclination "
                     f"{r.inclination_deg:.2f} deg; heading 1-sigma {cal.get('heading_sigma_deg', r.heading_sigma_deg):.3f} "
                     f"deg; 1-sigma {html.escape(r.sigma_basis)}</p>")
        for fig in (sphere_figure(name, r, readings[name]), heading_figure(name, r, readings[name], R_decl)):
            parts.append(fig.to_html(full_html=False, include_plotlyjs=first))
            first = False
    return "".join(parts)


def mag_report(rig: Rig, declared: Rig, results: dict[str, MagResult], readings: dict[str, np.ndarray]) -> str:
    """The whole page (self-contained HTML: plotly inlined once)."""
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>rigcal: magnetometers "
            f"of {html.escape(str(rig.name))}</title></head><body><h1>Magnetometers of {html.escape(str(rig.name))}</h1>"
            + mag_section(rig, declared, results, readings, include_plotlyjs=True) + "</body></html>\n")


def with_mag_section(page: str, rig: Rig, declared: Rig, results: dict[str, MagResult],
                     readings: dict[str, np.ndarray]) -> str:
    """The camera report `page` with the magnetometer section before its end; plotly.js is the
    page's where it has a figure already, else the section's first figure inlines it."""
    end = page.rindex("</body>")
    section = mag_section(rig, declared, results, readings, include_plotlyjs="Plotly.newPlot" not in page)
    return page[:end] + section + "\n" + page[end:]
