"""The dataset folder (docs/formats.md#dataset): which image is which camera's which frame.

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


def check_shared_stems(dataset: DatasetImages, tolerance_ns: int | None = None) -> None:
    """DatasetError when a camera shares no file stem with any other camera. Such a camera can
    never be placed in the rig (not even through the rig's motion, which needs its frames
    posed by the others): almost always files named per camera (left01.jpg, right01.jpg)
    where the stem must name the instant, or, with integer stems that interleave in time,
    free-running cameras, which calibrate groups by time before this check. A layout check for
    calibrate, not for listing. tolerance_ns: `dataset` is associate_by_time's (a motion
    dataset) and the refusal says no image lies within that of another camera's."""
    images = dataset.root / "images"
    # cameras given as corners/ files are matched on their csv frames, not here
    frames = {c: f for c, f in dataset.frames.items() if c not in dataset.corners}
    if len(frames) < 2:
        return
    stems = {c: set(f) for c, f in frames.items()}
    lone = [c for c in frames if not any(stems[c] & stems[o] for o in frames if o != c)]
    if not lone:
        return
    cam = lone[0]
    other = next(c for c in frames if c != cam)

    def show(c: str) -> str:
        return ", ".join(list(frames[c])[:3]) + (", ..." if len(frames[c]) > 3 else "")

    def span(c: str) -> str:
        t = [int(f) for f in frames[c]]
        return f"{min(t) * 1e-9:.3f}-{max(t) * 1e-9:.3f} s"

    if tolerance_ns is not None:
        raise DatasetError(
            f"{images / cam}: camera {cam}: none of its images was taken within {tolerance_ns * 1e-6:.1f} ms of "
            f"another camera's (its images {span(cam)}, {other}'s {span(other)}); the camera-only start needs images "
            f"of two cameras taken together (within half a frame period) to link them")
    if all(f.isdigit() for c in (cam, other) for f in frames[c]) and _interleave(frames[cam], frames[other]):
        raise DatasetError(
            f"{images / cam}: camera {cam} shares no stem with the other cameras and its images interleave in time "
            f"with {other}'s ({show(cam)}; {show(other)}): free-running cameras, which rigcal places on the rig's "
            f"motion only when every camera's images lie within another camera's span; trim the recording to the "
            f"time all cameras ran, or record with synchronised stems (equal stems for images taken together)")
    raise DatasetError(
        f"{images}: camera {cam} shares no frame with the other cameras (its file stems: {show(cam)}; "
        f"{other}'s: {show(other)}); images taken at the same instant must have the same stem in every camera "
        f"folder, e.g. images/{cam}/0001.png and images/{other}/0001.png")


def _interleave(a: Iterable[str], b: Iterable[str]) -> bool:
    """Whether two cameras' integer stems overlap in time (each has images within the other's span)."""
    ta, tb = [int(x) for x in a], [int(x) for x in b]
    return bool(ta and tb) and min(ta) < max(tb) and min(tb) < max(ta)


# Free-running cameras (a motion dataset whose cameras do not share stems): for the
# camera-only start, images of different cameras taken within this fraction of the
# shortest frame period of each other are treated as one frame. The camera-IMU step then
# places every image at its own time, so the start's error from the motion in between is
# not in the answer. A quarter period at 20 Hz is 12.5 ms: the start already copes with
# clock offsets of that size between cameras with equal stems. Where a camera then shares
# no frame (two cameras at one rate with phases a third of a period apart), half a period.
ASSOCIATE_FRACTIONS = (0.25, 0.5)


@dataclass(frozen=True)
class Association:
    """associate_by_time's outcome: `images` with each camera's frames renamed so that images
    taken together share a name (a group's name is its earliest stem), `image_t_ns`: camera
    -> frame (as renamed) -> the image's own stem in ns, the tolerance used (ns), the
    number of frames shared by two cameras or more, and whether anything was renamed;
    corner_frames: for the cameras given as corners/ files, camera -> the csv's frame -> its
    frame as renamed (their views are renamed when calibrate reads them)."""

    images: DatasetImages
    image_t_ns: Mapping[str, Mapping[str, int]]
    tolerance_ns: int
    shared_frames: int
    renamed: bool
    corner_frames: Mapping[str, Mapping[str, str]] = field(default_factory=lambda: MappingProxyType({}))


def frame_period_ns(t_ns) -> float:
    """A camera's frame period: the median interval of its sorted stems (ns), inf with one image."""
    t = sorted(int(x) for x in t_ns)
    if len(t) < 2:
        return float("inf")
    d = sorted(b - a for a, b in zip(t, t[1:]))
    return float(d[len(d) // 2])


def time_groups(times: Mapping[str, Iterable[int]], tolerance_ns: int) -> list[dict[str, int]]:
    """Images of different cameras grouped by time: going through all stems in order, an
    image joins the open group when its camera is not in it yet and it lies within
    tolerance_ns of the group's earliest stem, else it opens a new group. Equal stems
    always group (tolerance 0 gives exactly the groups of equal stems). Returns the groups
    in time order, each camera -> stem."""
    events = sorted((int(t), cam) for cam, ts in times.items() for t in ts)
    groups: list[dict[str, int]] = []
    for t, cam in events:
        g = groups[-1] if groups else None
        if g is not None and cam not in g and t - min(g.values()) <= tolerance_ns:
            g[cam] = t
        else:
            groups.append({cam: t})
    return groups


def associate_by_time(dataset: DatasetImages, fractions: tuple[float, ...] = ASSOCIATE_FRACTIONS,
                      corner_stems: Mapping[str, Iterable[str]] | None = None) -> Association:
    """A motion dataset's images (integer-ns stems, checked before) grouped into shared frames
    by time (time_groups, within a fraction of the shortest camera's frame period: the first
    of `fractions` at which every camera shares a frame with another), for the camera-only
    start of free-running or mixed-rate cameras. Cameras given as corners/ files take part
    through `corner_stems` (camera -> the csv's frames, integer ns), their renaming returned
    in Association.corner_frames; without it they keep their frames. Where every camera
    shares its stems the frames are the dataset's own."""
    corner_stems = {c: list(f) for c, f in (corner_stems or {}).items() if c in dataset.corners and f}
    cams = [c for c in dataset.cameras if (c not in dataset.corners and dataset.frames[c]) or c in corner_stems]
    stems = {c: {int(f): f for f in (corner_stems[c] if c in corner_stems else dataset.frames[c])} for c in cams}
    periods = [frame_period_ns(stems[c]) for c in cams]
    finite = [p for p in periods if p != float("inf")]
    for fraction in fractions:
        tol = int(fraction * min(finite)) if finite else 0
        groups = time_groups({c: stems[c].keys() for c in cams}, tol)
        linked = {c for g in groups if len(g) > 1 for c in g}
        if len(cams) < 2 or linked == set(cams):
            break
    frames: dict[str, dict[str, Path]] = {c: {} for c in cams if c not in corner_stems}
    renames: dict[str, dict[str, str]] = {c: {} for c in corner_stems}
    own: dict[str, dict[str, int]] = {c: {} for c in cams}
    renamed = False
    for g in groups:
        name = stems[min(g, key=lambda c: (g[c], cams.index(c)))][min(g.values())]
        for cam, t in g.items():
            if cam in renames:
                renames[cam][stems[cam][t]] = name
            else:
                frames[cam][name] = dataset.frames[cam][stems[cam][t]]
            own[cam][name] = t
            renamed |= stems[cam][t] != name
    out = {c: (MappingProxyType({k: frames[c][k] for k in sorted(frames[c], key=frame_sort_key)}) if c in frames
               else dataset.frames[c]) for c in dataset.cameras}
    shared = sum(len(g) > 1 for g in groups)
    return Association(DatasetImages(dataset.root, dataset.cameras, MappingProxyType(out), dataset.corners),
                       MappingProxyType({c: MappingProxyType(v) for c, v in own.items()}), tol, shared, renamed,
                       MappingProxyType({c: MappingProxyType(v) for c, v in renames.items()}))


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
