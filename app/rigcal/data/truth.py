"""A simulated dataset's truth.yaml (or a plain rig file standing in for it): the true rig,
board poses and per-frame body poses that `rigcal compare`, the stereo depth check and the
benchmarks score a calibration against."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.rig import Rig, load_yaml, rig_file, rig_from_dict
from rigcal.core.validate import read_text
from rigcal.errors import InputError


@dataclass(frozen=True)
class Truth:
    """A simulated dataset's truth.yaml: the true rig, board poses, per-frame body poses."""

    rig: Rig
    T_world_board: dict[str, np.ndarray]
    T_world_body: dict[str, np.ndarray]
    frame_boards: dict[str, dict[str, np.ndarray]]

    def board_pose(self, frame: str, board: str) -> np.ndarray | None:
        """T_world_board at a frame: the frame's own pose for a moving board, else the static one."""
        fb = self.frame_boards.get(frame, {})
        if board in fb:
            return fb[board]
        return self.T_world_board.get(board)


def _pose(d: Any, key: str, label: str) -> np.ndarray:
    if not isinstance(d, dict) or "rotation" not in d or "position" not in d:
        raise InputError(f"{label}: {key}: expected a mapping with rotation and position")
    try:
        R = geo.check_rotation(np.array(d["rotation"], dtype=float))
        t = np.array(d["position"], dtype=float)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError("position: expected 3 finite numbers")
    except (ValueError, TypeError) as e:
        raise InputError(f"{label}: {key}: {e}") from None
    return geo.make_T(R, t)


def _mapping(v: Any, key: str, label: str) -> dict:
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise InputError(f"{label}: {key}: expected a mapping, got {type(v).__name__}")
    return v


def load_truth(path: str | Path) -> Truth:
    """truth.yaml (docs/formats.md#truth) or a plain rig file, or a shipped rig's name (then there
    are no board/frame poses)."""
    label = str(path)
    path = rig_file(path)
    doc = load_yaml(read_text(path, InputError), label, InputError)
    if isinstance(doc, dict) and "cameras" in doc:
        return Truth(rig_from_dict(doc, label), {}, {}, {})
    if not isinstance(doc, dict) or "rig" not in doc:
        raise InputError(f"{label}: expected a truth.yaml (with `rig`) or a rig file (with `cameras`)")
    rig = rig_from_dict(doc["rig"], f"{label}: rig")
    boards = {str(k): _pose(v, f"boards.{k}", label) for k, v in _mapping(doc.get("boards"), "boards", label).items()}
    frames, frame_boards = {}, {}
    for k, v in _mapping(doc.get("frames"), "frames", label).items():
        frames[str(k)] = _pose(v, f"frames.{k}", label)
        fb = _mapping(v.get("boards"), f"frames.{k}.boards", label)
        if fb:
            frame_boards[str(k)] = {str(b): _pose(p, f"frames.{k}.boards.{b}", label) for b, p in fb.items()}
    return Truth(rig, boards, frames, frame_boards)
