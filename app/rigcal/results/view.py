"""`rigcal view`: the rig's camera frames drawn in the FLU body frame, as an interactive
3D page (the textbook's camera-frames figure).

Body axes F, L, U are drawn from the body origin; each posed camera gets its x, y, z
axes (red, green, blue) at its pinhole, labelled with its name, and a small frustum
traced from its image border through its own lens model; each IMU gets its measurement
axes x, y, z (the same colours, dotted, thicker) at its position, labelled with its name. Plotly's JavaScript is
embedded so the page works offline.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plotly.graph_objects as go

from rigcal.core.camera import CameraModel
from rigcal.core.io import atomic_write_text
from rigcal.core.rig import Camera, Imu, Rig, load_rig

AXIS_COLOURS = {"x": "red", "y": "green", "z": "blue"}
BODY_COLOURS = {"F": "#7f0000", "L": "#005f00", "U": "#00007f"}
FRUSTUM_COLOUR = "#808080"
BORDER_SAMPLES = 16  # points per image side traced through the lens model


def rig_extent(rig: Rig) -> float:
    """Distance of the farthest posed camera from the body origin (m); 0.1 when none is away from it."""
    d = [float(np.linalg.norm(c.T_body_cam[:3, 3])) for c in rig.cameras if c.has_pose]
    d += [float(np.linalg.norm(i.T_body_imu[:3, 3])) for i in rig.imus]
    d += [float(np.linalg.norm(m.T_body_mag[:3, 3])) for m in rig.magnetometers]
    return max(d) if d and max(d) > 1e-6 else 0.1


def frustum_rays(model: CameraModel, samples: int = BORDER_SAMPLES, steps: int = 64) -> np.ndarray:
    """Unit rays (4 * samples + 1, 3) around the edge of what the camera sees, clockwise
    from the top-left pixel corner and closed.

    Each ray goes through an image-border pixel or, where that pixel lies outside the
    lens model's valid field (a fisheye's corners lie beyond its image circle), through
    the last valid pixel on the way from the principal point to it."""
    w, h = model.width - 0.5, model.height - 0.5
    s = np.linspace(0.0, 1.0, samples, endpoint=False)
    top = np.column_stack([-0.5 + s * (w + 0.5), np.full(samples, -0.5)])
    right = np.column_stack([np.full(samples, w), -0.5 + s * (h + 0.5)])
    bottom = np.column_stack([w - s * (w + 0.5), np.full(samples, h)])
    left = np.column_stack([np.full(samples, -0.5), h - s * (h + 0.5)])
    border = np.vstack([top, right, bottom, left, top[:1]])  # (M, 2)
    centre = np.array([model.cx, model.cy])
    inward = np.linspace(1.0, 0.0, steps)  # fraction of the way out from the centre
    uv = centre + inward[None, :, None] * (border - centre)[:, None, :]  # (M, steps, 2)
    rays = model.unproject(uv.reshape(-1, 2)).reshape(len(border), steps, 3)
    ok = np.all(np.isfinite(rays), axis=2)
    out = rays[np.arange(len(border)), np.argmax(ok, axis=1)]
    out[~ok.any(axis=1)] = np.nan
    return out


def frustum_points(model: CameraModel, size: float) -> np.ndarray:
    """Camera-frame outline (M, 3) of the field of view: on the plane z = size when the whole
    field lies well in front (the textbook pyramid), else on a sphere of radius size (a
    wide fisheye sees past 90 degrees, where no plane in front can hold its edge)."""
    rays = frustum_rays(model)
    with np.errstate(invalid="ignore"):
        flat = np.nanmin(rays[:, 2]) > 0.2
    return rays * (size / rays[:, 2:3]) if flat else rays * size


def _segments(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Line segments (N, 3) -> (3N, 3) polyline with NaN breaks, the form plotly draws."""
    gap = np.full_like(starts, np.nan)
    return np.stack([starts, ends, gap], axis=1).reshape(-1, 3)


def _line(points: np.ndarray, name: str, colour: str, width: float, text=None, group: str | None = None,
          dash: str = "solid") -> go.Scatter3d:
    return go.Scatter3d(
        x=points[:, 0], y=points[:, 1], z=points[:, 2], name=name, legendgroup=group or name,
        mode="lines+text" if text is not None else "lines", text=text, textposition="top center",
        line={"color": colour, "width": width, "dash": dash}, hoverinfo="name", connectgaps=False)


def body_traces(length: float) -> list[go.Scatter3d]:
    """The FLU body axes from the origin, labelled F, L, U."""
    traces = []
    for name, axis in zip("FLU", np.eye(3)):
        pts = np.array([np.zeros(3), length * axis])
        traces.append(_line(pts, f"body {name}", BODY_COLOURS[name], 7, ["", name], group="body", dash="dash"))
    return traces


def camera_traces(cam: Camera, length: float) -> list[go.Scatter3d]:
    """A posed camera's x, y, z axes (one trace each; z carries its name) and its frustum."""
    R_body_cam, t_body_cam = cam.T_body_cam[:3, :3], cam.T_body_cam[:3, 3]
    traces = axes_traces(cam.T_body_cam, cam.name, length, "z", 5)
    p_body = frustum_points(cam.intrinsics, 0.6 * length) @ R_body_cam.T + t_body_cam
    corners = p_body[:: BORDER_SAMPLES][:4]
    ok = np.all(np.isfinite(corners), axis=1)
    # Edges run from the pinhole to the image corners the lens can see, then the border.
    edges = _segments(np.repeat(t_body_cam[None], ok.sum(), axis=0), corners[ok])
    outline = np.vstack([edges, p_body])
    traces.append(_line(outline, f"{cam.name} frustum", FRUSTUM_COLOUR, 2, group=cam.name))
    return traces


def imu_traces(imu: Imu, length: float) -> list[go.Scatter3d]:
    """An IMU's measurement axes x, y, z (one trace each, dotted; x carries its name)."""
    return axes_traces(imu.T_body_imu, imu.name, length, "x", 9, dash="dot")


def axes_traces(T_body_frame: np.ndarray, name: str, length: float, named_axis: str, width: float,
                dash: str = "solid") -> list[go.Scatter3d]:
    """A frame's x, y, z axes from its origin (traces `<name> x|y|z`); `named_axis` carries the name."""
    R, t = T_body_frame[:3, :3], T_body_frame[:3, 3]
    traces = []
    for i, axis in enumerate("xyz"):
        pts = np.array([t, t + length * R[:, i]])
        label = [name if axis == named_axis else "", axis]
        traces.append(_line(pts, f"{name} {axis}", AXIS_COLOURS[axis], width, label, group=name, dash=dash))
    return traces


def rig_figure(rig: Rig) -> go.Figure:
    """The rig's camera frames in the FLU body frame; equal scale on all three axes.

    Traces: `body F`, `body L`, `body U`; per posed camera `<name> x`, `<name> y`,
    `<name> z` and `<name> frustum`; per IMU `<name> x`, `<name> y`, `<name> z`. Cameras
    without a pose are not drawn."""
    extent = rig_extent(rig)
    fig = go.Figure(body_traces(1.5 * extent))
    for cam in rig.cameras:
        if cam.has_pose:
            fig.add_traces(camera_traces(cam, 0.4 * extent))
    for imu in rig.imus:
        fig.add_traces(imu_traces(imu, 0.3 * extent))
    for mag in rig.magnetometers:  # dashed: a magnetometer's measurement axes (docs/magnetometer.md)
        fig.add_traces(axes_traces(mag.T_body_mag, mag.name, 0.25 * extent, "x", 7, dash="dash"))
    unit = {"showbackground": False, "zeroline": False}
    fig.update_layout(
        title=f"rig {rig.name}: camera frames in the body frame (FLU; camera x red, y green, z blue"
              + ("; IMU axes dotted)" if rig.imus else ")"),
        scene={"aspectmode": "data",
               "xaxis": {"title": {"text": "F (x, m)"}, **unit},
               "yaxis": {"title": {"text": "L (y, m)"}, **unit},
               "zaxis": {"title": {"text": "U (z, m)"}, **unit},
               # Look from behind, above and to the right, nose away from the viewer.
               "camera": {"eye": {"x": -1.6, "y": -1.0, "z": 0.9}, "up": {"x": 0, "y": 0, "z": 1}}},
        legend={"groupclick": "togglegroup"},
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
    )
    return fig


def run(rig_path: str | Path, out_path: str | Path) -> str:
    """Write the page for `rigcal view`; returns what was drawn and what was not."""
    rig = load_rig(rig_path)
    html = rig_figure(rig).to_html(include_plotlyjs=True, full_html=True)
    atomic_write_text(out_path, html)
    drawn = [c.name for c in rig.cameras if c.has_pose]
    lines = [f"wrote {out_path}: body axes F, L, U and {len(drawn)} camera(s): {', '.join(drawn) or 'none'}"
             + (f"; IMU(s): {', '.join(i.name for i in rig.imus)}" if rig.imus else "")
             + (f"; magnetometer(s): {', '.join(m.name for m in rig.magnetometers)}" if rig.magnetometers else "")]
    lines += [f"{c.name}: no pose in the rig file; not drawn" for c in rig.cameras if not c.has_pose]
    return "\n".join(lines)
