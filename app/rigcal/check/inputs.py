"""What `rigcal check` reads, checked once: a calibrated rig (every camera with its pose and
calibration sigmas) and a recording of some of its cameras, detected as `calibrate` does."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rigcal.core.observations import BoardView
from rigcal.core.rig import Rig, load_rig
from rigcal.errors import DatasetError, InputError, OutputError

HOW_TO_CALIBRATE = "make one with `rigcal calibrate DATASET --out RIG.yaml`"


def load_calibrated_rig(path: Path) -> Rig:
    """The rig, or InputError naming the first camera without a pose or calibration sigmas."""
    rig = load_rig(path)
    for c in rig.cameras:
        sig = (c.calibration or {}).get("sigma")
        if c.T_body_cam is None:
            raise InputError(f"{path}: cameras.{c.name}: no pose; rigcal check needs a calibrated rig "
                             f"({HOW_TO_CALIBRATE})")
        if not sig or "rotation_deg" not in sig or "position_mm" not in sig:
            raise InputError(f"{path}: cameras.{c.name}: no calibration.sigma (position_mm, rotation_deg); rigcal "
                             f"check needs a calibrated rig with its uncertainties ({HOW_TO_CALIBRATE})")
        for key, n in (("rotation_deg", 3), ("position_mm", 3)):
            v = sig[key]
            if not (isinstance(v, (list, tuple)) and len(v) == n and all(isinstance(x, (int, float)) for x in v)):
                raise InputError(f"{path}: cameras.{c.name}.calibration.sigma.{key}: expected {n} numbers, got {v!r}")
    return rig


def recorded_cameras(dataset: Path, rig: Rig, rig_path: Path) -> list[str]:
    """The rig's cameras the recording has (images/<camera>/ or corners/<camera>.csv), in rig
    order; InputError for a camera the rig does not have, or none of the rig's."""
    if not dataset.is_dir():
        raise DatasetError(f"{dataset}: not a dataset folder (expected target.yaml and images/<camera>/)")
    images, corners = dataset / "images", dataset / "corners"
    found = set()
    if images.is_dir():
        found |= {p.name for p in images.iterdir() if p.is_dir() and not p.name.startswith(".")}
    if corners.is_dir():
        found |= {p.stem for p in corners.iterdir() if p.suffix.lower() == ".csv" and not p.name.startswith(".")}
    extra = sorted(found - set(rig.names))
    if extra:
        raise DatasetError(f"{dataset}: camera {extra[0]} is not in the rig {rig_path} (its cameras: "
                           f"{', '.join(rig.names)}); check a recording against the rig it was made with")
    present = [n for n in rig.names if n in found]
    if not present:
        raise DatasetError(f"{dataset}: no camera of the rig {rig_path} ({', '.join(rig.names)}) in images/ or "
                           f"corners/")
    return present


def check_output(path: Path | None, option: str) -> None:
    """OutputError before any work when `path` can never be written."""
    if path is None:
        return
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; {option} expects a file path")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{path}: {option}: folder {parent} does not exist")


@dataclass(frozen=True)
class Recording:
    """The recording's board views (detected, and those of corners/<camera>.csv), the
    cameras it has, the target's corners and print faces, and the detection seconds."""

    views: list[BoardView]
    cameras: list[str]
    corners: dict
    faces: dict
    detection_s: float


def read_recording(dataset: Path, rig: Rig, rig_path: Path, jobs: int | None) -> Recording:
    """Detect the boards of the recording's cameras (detect.detect_dataset) with the
    dataset's target.yaml; DatasetError for images of another size than the rig's."""
    from rigcal.core.target import load_target
    from rigcal.data.corners import read_corners
    from rigcal.data.dataset import dataset_target_path, list_dataset
    from rigcal.detect.detect import detect_dataset

    present = recorded_cameras(dataset, rig, rig_path)
    target = load_target(dataset_target_path(dataset))
    images = list_dataset(dataset, present)
    views = []
    for cam, path in images.corners.items():
        views += [BoardView(cam, f, b, ids, uv) for f, b, ids, uv in read_corners(path, target)]
    det = detect_dataset(images, target, rig=rig, jobs=jobs, progress=False)
    if det.size_mismatch:
        cam, path, got, expected = det.size_mismatch[0]
        raise DatasetError(f"{path}: camera {cam}: image is {got[0]}x{got[1]} but the rig's calibration is for "
                           f"{expected[0]}x{expected[1]}; a check needs images at the calibrated resolution")
    views += [v for v in det.views if v.camera not in images.corners]
    return Recording(views=views, cameras=present, corners={b.name: b.corners for b in target.boards},
                     faces={b.name: b.print_face for b in target.boards}, detection_s=det.seconds)
