"""The `rigcal` command line (docs/cli.md). Thin: parse, call the library, print.

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
    of the rig) or imu (a hand-held recording with IMU streams, simulate_imu); static: the
    rig's IMUs at rest, for imu-noise (sim.static_imu)."""

    room = "room"
    board = "board"
    imu = "imu"
    static = "static"
    mag = "mag"


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

    auto = "auto"
    joint = "joint"
    held = "held"
    prior = "prior"


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
    # estimators and autopilots (rigcal.exports.openvins, vins, orbslam3, basalt, autopilot)
    openvins = "openvins"
    vins = "vins"
    orbslam3 = "orbslam3"
    basalt = "basalt"
    px4 = "px4"
    ardupilot = "ardupilot"


class ImportFormat(str, Enum):
    """`import --format`: the formats `rigcal import` reads."""

    kalibr = "kalibr"


@app.command()
@guarded
def simulate(
    rig: Path = typer.Argument(..., help="rig YAML (every camera needs a pose)"),
    out_dir: Path = typer.Option(..., "--out", help="dataset folder to write (the docs' File formats page)"),
    scene: Optional[Scene] = typer.Option(None, help="room: boards around a moving rig; board: one board moved in front; imu: the rig moved by hand in front of static boards, with IMU streams; static: the rig's IMUs at rest (imu-noise); mag: the rig turned through every orientation, IMU and magnetometer streams, no images. Default: room when some camera shares no view with the others"),
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
    duration: Optional[float] = typer.Option(None, help="--scene imu / mag: seconds of motion (default 30 / 60); --scene static: seconds at rest (default 10800)"),
    camera_rate: Optional[list[str]] = typer.Option(None, help="--scene imu: images per second per camera (default 20); HZ for all, or NAME=HZ once per camera (mixed rates)"),
    exposure: Optional[float] = typer.Option(None, help="--scene imu: exposure in seconds, gives motion blur (default 0.005)"),
    time_offset_ms: Optional[float] = typer.Option(None, help="--scene imu: true camera clock offsets are uniform in +-this (default 10)"),
    free_running: bool = typer.Option(False, help="--scene imu: every camera takes frames on its own schedule (own phase, rate error, jitter, start and stop): the stems differ"),
    drop_frames: Optional[float] = typer.Option(None, help="--scene imu: this fraction of every camera's frames is dropped at random (default 0)"),
):
    """Render a synthetic ChArUco dataset with ground truth (truth.yaml); --scene imu: a moving
    recording with IMU streams."""
    motion_flags = {"--duration": duration, "--camera-rate": camera_rate or None, "--exposure": exposure,
                    "--time-offset-ms": time_offset_ms, "--free-running": free_running or None,
                    "--drop-frames": drop_frames}
    if scene is Scene.static:
        from rigcal.sim import static_imu

        for flag, given in (("--frames", frames is not None), ("--blur", blur != 0.0),
                            *((f, v is not None) for f, v in motion_flags.items() if f != "--duration")):
            if given:
                raise InputError(f"{flag}: not used with --scene static (its options: --duration, --seed, --force)")
        out(static_imu.simulate_static(rig, out_dir, static_imu.DEFAULT_DURATION_S if duration is None else duration,
                                       seed=seed, force=force))
        return
    if scene is Scene.mag:  # the compass dance: IMU and magnetometer streams, no images (docs/magnetometer.md)
        from rigcal.sim import mag_scene

        unused = {"--frames": frames is not None, "--blur": blur != 0.0, "--target": target is not None,
                  **{f: v is not None for f, v in motion_flags.items() if f != "--duration"}}
        for flag, given in unused.items():
            if given:
                raise InputError(f"{flag}: not used with --scene mag (no images; --duration and --seed apply)")
        out(mag_scene.run(rig_path=rig, out_dir=out_dir, duration=duration, seed=seed, force=force))
        return
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


# `rigcal calibrate --help` groups its options (typer's help panels)
IO_PANEL, MODEL_PANEL, RUN_PANEL, IMU_PANEL = ("Inputs and outputs", "Camera model", "Detection and execution",
                                               "Camera-IMU (a dataset with imu/)")


@app.command()
@guarded
def calibrate(
    dataset: Path = typer.Argument(..., help="dataset folder (the docs' File formats page)"),
    out_yaml: Path = typer.Option(..., "--out", help="calibrated rig YAML to write", rich_help_panel=IO_PANEL),
    rig: Optional[Path] = typer.Option(None, help="declared rig (default DATASET/rig.yaml)", rich_help_panel=IO_PANEL),
    target: Optional[Path] = typer.Option(None, help="target YAML (default DATASET/target.yaml)",
                                          rich_help_panel=IO_PANEL),
    report: Optional[Path] = typer.Option(None, help="write a self-contained HTML report here",
                                          rich_help_panel=IO_PANEL),
    reference: Optional[str] = typer.Option(
        None, help="body frame: 'aligned' (fit to the declared rig), 'camera:NAME', or 'imu:NAME' (that IMU keeps "
                   "its declared pose; the default when the rig declares an IMU and the dataset has imu/)",
                   rich_help_panel=MODEL_PANEL),
    distortion: Distortion = typer.Option(
        Distortion.auto, help="pinhole distortion model; auto: radtan4, plus k3 or the rational terms when the data "
                              "show them", rich_help_panel=MODEL_PANEL),
    intrinsics: IntrinsicsChoice = typer.Option(
        IntrinsicsChoice.auto, help="which of fx, fy, cx, cy to estimate; auto: fx = fy and the principal point at "
                                    "its declared value (default the image centre) unless the data show otherwise; "
                                    "free: all four; square: fx = fy; centred: cx, cy held at the declared value; "
                                    "square-centred: both", rich_help_panel=MODEL_PANEL),
    fix_intrinsics: bool = typer.Option(False, help="keep the declared intrinsics and distortion",
                                        rich_help_panel=MODEL_PANEL),
    allow_resize: bool = typer.Option(False, help="accept images whose size differs from the rig's resolution (intrinsics are scaled)",
                                      rich_help_panel=MODEL_PANEL),
    guided: Guided = typer.Option(
        Guided.auto, help="re-measure the corners with the calibrated camera models, then solve again: auto = "
                          "fisheye cameras, on = every camera, off = the detector's corners are final",
                          rich_help_panel=RUN_PANEL),
    jobs: Optional[int] = typer.Option(None, help="detection worker processes (default: all cores)",
                                       rich_help_panel=RUN_PANEL),
    scheduler: Optional[str] = typer.Option(
        None, envvar="RIGCAL_SCHEDULER", help="a Dask scheduler's address (tcp://host:8786): its workers detect "
                                             "and re-measure the corners, reading the images at their absolute "
                                             "paths (needs rigcal[dask])", rich_help_panel=RUN_PANEL),
    camera_only: bool = typer.Option(False, help="with imu/: calibrate the cameras only (the IMU blocks are "
                                                 "carried through unchanged, the reference is 'aligned')",
                                                 rich_help_panel=IMU_PANEL),
    gravity: Optional[float] = typer.Option(None, help="with imu/: local gravity, m/s^2 (default 9.80665; EuRoC's "
                                                       "site 9.81007); its direction is estimated",
                                                       rich_help_panel=IMU_PANEL),
    offset_window: Optional[float] = typer.Option(None, help="with imu/: clock offsets are searched within +-this "
                                                             "many seconds of the declared time_offset_s (default 0.2)",
                                                             rich_help_panel=IMU_PANEL),
    rolling_shutter: bool = typer.Option(False, help="with imu/: estimate every camera's line_delay_s (default: "
                                                     "only where the rig declares one non-zero)",
                                                     rich_help_panel=IMU_PANEL),
    knot_spacing: Optional[float] = typer.Option(None, help="with imu/: the trajectory spline's knot spacing, s "
                                                            "(default: the coarsest of 0.05 .. 0.005 s at which a "
                                                            "spline follows the IMU's signal within 1.5x its "
                                                            "declared noise; printed and written)",
                                                            rich_help_panel=IMU_PANEL),
    imu_model: ImuModel = typer.Option(
        ImuModel.auto, help="with imu/: calibrated (gyro = omega + bias, accel = f + bias) or scale-misalignment "
                            "(each sensor reads M @ ideal + bias, M = I + lower-triangular: 3 scales and 3 "
                            "misalignments per sensor); auto: calibrated unless a likelihood-ratio test at the "
                            "lens models' level (p = 1e-4) finds scale and misalignment", rich_help_panel=IMU_PANEL),
    imu_intrinsics: ImuIntrinsics = typer.Option(
        ImuIntrinsics.auto, help="with imu/: auto = held when --rig (or DATASET/rig.yaml) is the output of an "
                                 "earlier `rigcal calibrate` (a camera calibration: its cameras carry calibration "
                                 "sigmas), else joint; joint = every camera's intrinsics are estimated again with "
                                 "the trajectory, poses and clocks (their 1-sigma then includes it); held = kept at "
                                 "the camera-only step's, as Kalibr does (--fix-intrinsics implies held); prior = "
                                 "estimated with the rest, weighted by the declared camera calibration's values "
                                 "and sigmas", rich_help_panel=IMU_PANEL),
):
    """Detect the boards and calibrate every camera's intrinsics and T_body_cam."""
    from rigcal.commands import calibrate as cal

    out(cal.run(dataset, out_yaml, cal.CalibrateOptions(
        rig=rig, target=target, report=report, reference=reference, distortion=distortion.value,
        intrinsics=intrinsics.value, fix_intrinsics=fix_intrinsics, allow_resize=allow_resize, guided=guided.value,
        jobs=jobs, scheduler=scheduler, camera_only=camera_only, gravity=gravity, offset_window=offset_window,
        rolling_shutter=rolling_shutter, knot_spacing=knot_spacing, imu_model=imu_model.value,
        imu_intrinsics=imu_intrinsics.value)))


@app.command()
@guarded
def check(
    rig: Path = typer.Argument(..., help="calibrated rig YAML (what `rigcal calibrate` writes, with sigmas)"),
    dataset: Path = typer.Argument(..., help="a short new recording of the rig (docs/formats.md#dataset: images/ or corners/, "
                                             "target.yaml; with imu/ a camera-IMU rig is checked against its IMU)"),
    report: Optional[Path] = typer.Option(None, help="write an HTML report here (residual maps, tests)"),
    level: float = typer.Option(0.01, help="false-alarm rate of the whole check (an unchanged rig fails this "
                                           "share of recordings)"),
    json_out: bool = typer.Option(False, "--json", help="print one JSON object instead of the table"),
    update: Optional[Path] = typer.Option(None, help="write the rig with what changed re-estimated from this "
                                                     "recording (the rest held)"),
    jobs: Optional[int] = typer.Option(None, help="detection worker processes (default: all cores)"),
):
    """Is the rig's calibration still good? Per camera ok, moved, intrinsics changed, clock changed or undetermined.
    Exit 0: all ok; 1: something changed; 2: bad input."""
    from rigcal.check.run import run as run_check

    text, code = run_check(rig, dataset, report_path=report, level=level, as_json=json_out, update_path=update,
                           jobs=jobs)
    out(text)
    if code:
        raise typer.Exit(code)


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
    format: ExportFormat = typer.Option(..., "--format", help="kalibr | opencv | ros | json | kalibr-imu | euroc | "
                                                              "openvins | vins | orbslam3 | basalt | px4 | ardupilot"),
    out_path: Path = typer.Option(..., "--out", help="file (kalibr, json, orbslam3, basalt, px4, ardupilot) or folder "
                                                     "(opencv, ros, kalibr-imu, euroc, openvins, vins)"),
    camera: Optional[str] = typer.Option(None, help="vins, orbslam3: this camera (with its stereo partner); px4, "
                                                    "ardupilot: the sensor camera. Default: the first pair / camera"),
):
    """Write the rig for other tools: Kalibr camchain, OpenCV FileStorage, ROS camera_info, JSON, and the
    settings of OpenVINS, VINS-Fusion, ORB-SLAM3, basalt, PX4 and ArduPilot."""
    from rigcal.commands import export as exp

    out(exp.run(rig, format.value, out_path, camera=camera))


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
    out_dir: Path = typer.Option(..., "--out", help="dataset folder to write (the docs' File formats page: dataset, motion datasets)"),
    rig: Optional[Path] = typer.Option(None, help="rig YAML to copy in as DATASET/rig.yaml (EuRoC: default "
                                                  "written from the sensor.yaml files)"),
    target: Optional[Path] = typer.Option(None, help="target YAML to copy in as DATASET/target.yaml"),
    camera: Optional[list[str]] = typer.Option(None, help="NAME=TOPIC (bag), NAME=FILE (video) or NAME=camN "
                                                          "(EuRoC); repeat per camera"),
    imu: Optional[list[str]] = typer.Option(None, help="NAME=TOPIC (bag) or NAME=imuN (EuRoC)"),
    mag: Optional[list[str]] = typer.Option(None, help="NAME=TOPIC: a bag's sensor_msgs/MagneticField topic, written "
                                                       "as mag/NAME.csv (microtesla); repeat per magnetometer"),
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
    """Turn a recording (EuRoC folder, ROS bag, videos, ArduPilot .bin log) into a dataset folder."""
    from rigcal.mag.flightlog import is_flight_log

    if is_flight_log(source):  # ArduPilot DataFlash: imu/ + mag/ for the magnetometer calibration (--rig)
        from rigcal.mag.flightlog import run as ingest_log

        out(ingest_log(source, out_dir, rig, force=force))
        return
    from rigcal.data import ingest as ing

    out(ing.run(source, out_dir, rig_path=rig, target_path=target, cameras=camera, imus=imu, rate=rate, start=start,
                end=end, offsets=offset, body_axes=body_axes, copy=copy, force=force, mags=mag))


class NoiseFormat(str, Enum):
    """`imu-noise --format`: the file written (rigcal.imunoise.formats)."""

    kalibr = "kalibr"
    rig = "rig"
    basalt = "basalt"
    openvins = "openvins"
    vins = "vins"
    orbslam3 = "orbslam3"


@app.command("imu-noise")
@guarded
def imu_noise(
    source: Path = typer.Argument(..., help="static recording: an IMU .csv (EuRoC format), a dataset folder with "
                                            "imu/, a EuRoC folder, or a ROS 1 / ROS 2 bag"),
    out_path: Path = typer.Option(..., "--out", help="file to write (Kalibr imu.yaml by default)"),
    imu: Optional[list[str]] = typer.Option(None, help="NAME=TOPIC (bag), NAME=FILE (dataset imu/ or csv) or "
                                                       "NAME=imuN (EuRoC); repeat per IMU"),
    rig: Optional[Path] = typer.Option(None, help="rig YAML whose imus entry takes the figures (--format rig; "
                                                  "written to --out, the rest of the rig kept)"),
    report: Optional[Path] = typer.Option(None, help="HTML page: Allan deviation per axis, fitted lines, "
                                                     "confidence bands, tau ranges"),
    format: Optional[NoiseFormat] = typer.Option(None, "--format", help="kalibr (default; rig with --rig), rig, "
                                                                        "basalt, openvins, vins, orbslam3"),
    inflate: float = typer.Option(1.0, help="multiply every figure written by this factor (the file says so)"),
):
    """An IMU's noise figures (white noise density, random walk, bias instability) from a static
    recording, by overlapping Allan deviation, with 95 % intervals."""
    from rigcal.commands import imu_noise as cmd

    out(cmd.run(source, out_path, imus=imu, rig_path=rig, report_path=report,
                fmt=format.value if format else None, inflate=inflate))


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
        # a bad option or argument is bad input like any other: one line, exit 2 (docs/cli.md)
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
