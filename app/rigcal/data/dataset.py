"""The dataset folder (../shared/spec/dataset.md): which image is which camera's which frame.

    DATASET/rig.yaml, DATASET/target.yaml, DATASET/images/<camera>/<frame>.<ext>

Images of different cameras with the same stem were taken at the same instant. A
camera may lack a frame the others have. Images may be symbolic links. Nothing is
decoded here (that is image_read.py); this module only names files and refuses layouts
that break the contract, with one line naming the folder and the camera.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Iterable, Mapping

from rigcal.errors import DatasetError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
_DIGITS = re.compile(r"(\d+)")


@dataclass(frozen=True)
class DatasetImages:
    """Per camera (rig order) an ordered mapping frame stem -> image path.

    `frames[camera]` is ordered by stem, numbers compared as numbers ("img2" before "img10")."""

    root: Path
    cameras: tuple[str, ...]
    frames: Mapping[str, Mapping[str, Path]]
    # camera -> corners/<camera>.csv (corners detected elsewhere; calibrate uses them, not the images)
    corners: Mapping[str, Path] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def all_frames(self) -> tuple[str, ...]:
        """Every frame stem seen by any camera, in the same natural order."""
        return tuple(sorted({f for cam in self.cameras for f in self.frames[cam]}, key=frame_sort_key))

    @property
    def n_images(self) -> int:
        return sum(len(self.frames[c]) for c in self.cameras)

    def items(self) -> list[tuple[str, str, Path]]:
        """(camera, frame, path) for every image, camera-major in rig order, frames in order."""
        return [(cam, frame, path) for cam in self.cameras for frame, path in self.frames[cam].items()]


def frame_sort_key(stem: str) -> tuple:
    """Natural order: digit runs compare as integers, so 'left2' < 'left10'."""
    return tuple((0, int(p), p) if p.isdigit() else (1, 0, p) for p in _DIGITS.split(stem) if p != "")


def _camera_names(rig) -> tuple[str, ...]:
    names = getattr(rig, "names", rig)
    return tuple(str(n) for n in names)


def list_dataset(dataset_dir: str | Path, rig) -> DatasetImages:
    """Index DATASET/images/<camera>/<frame>.<ext> for the cameras of `rig` (a Rig or camera names).

    Raises DatasetError when images/ is missing, when a folder does not match a declared
    camera or a declared camera has no folder (one message naming both), when a camera
    folder holds no image, or when two files of one camera share a stem."""
    root = Path(dataset_dir)
    cameras = _camera_names(rig)
    images = root / "images"
    if not root.is_dir():
        raise DatasetError(f"{root}: not a folder (expected a dataset with rig.yaml, target.yaml, images/<camera>/)")
    corners = _corner_files(root / "corners", cameras)
    if not images.is_dir() and not (corners and not images.exists()):
        what = "not a folder" if images.exists() else "missing"
        raise DatasetError(f"{images}: {what} (expected one folder of images per camera: "
                           f"{', '.join(f'images/{c}/' for c in cameras)}, or corners/<camera>.csv)")
    folders = (sorted(p.name for p in _listdir(images) if p.is_dir() and not p.name.startswith("."))
               if images.is_dir() else [])
    # a camera with a corners file needs no image folder
    _check_folders(images, folders, tuple(c for c in cameras if c not in corners or c in folders),
                   declared=cameras)
    frames = {cam: MappingProxyType(_camera_frames(images / cam) if cam in folders else {}) for cam in cameras}
    return DatasetImages(root=root, cameras=cameras, frames=MappingProxyType(frames),
                         corners=MappingProxyType(corners))


def _corner_files(folder: Path, cameras: tuple[str, ...]) -> dict[str, Path]:
    """camera -> corners/<camera>.csv; a csv for a camera the rig does not declare is an error."""
    if not folder.is_dir():
        return {}
    found = {p.stem: p for p in _listdir(folder) if p.suffix.lower() == ".csv" and not p.name.startswith(".")}
    extra = sorted(set(found) - set(cameras))
    if extra:
        raise DatasetError(f"{folder}: {extra[0]}.csv is not a camera of the rig (the rig declares "
                           f"{', '.join(cameras)})")
    return {c: found[c] for c in cameras if c in found}


def check_shared_stems(dataset: DatasetImages) -> None:
    """DatasetError when a camera shares no file stem with any other camera. Such a camera can
    never be placed in the rig (not even through the rig's motion, which needs its frames
    posed by the others): almost always files named per camera (left01.jpg, right01.jpg)
    where the stem must name the instant. A layout check for calibrate, not for listing."""
    images = dataset.root / "images"
    # cameras given as corners/ files are matched on their csv frames, not here
    frames = {c: f for c, f in dataset.frames.items() if c not in dataset.corners}
    if len(frames) < 2:
        return
    stems = {c: set(f) for c, f in frames.items()}
    lone = [c for c in frames if not any(stems[c] & stems[o] for o in frames if o != c)]
    if not lone:
        return
    other = next(c for c in frames if c != lone[0])

    def show(cam: str) -> str:
        return ", ".join(list(frames[cam])[:3]) + (", ..." if len(frames[cam]) > 3 else "")

    raise DatasetError(
        f"{images}: camera {lone[0]} shares no frame with the other cameras (its file stems: {show(lone[0])}; "
        f"{other}'s: {show(other)}); images taken at the same instant must have the same stem in every camera "
        f"folder, e.g. images/{lone[0]}/0001.png and images/{other}/0001.png")


def _listdir(folder: Path) -> list[Path]:
    try:
        return list(folder.iterdir())
    except OSError as e:
        raise DatasetError(f"{folder}: cannot list ({e.strerror or e})") from None


def _check_folders(images: Path, folders: Iterable[str], cameras: tuple[str, ...],
                   declared: tuple[str, ...] | None = None) -> None:
    """cameras: those that need a folder; declared: every camera of the rig (default: cameras)."""
    folders = list(folders)
    declared = cameras if declared is None else declared
    extra = [f for f in folders if f not in declared]
    missing = [c for c in cameras if c not in folders]
    if not extra and not missing:
        return
    parts = []
    if extra:
        parts.append(", ".join(f"folder images/{f}/" for f in extra)
                     + (" is" if len(extra) == 1 else " are") + " not a camera of the rig")
    if missing:
        parts.append(", ".join(f"camera {c}" for c in missing)
                     + (" has" if len(missing) == 1 else " have") + " no folder "
                     + ", ".join(f"images/{c}/" for c in missing))
    hints = []
    for f in extra:
        close = difflib.get_close_matches(f, missing or cameras, n=1, cutoff=0.6)
        if close:
            hints.append(f"images/{f}/ -> images/{close[0]}/?")
    msg = "; ".join(parts) + f" (the rig declares {', '.join(declared)})"
    if hints:
        msg += "; did you mean " + ", ".join(hints)
    raise DatasetError(f"{images}: {msg}")


def _camera_frames(folder: Path) -> dict[str, Path]:
    found: dict[str, Path] = {}
    for p in _listdir(folder):
        if p.name.startswith(".") or p.suffix.lower() not in IMAGE_EXTENSIONS:
            continue
        # A broken symbolic link is still listed: detection reports it as unreadable.
        if p.is_dir():
            continue
        if p.stem in found:
            a, b = sorted([found[p.stem].name, p.name])
            raise DatasetError(f"{folder}: {a} and {b} are the same frame {p.stem!r}; keep one image per frame")
        found[p.stem] = p
    if not found:
        raise DatasetError(f"{folder}: no images (expected <frame>{'|'.join(IMAGE_EXTENSIONS)}, any case)")
    return {stem: found[stem] for stem in sorted(found, key=frame_sort_key)}


def dataset_rig_path(dataset: str | Path, override: str | Path | None = None) -> Path:
    """--rig when given, else DATASET/rig.yaml (DatasetError when that is missing)."""
    return _default_file(dataset, override, "rig.yaml", "--rig")


def dataset_target_path(dataset: str | Path, override: str | Path | None = None) -> Path:
    """--target when given, else DATASET/target.yaml (DatasetError when that is missing)."""
    return _default_file(dataset, override, "target.yaml", "--target")


def _default_file(dataset: str | Path, override: str | Path | None, name: str, option: str) -> Path:
    if override is not None:
        return Path(override)
    path = Path(dataset) / name
    if not path.is_file():
        raise DatasetError(f"{path}: missing (put {name} in the dataset or pass {option} FILE)")
    return path
