"""The `rigcal` command line (../shared/spec/cli.md). Thin: parse, call the library, print.

Results go to stdout, progress and warnings to stderr. A RigcalError becomes one
line on stderr and its exit code (2 bad input, 1 the work failed); nothing else
ever reaches the user as a traceback (set RIGCAL_DEBUG=1 to see one).
"""

from __future__ import annotations

import functools
import os
import signal
import sys
from enum import Enum
from pathlib import Path
from typing import Optional

import typer

from rigcal.errors import InputError, RigcalError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Calibrate the cameras of a drone's camera rig (body frame FLU).",
)


def _fail(message: str, code: int) -> None:
    typer.echo(f"rigcal: {message}", err=True)
    raise typer.Exit(code)


def guarded(fn):
    """Turn every failure into one stderr line and an exit code."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except typer.Exit:
            raise
        except RigcalError as e:
            _fail(str(e), e.exit_code)
        except Terminated:
            _fail("terminated (SIGTERM); no partial output was left behind", 128 + signal.SIGTERM)
        except KeyboardInterrupt:
            _fail("interrupted; no partial output was left behind", 130)
        except Exception as e:  # pragma: no cover - the last line of defence
            if os.environ.get("RIGCAL_DEBUG"):
                raise
            _fail(f"internal error: {e.__class__.__name__}: {e} (set RIGCAL_DEBUG=1 for a traceback)", 1)

    return wrapper


def out(text) -> None:
    """Print a result (str or rich renderable) to stdout."""
    if isinstance(text, str):
        typer.echo(text)
    else:
        import shutil

        from rich.console import Console

        # Tables must not be cut to 80 columns when piped to a file or a log.
        width = None if sys.stdout.isatty() else max(shutil.get_terminal_size((160, 24)).columns, 160)
        Console(soft_wrap=True, width=width).print(text)


class Scene(str, Enum):
    """`simulate --scene`: room (wall boards around a turning rig), board (one board in front
    of the rig) or imu (a hand-held recording with IMU streams, simulate_imu)."""

    room = "room"
    board = "board"
    imu = "imu"


class Distortion(str, Enum):
    """`calibrate --distortion`: the distortion model, or auto (chosen per camera, model_selection)."""

    auto = "auto"
    radial2 = "radial2"
    radtan4 = "radtan4"
    radtan5 = "radtan5"
    rational8 = "rational8"


class IntrinsicsChoice(str, Enum):
    """`calibrate --intrinsics`: which of fx, fy, cx, cy are estimated, or auto (model_selection)."""

    auto = "auto"
    free = "free"
    square = "square"
    centred = "centred"
    square_centred = "square-centred"


class ImuModel(str, Enum):
    """`calibrate --imu-model`: the IMU's measurement model (calibrate_imu), or auto (tested)."""

    auto = "auto"
    calibrated = "calibrated"
    scale_misalignment = "scale-misalignment"


class ImuIntrinsics(str, Enum):
    """`calibrate --imu-intrinsics`: the intrinsics in the camera-IMU estimate (calibrate_imu)."""

    joint = "joint"
    held = "held"


class Guided(str, Enum):
    """`calibrate --guided`: the guided corner pass (guided.py); auto runs it on fisheye cameras."""

    auto = "auto"
    on = "on"
    off = "off"


class ExportFormat(str, Enum):
    """`export --format`: the formats of export.py and export_imu.py."""

    kalibr = "kalibr"
    opencv = "opencv"
    ros = "ros"
    json = "json"
    kalibr_imu = "kalibr-imu"
    euroc = "euroc"


class ImportFormat(str, Enum):
    """`import --format`: the formats `rigcal import` reads."""

    kalibr = "kalibr"


@app.command()
@guarded
def simulate(
    rig: Path = typer.Argument(..., help="rig YAML (every camera needs a pose)"),
    out_dir: Path = typer.Option(..., "--out", help="dataset folder to write (dataset.md)"),
    scene: Optional[Scene] = typer.Option(None, help="room: boards around a moving rig; board: one board moved in front; imu: the rig moved by hand in front of static boards, with IMU streams (imu.md). Default: room when some camera shares no view with the others"),
    frames: Optional[int] = typer.Option(None, help="number of frames (default 60 room, 40 board)"),
    seed: int = typer.Option(0, help="random seed; the same seed writes byte-identical images"),
    noise: float = typer.Option(2.0, help="Gaussian image noise, grey levels (sigma)"),
    blur: float = typer.Option(0.0, help="motion blur length, pixels"),
    mount_error_mm: float = typer.Option(5.0, help="1-sigma mounting position error, mm"),
    mount_error_deg: float = typer.Option(1.0, help="1-sigma mounting rotation error, degrees"),
    focal_error: float = typer.Option(0.02, help="1-sigma relative focal length error"),
    target: Optional[Path] = typer.Option(None, help="target YAML to use instead of one generated from the rig"),
    force: bool = typer.Option(False, help="replace a non-empty output folder"),
    jobs: Optional[int] = typer.Option(None, help="worker processes (default: all cores)"),
    duration: Optional[float] = typer.Option(None, help="--scene imu: seconds of motion (default 30)"),
    camera_rate: Optional[list[str]] = typer.Option(None, help="--scene imu: images per second per camera (default 20); HZ for all, or NAME=HZ once per camera (mixed rates)"),
    exposure: Optional[float] = typer.Option(None, help="--scene imu: exposure in seconds, gives motion blur (default 0.005)"),
    time_offset_ms: Optional[float] = typer.Option(None, help="--scene imu: true camera clock offsets are uniform in +-this (default 10)"),
    free_running: bool = typer.Option(False, help="--scene imu: every camera takes frames on its own schedule (own phase, rate error, jitter, start and stop): the stems differ"),
    drop_frames: Optional[float] = typer.Option(None, help="--scene imu: this fraction of every camera's frames is dropped at random (default 0)"),
):
    """Render a synthetic ChArUco dataset with ground truth (truth.yaml); --scene imu: a moving
    recording with IMU streams (imu.md)."""
    motion_flags = {"--duration": duration, "--camera-rate": camera_rate or None, "--exposure": exposure,
                    "--time-offset-ms": time_offset_ms, "--free-running": free_running or None,
                    "--drop-frames": drop_frames}
    if scene is Scene.imu:
        from rigcal.sim import imu_scene as simulate_imu

        for flag, given in (("--frames", frames is not None), ("--blur", blur != 0.0)):
            if given:
                raise InputError(f"{flag}: not used with --scene imu (use --duration / --camera-rate; the motion "
                                 f"blur comes from --exposure)")
        out(simulate_imu.run(rig_path=rig, out_dir=out_dir, duration=duration, camera_rate=camera_rate,
                             exposure=exposure, time_offset_ms=time_offset_ms, seed=seed, noise=noise,
                             mount_error_mm=mount_error_mm, mount_error_deg=mount_error_deg, focal_error=focal_error,
                             target_path=target, force=force, jobs=jobs, free_running=free_running,
                             drop=drop_frames or 0.0))
        return
    for flag, v in motion_flags.items():
        if v is not None:
            raise InputError(f"{flag}: only used with --scene imu")
    from rigcal.sim import simulate as sim

    out(sim.run(rig_path=rig, out_dir=out_dir, scene=scene.value if scene else None, frames=frames, seed=seed,
                noise=noise, blur=blur, mount_error_mm=mount_error_mm, mount_error_deg=mount_error_deg,
                focal_error=focal_error, target_path=target, force=force, jobs=jobs))


@app.command()
@guarded
def calibrate(
    dataset: Path = typer.Argument(..., help="dataset folder (dataset.md)"),
    out_yaml: Path = typer.Option(..., "--out", help="calibrated rig YAML to write"),
    rig: Optional[Path] = typer.Option(None, help="declared rig (default DATASET/rig.yaml)"),
    target: Optional[Path] = typer.Option(None, help="target YAML (default DATASET/target.yaml)"),
    report: Optional[Path] = typer.Option(None, help="write a self-contained HTML report here"),
    jobs: Optional[int] = typer.Option(None, help="detection worker processes (default: all cores)"),
    reference: Optional[str] = typer.Option(
        None, help="body frame: 'aligned' (fit to the declared rig), 'camera:NAME', or 'imu:NAME' (that IMU keeps "
                   "its declared pose; the default when the rig declares an IMU and the dataset has imu/)"),
    distortion: Distortion = typer.Option(
        Distortion.auto, help="pinhole distortion model; auto: radtan4, plus k3 or the rational terms when the data "
                              "show them"),
    intrinsics: IntrinsicsChoice = typer.Option(
        IntrinsicsChoice.auto, help="which of fx, fy, cx, cy to estimate; auto: fx = fy and the principal point at "
                                    "its declared value (default the image centre) unless the data show otherwise; "
                                    "free: all four; square: fx = fy; centred: cx, cy held at the declared value; "
                                    "square-centred: both"),
    fix_intrinsics: bool = typer.Option(False, help="keep the declared intrinsics and distortion"),
    allow_resize: bool = typer.Option(False, help="accept images whose size differs from the rig's resolution (intrinsics are scaled)"),
    guided: Guided = typer.Option(
        Guided.auto, help="re-measure the corners with the calibrated camera models, then solve again: auto = "
                          "fisheye cameras, on = every camera, off = the detector's corners are final"),
    scheduler: Optional[str] = typer.Option(
        None, envvar="RIGCAL_SCHEDULER", help="a Dask scheduler's address (tcp://host:8786): its workers detect "
                                             "and re-measure the corners, reading the images at their absolute "
                                             "paths (needs rigcal[dask])"),
    gravity: Optional[float] = typer.Option(None, help="with imu/: local gravity, m/s^2 (default 9.80665; EuRoC's "
                                                       "site 9.81007); its direction is estimated"),
    offset_window: Optional[float] = typer.Option(None, help="with imu/: clock offsets are searched within +-this "
                                                             "many seconds of the declared time_offset_s (default 0.2)"),
    rolling_shutter: bool = typer.Option(False, help="with imu/: estimate every camera's line_delay_s (default: "
                                                     "only where the rig declares one non-zero)"),
    camera_only: bool = typer.Option(False, help="with imu/: calibrate the cameras only (the IMU blocks are "
                                                 "carried through unchanged, the reference is 'aligned')"),
    knot_spacing: Optional[float] = typer.Option(None, help="with imu/: the trajectory spline's knot spacing, s "
                                                            "(default 0.05; 0.01, Kalibr's, for fast hand-waved motion)"),
    imu_model: ImuModel = typer.Option(
        ImuModel.auto, help="with imu/: calibrated (gyro = omega + bias, accel = f + bias) or scale-misalignment "
                            "(each sensor reads M @ ideal + bias, M = I + lower-triangular: 3 scales and 3 "
                            "misalignments per sensor); auto: calibrated unless a likelihood-ratio test at the "
                            "lens models' level (p = 1e-4) finds scale and misalignment"),
    imu_intrinsics: ImuIntrinsics = typer.Option(
        ImuIntrinsics.joint, help="with imu/: joint = every camera's intrinsics are estimated again with the "
                                  "trajectory, poses and clocks (their 1-sigma then includes it); held = kept at "
                                  "the camera-only step's, as Kalibr does (--fix-intrinsics implies held)"),
):
    """Detect the boards and calibrate every camera's intrinsics and T_body_cam."""
    from rigcal.commands import calibrate as cal

    out(cal.run(dataset=dataset, out_path=out_yaml, rig_path=rig, target_path=target, report_path=report, jobs=jobs,
                reference=reference, distortion=distortion.value, fix_intrinsics=fix_intrinsics,
                allow_resize=allow_resize, guided=guided.value, intrinsics=intrinsics.value,
                scheduler=scheduler, imu_options={"gravity": gravity, "window_s": offset_window,
                                                  "rolling_shutter": True if rolling_shutter else None,
                                                  "knot_dt": knot_spacing, "imu_model": imu_model.value,
                                                  "intrinsics": imu_intrinsics.value},
                camera_only=camera_only))


@app.command()
@guarded
def compare(
    calibrated: Path = typer.Argument(..., help="calibrated rig YAML"),
    truth: Path = typer.Argument(..., help="truth.yaml of a simulated dataset, or another rig file"),
):
    """Errors of a calibrated rig against truth: per camera, per camera pair, per stereo baseline."""
    from rigcal.results import compare as cmp

    out(cmp.run(calibrated, truth))


@app.command()
@guarded
def project(
    rig: Path = typer.Argument(..., help="rig YAML"),
    position: tuple[float, float, float] = typer.Option(..., help="body position E N U (metres)"),
    point: tuple[float, float, float] = typer.Option(..., help="navigation-frame point E N U (metres)"),
    heading: Optional[float] = typer.Option(None, help="degrees clockwise from north (0 = flying north), level flight"),
    axes: Optional[tuple[str, str, str]] = typer.Option(None, help="body F, L, U axes in ENU terms, e.g. N -E U"),
):
    """Project an ENU point into every camera at a body pose; stereo disparity and depth."""
    from rigcal.commands.project import run as run_project

    out(run_project(rig, position=position, point=point, heading=heading, axes=axes))


@app.command()
@guarded
def export(
    rig: Path = typer.Argument(..., help="calibrated rig YAML"),
    format: ExportFormat = typer.Option(..., "--format", help="kalibr | opencv | ros | json | kalibr-imu | euroc"),
    out_path: Path = typer.Option(..., "--out", help="file (kalibr, json) or folder (opencv, ros, kalibr-imu, euroc)"),
):
    """Write the rig for other tools: Kalibr camchain, OpenCV FileStorage, ROS camera_info, JSON."""
    from rigcal.commands import export as exp

    out(exp.run(rig, format.value, out_path))


@app.command("import")
@guarded
def import_(
    source: Path = typer.Argument(..., help="file to import (Kalibr camchain.yaml)"),
    format: ImportFormat = typer.Option(ImportFormat.kalibr, "--format"),
    out_path: Path = typer.Option(..., "--out", help="rig YAML to write"),
    rig: Optional[Path] = typer.Option(None, help="declared rig giving the body frame (camera names and poses)"),
    body_from: Optional[str] = typer.Option(None, help="use this camera (e.g. cam0) as the body frame instead"),
):
    """Read another tool's calibration into a rig YAML."""
    from rigcal.commands import export as exp

    out(exp.run_import(source, format.value, out_path, rig_path=rig, body_from=body_from))


@app.command()
@guarded
def board(
    target: Path = typer.Argument(..., help="target YAML"),
    out_path: Path = typer.Option(..., "--out", help="FILE.png or FILE.pdf"),
    dpi: int = typer.Option(300, help="dots per inch; 1 board metre = dpi / 0.0254 px"),
):
    """A printable image of each board, to scale."""
    from rigcal.core import target as tgt

    out(tgt.run_board(target, out_path, dpi))


@app.command()
@guarded
def view(
    rig: Path = typer.Argument(..., help="rig YAML"),
    out_path: Path = typer.Option(..., "--out", help="HTML file to write"),
):
    """The rig's camera frames in the FLU body frame, as an interactive 3D page (works offline)."""
    from rigcal.results import view as vw

    out(vw.run(rig, out_path))


@app.command()
@guarded
def ingest(
    source: Path = typer.Argument(..., help="EuRoC folder (mav0/), ROS 1 .bag, ROS 2 bag (folder, .db3, .mcap), "
                                            "or a video file / folder of videos"),
    out_dir: Path = typer.Option(..., "--out", help="dataset folder to write (dataset.md, imu.md)"),
    rig: Optional[Path] = typer.Option(None, help="rig YAML to copy in as DATASET/rig.yaml (EuRoC: default "
                                                  "written from the sensor.yaml files)"),
    target: Optional[Path] = typer.Option(None, help="target YAML to copy in as DATASET/target.yaml"),
    camera: Optional[list[str]] = typer.Option(None, help="NAME=TOPIC (bag), NAME=FILE (video) or NAME=camN "
                                                          "(EuRoC); repeat per camera"),
    imu: Optional[list[str]] = typer.Option(None, help="NAME=TOPIC (bag) or NAME=imuN (EuRoC)"),
    rate: Optional[float] = typer.Option(None, help="keep one instant per 1/HZ s, the sharpest (variance of the "
                                                    "Laplacian); default: every frame"),
    start: Optional[float] = typer.Option(None, help="seconds after the first image stamp to start at"),
    end: Optional[float] = typer.Option(None, help="seconds after the first image stamp to end at"),
    offset: Optional[list[str]] = typer.Option(None, help="NAME=SECONDS added to a video camera's frame times"),
    body_axes: Optional[tuple[str, str, str]] = typer.Option(
        None, help="EuRoC: the body frame B's x, y, z axes in FLU terms (default U -L F: EuRoC's IMU, x up, "
                   "y right, z forward)"),
    copy: bool = typer.Option(False, help="copy image files instead of linking them (EuRoC)"),
    force: bool = typer.Option(False, help="replace a non-empty output folder"),
):
    """Turn a recording (EuRoC folder, ROS bag, videos) into a dataset folder."""
    from rigcal.data import ingest as ing

    out(ing.run(source, out_dir, rig_path=rig, target_path=target, cameras=camera, imus=imu, rate=rate, start=start,
                end=end, offsets=offset, body_axes=body_axes, copy=copy, force=force))


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is so that every atomic writer and worker pool
    cleans up as it does for Ctrl-C (Python's default for SIGTERM is to die on the spot,
    leaving temporary files and orphaned worker processes)."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated()


def _click_exceptions():
    """(ClickException, NoArgsIsHelpError or None): typer >= 0.2x vendors click as typer._click."""
    try:
        from typer._click import exceptions as ex
    except ImportError:  # older typer: click itself
        from click import exceptions as ex
    return ex.ClickException, getattr(ex, "NoArgsIsHelpError", None)


def main() -> None:
    signal.signal(signal.SIGTERM, _on_sigterm)
    click_error, no_args = _click_exceptions()
    try:
        rv = app(standalone_mode=False)
    except click_error as e:
        if no_args is not None and isinstance(e, no_args):
            sys.exit(e.exit_code)  # `rigcal` alone: typer has printed its help page
        # a bad option or argument is bad input like any other: one line, exit 2 (cli.md)
        ctx = getattr(e, "ctx", None)
        where = ctx.command_path if ctx is not None else "rigcal"
        msg = " ".join(e.format_message().split())
        typer.echo(f"{where}: {msg} (see {where} --help)", err=True)
        sys.exit(e.exit_code)
    except KeyboardInterrupt:  # before a command's own guard was entered
        typer.echo("rigcal: interrupted", err=True)
        sys.exit(130)
    except typer.Abort:  # end of input at a prompt
        typer.echo("rigcal: aborted", err=True)
        sys.exit(1)
    sys.exit(rv if isinstance(rv, int) else 0)


if __name__ == "__main__":
    main()
