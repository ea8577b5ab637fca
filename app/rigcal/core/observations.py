"""The board view: what every stage of the calibration reads, from detection to the solver.

One immutable type for "one board seen by one camera in one frame". The detector
(detect.py), corner files (corners.py, via calibrate.py), the simulators and the tests
all make BoardViews; the pipeline (pipeline.py) and its stages read them. A stage that
learns something about a view (its pose, a reversed corner order) returns it in its own
result type instead of editing the view.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


def _frozen(a, dtype) -> np.ndarray:
    """A read-only copy of `a` as `dtype` (the caller's array stays writeable); an array that
    is already read-only and of that type (another view's) is shared, not copied."""
    if isinstance(a, np.ndarray) and a.dtype == dtype and not a.flags.writeable:
        return a
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class BoardView:
    """One board seen by one camera in one frame: its corners' ids and pixels.

    camera, frame, board: names as in rig.yaml, the dataset's image stems and target.yaml.
    ids: (N,) int64 corner ids, rows of the board's corners (Board.corners).
    uv: (N, 2) float64 pixels, OpenCV pixel-centre convention.
    ambiguous: a 180-degree-symmetric chessboard, whose corner order may be reversed
    (initialise.resolve_flips decides per frame).
    sigma: (N,) each corner's own 1-sigma error in px as the detector estimates it (NaN
    where unknown), or None: then every corner counts alike.
    The arrays are stored as read-only copies, so a view cannot change after it is made.
    """

    camera: str
    frame: str
    board: str
    ids: np.ndarray
    uv: np.ndarray
    ambiguous: bool = False
    sigma: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "ids", _frozen(self.ids, np.int64))
        object.__setattr__(self, "uv", _frozen(self.uv, np.float64))
        if self.sigma is not None:
            object.__setattr__(self, "sigma", _frozen(self.sigma, np.float64))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BoardView):
            return NotImplemented
        return ((self.camera, self.frame, self.board, self.ambiguous)
                == (other.camera, other.frame, other.board, other.ambiguous)
                and np.array_equal(self.ids, other.ids) and np.array_equal(self.uv, other.uv)
                and ((self.sigma is None) == (other.sigma is None))
                and (self.sigma is None or np.array_equal(self.sigma, other.sigma, equal_nan=True)))

    __hash__ = None  # arrays inside: equal views need not hash alike

    def reversed_order(self, n_corners: int) -> BoardView:
        """This view with its corner ids renumbered k -> n_corners - 1 - k: a symmetric
        chessboard seen turned by 180 degrees (initialise.resolve_flips)."""
        return replace(self, ids=n_corners - 1 - self.ids)
