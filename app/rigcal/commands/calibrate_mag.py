"""`rigcal calibrate` on a dataset with mag/: the magnetometer step (rigcal.mag.step), either
after the cameras and IMU (with_magnetometers) or alone on a dataset of imu/ and mag/ with no
images (run_mag_only: the cameras are carried through unchanged, the IMUs keep their
declared poses)."""

from __future__ import annotations

from pathlib import Path
from types import MappingProxyType
from typing import Mapping

from rich.console import Console, Group

from rigcal.core.io import atomic_write_texts
from rigcal.core.rig import Rig, dump_rig, load_rig
from rigcal.data.imu_csv import ImuSamples
from rigcal.data.mag_csv import check_mag_dataset
from rigcal.errors import DatasetError
from rigcal.mag.step import MagStep, calibrate_magnetometers, console_table


def mag_only_dataset(dataset: Path) -> bool:
    """A dataset with mag/ and imu/ and neither images/ nor corners/."""
    d = Path(dataset)
    return (d / "mag").is_dir() and (d / "imu").is_dir() and not (d / "images").exists() and not (
        d / "corners").exists()


def with_magnetometers(rig: Rig, dataset: Path, imus: Mapping[str, ImuSamples], console: Console,
                       refuse: bool = False) -> tuple[Rig, list, MagStep | None]:
    """The calibrated rig with its magnetometers calibrated too (when the dataset has mag/),
    the console tables to print after the others, and the step (None without magnetometers:
    the report's section needs its results); notes go to `console`. After a camera
    calibration (refuse=False) a magnetometer whose recording is refused is carried through
    with a warning rather than failing the whole run."""
    if not rig.magnetometers and not (Path(dataset) / "mag").exists():
        return rig, [], None
    step = calibrate_magnetometers(rig, dataset, imus, refuse=refuse)
    for n in step.notes:
        console.print(n if n.startswith("warning: ") else f"note: {n}")
    return step.rig, [console_table(step)] if step.results else [], step


def run_mag_only(dataset: Path, out_path: Path, rig_path: Path | None, report_path: Path | None, console: Console,
                 check_output_path) -> Group:
    """Calibrate the magnetometers of a dataset with imu/ and mag/ only; write the rig."""
    from rigcal.data.dataset import DatasetImages, dataset_rig_path
    from rigcal.data.imu_csv import check_motion_dataset

    check_output_path(out_path)
    if report_path is not None:
        check_output_path(report_path)
    rig = load_rig(dataset_rig_path(dataset, rig_path))
    if not rig.magnetometers:
        raise DatasetError(f"{Path(dataset) / 'mag'}: the rig declares no magnetometer (add `magnetometers:`)")
    motion = check_motion_dataset(dataset, rig, DatasetImages(Path(dataset), (), MappingProxyType({})))
    samples = check_mag_dataset(dataset, rig, motion.imus)  # every bad input refused before anything is printed
    for n in motion.notes:
        console.print(f"note: {n}")
    console.print(f"note: no images: {len(rig.cameras)} camera(s) carried through unchanged; the IMUs keep their "
                  f"declared poses; magnetometers calibrated against them")
    step = calibrate_magnetometers(rig, dataset, motion.imus, refuse=True, samples=samples)
    for n in step.notes:
        console.print(n if n.startswith("warning: ") else f"note: {n}")
    files = [(out_path, dump_rig(step.rig))]
    if report_path is not None:
        from rigcal.results.report_mag import mag_report

        files.append((report_path, mag_report(step.rig, rig, dict(step.results),
                                              {k: v.m for k, v in step.inputs.items()})))
    atomic_write_texts(files)
    wrote = f"wrote {out_path}" + (f" and {report_path}" if report_path is not None else "")
    return Group(f"{wrote}: {len(step.rig.magnetometers)} magnetometer(s) calibrated", console_table(step))
