"""Text for OpenCV's cv::FileStorage YAML reader, which OpenVINS, VINS-Fusion and ORB-SLAM3
read their settings with.

cv2.FileStorage's own writer refuses key names with a dot (ORB-SLAM3's ``Camera1.fx``),
so these files are written as text: ``%YAML:1.0`` on the first line, then ``key: value``
lines in the given order. Values: str (quoted), bool (true/false, as those projects
write them), int, float (shortest exact repr), a flat list (flow sequence), a list of
lists (block sequence of flow rows, OpenVINS's matrices), a dict (nested mapping), Mat
(``!!opencv-matrix`` with ``dt: d`` or ``dt: f``). A ("#", text) entry is a comment line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np


@dataclass(frozen=True)
class Mat:
    """An ``!!opencv-matrix``; dt "d" (float64) or "f" (float32, ORB-SLAM3's transforms)."""

    data: np.ndarray
    dt: str = "d"


def _num(x: Any) -> str:
    if isinstance(x, (bool, np.bool_)):
        return "true" if x else "false"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    v = float(x) + 0.0
    if not math.isfinite(v):
        raise ValueError(f"not a finite number: {x!r}")
    return repr(v)


def _scalar(x: Any) -> str:
    if isinstance(x, str):
        return '"' + x.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return _num(x)


def _flow(xs: Sequence[Any]) -> str:
    return "[" + ", ".join(_scalar(x) for x in xs) + "]"


def _lines(key: str, value: Any, indent: str) -> list[str]:
    if isinstance(value, Mat):
        M = np.atleast_2d(np.asarray(value.data, dtype=float))
        return [f"{indent}{key}: !!opencv-matrix", f"{indent}   rows: {M.shape[0]}", f"{indent}   cols: {M.shape[1]}",
                f"{indent}   dt: {value.dt}", f"{indent}   data: {_flow(M.ravel())}"]
    if isinstance(value, dict):
        out = [f"{indent}{key}:"]
        for k, v in value.items():
            out += _lines(k, v, indent + "  ")
        return out
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) and isinstance(value[0], (list, tuple, np.ndarray)):
            return [f"{indent}{key}:"] + [f"{indent}  - {_flow(row)}" for row in value]
        return [f"{indent}{key}: {_flow(value)}"]
    return [f"{indent}{key}: {_scalar(value)}"]


def cv_yaml(entries: Sequence[tuple[str, Any]]) -> str:
    """The file text: ``%YAML:1.0`` first, then each (key, value) or ("#", comment) in order."""
    out = ["%YAML:1.0"]
    for key, value in entries:
        if key == "#":
            out += [f"# {line}".rstrip() for line in str(value).splitlines()]
        else:
            out += _lines(key, value, "")
    return "\n".join(out) + "\n"
