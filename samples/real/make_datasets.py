"""Real calibration photos from ../shared/data/real in rigcal's dataset layout.

    python samples/real/make_datasets.py OUTDIR [NAME ...]      # NAME: caliscope caliscope_b wideangle trinocular
                                                                 # euroc (default all)
    python samples/real/make_datasets.py --samples               # rebuild samples/real/bumblebee2, opencv_stereo

The big sets (caliscope, wideangle, trinocular) become folders under OUTDIR whose
images are symbolic links into the shared copy (nothing is duplicated; caliscope_b's
frames are decoded from its videos into PNG files); rig.yaml and
target.yaml are written beside them. The two small chessboard sets are copied, with
their licences, into samples/real/ (--samples), which is how the committed samples
were made. The EuRoC imu_april set (euroc) has no images: its corners become
corners/<camera>.csv. Every rig.yaml here is a *declared* rig: resolutions, rough nominal focal
lengths and, where the geometry is known, nominal poses - never the reference
calibration, which the READMEs quote for comparison.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REAL = HERE.parents[2] / "shared" / "data" / "real"


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text.lstrip("\n"), encoding="utf-8")


def _link_images(dst: Path, pairs: list[tuple[str, str, Path]]) -> None:
    """(camera, frame stem, source image) -> DST/images/<camera>/<stem><ext> as a symbolic link."""
    for cam, stem, src in pairs:
        out = dst / "images" / cam / f"{stem}{src.suffix.lower()}"
        out.parent.mkdir(parents=True, exist_ok=True)
        if out.is_symlink() or out.exists():
            out.unlink()
        os.symlink(src.resolve(), out)


def _fresh(dst: Path) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)


# ----------------------------------------------------------------------------- linked sets


def build_caliscope(dst: Path) -> Path:
    """caliscope_4cam_charuco_a/frames_extracted: 4 webcams, 45 synchronised groups, an
    inverted 4x5 ChArUco board; the rig declares no pose (calibrate finds them)."""
    src = REAL / "caliscope_4cam_charuco_a" / "frames_extracted"
    _fresh(dst)
    _link_images(dst, [(cam.name, f.stem, f) for cam in sorted(src.iterdir()) if cam.is_dir()
                       for f in sorted(cam.glob("*.jpg"))])
    return _caliscope_files(dst, "caliscope_4cam_charuco_a")


def build_caliscope_b(dst: Path) -> Path:
    """caliscope_4cam_charuco_b: the same webcams and board, a second recording that comes
    as one video per camera (57 frames each). Each frame is written as a PNG (lossless from
    the decoded video) named by its sync index: video frame k is sync group 35 + k (the
    set's README, checked against caliscope's own corner file)."""
    import cv2

    src = REAL / "caliscope_4cam_charuco_b" / "calibration" / "extrinsic"
    _fresh(dst)
    for video in sorted(src.glob("cam_*.mp4")):
        out = dst / "images" / video.stem
        out.mkdir(parents=True)
        cap = cv2.VideoCapture(str(video))
        k = 0
        while True:
            ok, img = cap.read()
            if not ok:
                break
            cv2.imwrite(str(out / f"{35 + k:06d}.png"), img)
            k += 1
        cap.release()
    return _caliscope_files(dst, "caliscope_4cam_charuco_b")


def _caliscope_files(dst: Path, name: str) -> Path:
    """rig.yaml and target.yaml of a caliscope set."""
    cams = "".join(f"""
  cam_{i}:
    model: pinhole
    resolution: [1280, 720]
    intrinsics: {{focal: 800.0}}
""" for i in range(4))
    _write(dst / "rig.yaml", f"""
# caliscope's 4 USB webcams ({name}). Poses unknown: calibrate finds them.
# focal 800 px is a rough guess for these lenses, not the reference calibration.
rig: caliscope-4cam
body_frame: FLU
cameras:{cams}""")
    _write(dst / "target.yaml", """
# caliscope's board: printed colour-inverted (white markers on black); no key needed for that.
boards:
  - name: charuco
    type: charuco
    dictionary: DICT_4X4_1000
    squares: [4, 5]
    square_length: 0.054
    marker_length: 0.0405
""")
    return dst


def build_wideangle(dst: Path) -> Path:
    """stereo_calib_wideangle_charuco: 39 pairs, 1280x800, calib.io legacy ChArUco 31x16."""
    src = REAL / "stereo_calib_wideangle_charuco" / "dataset"
    _fresh(dst)
    pairs = []
    for cam in ("left", "right"):
        for f in sorted((src / cam).glob("*.png")):
            pairs.append((cam, re.sub(rf"^{cam}_", "", f.stem), f))  # left_p3_10 -> p3_10
    _link_images(dst, pairs)
    _write(dst / "rig.yaml", """
# Wide-angle grayscale stereo pair (stereo_calib_wideangle_charuco), ~75 mm baseline.
# Nominal values only; 8 distortion coefficients declare the rational model the author used.
rig: wideangle-stereo
body_frame: FLU
cameras:
  left:
    model: pinhole
    resolution: [1280, 800]
    intrinsics: {focal: 560.0}
    distortion: [0, 0, 0, 0, 0, 0, 0, 0]
    position: [0.0, 0.0375, 0.0]
    look: forward
  right:
    model: pinhole
    resolution: [1280, 800]
    intrinsics: {focal: 560.0}
    distortion: [0, 0, 0, 0, 0, 0, 0, 0]
    position: [0.0, -0.0375, 0.0]
    look: forward
stereo_pairs:
  - [left, right]
""")
    _write(dst / "target.yaml", """
# calib.io ChArUco 31x16 squares, measured 49.33 / 38.46 mm; even rows: OpenCV's legacy layout.
boards:
  - name: calibio
    type: charuco
    dictionary: DICT_4X4_250
    squares: [31, 16]
    square_length: 0.04933
    marker_length: 0.03846
    legacy_pattern: true
""")
    return dst


def build_trinocular(dst: Path) -> Path:
    """boofcv_trinocular_ecocheck: 3 cameras x 30, ECoCheck read as a 13x9 chessboard,
    180-degree symmetric, square size unknown (1.0 = results in squares)."""
    src = REAL / "boofcv_trinocular_ecocheck"
    _fresh(dst)
    pairs = []
    for cam in ("left", "middle", "right"):
        for f in sorted((src / cam).glob("*.jpg")):
            pairs.append((cam, f"{int(re.sub(r'[^0-9]', '', f.stem)):02d}", f))
    _link_images(dst, pairs)
    cams = "".join(f"""
  {c}:
    model: pinhole
    resolution: [1224, 1024]
    intrinsics: {{focal: 1800.0}}
""" for c in ("left", "middle", "right"))
    _write(dst / "rig.yaml", f"""
# BoofCV trinocular rig (boofcv_trinocular_ecocheck). Poses unknown to this file.
rig: boofcv-trinocular
body_frame: FLU
cameras:{cams}""")
    _write(dst / "target.yaml", """
# BoofCV ECoCheck 14x10 squares read as a plain chessboard (its dot codes are ignored).
# The physical square is undocumented: 1.0 makes every length come out in squares.
boards:
  - name: ecocheck
    type: chessboard
    inner_corners: [13, 9]
    square_length: 1.0
""")
    return dst


# ----------------------------------------------------------------------------- EuRoC corners

EUROC = REAL / "euroc_imu_april"
EUROC_CAMERAS = ("cam0", "cam1")
EUROC_BASELINE_MM = 110.07  # implied by EuRoC's published T_BS (reference.yaml)
EUROC_RIG = """
# EuRoC's MT9V034 stereo pair (752x480) as declared before calibration: rough focal
# length and distortion, nominal 110 mm baseline; EuRoC's own values are in
# ../shared/data/real/euroc_imu_april/reference.yaml, for comparison only.
rig: euroc-stereo
body_frame: FLU
cameras:
  cam0:
    model: pinhole
    resolution: [752, 480]
    intrinsics: {fx: 440.0, fy: 440.0, cx: 376.0, cy: 240.0}
    distortion: [-0.25, 0.05, 0.0, 0.0]
    position: [0.0, 0.055, 0.0]
    look: forward
  cam1:
    model: pinhole
    resolution: [752, 480]
    intrinsics: {fx: 440.0, fy: 440.0, cx: 376.0, cy: 240.0}
    distortion: [-0.25, 0.05, 0.0, 0.0]
    position: [0.0, -0.055, 0.0]
    look: forward
stereo_pairs:
  - [cam0, cam1]
"""


def read_yac(path: Path):
    """(N, 8) float rows of a yac corner file: t_ns, tag_id, corner, x_px, y_px, p_x_m, p_y_m, p_z_m."""
    import gzip

    import numpy as np

    with gzip.open(path, "rt") as f:
        return np.loadtxt(f, delimiter=",", skiprows=1, dtype=np.float64)


def build_euroc(dst: Path, every: int = 1) -> Path:
    """The EuRoC imu_april corners as a corners-only dataset (every `every`-th frame):
    corners/<camera>.csv in dataset.md's format (corner_id = 4 tag_id + corner, Kalibr's
    ids; yac's p_* columns are checked against rigcal's Board.corners on the way), Kalibr's
    own target file as target.yaml, and a declared rig."""
    import gzip

    import numpy as np

    from rigcal.core.target import load_target

    board = load_target(EUROC / "kalibr_target.yaml").boards[0]
    _fresh(dst)
    _write(dst / "rig.yaml", EUROC_RIG)
    _write(dst / "target.yaml", (EUROC / "kalibr_target.yaml").read_text())
    for cam in EUROC_CAMERAS:
        with gzip.open(EUROC / "corners" / f"{cam}.csv.gz", "rt") as f:
            raw = np.loadtxt(f, delimiter=",", skiprows=1, dtype=str)  # keeps the ns stamps exact
        num = raw[:, 1:].astype(np.float64)
        ids = (4 * num[:, 0] + num[:, 1]).astype(np.int64)
        if not np.allclose(num[:, 4:7], board.corners[ids], atol=1e-5):
            raise ValueError(f"{cam}: yac's corner positions differ from Kalibr's layout")
        keep = np.isin(raw[:, 0], np.unique(raw[:, 0])[::every])
        lines = [f"{t},{board.name},{i},{x:.6f},{y:.6f}"
                 for t, i, x, y in zip(raw[keep, 0], ids[keep], num[keep, 2], num[keep, 3])]
        _write(dst / "corners" / f"{cam}.csv", "#frame,board,corner_id,x_px,y_px\n" + "\n".join(lines) + "\n")
    return dst


BUILDERS = {"caliscope": build_caliscope, "caliscope_b": build_caliscope_b, "wideangle": build_wideangle,
            "trinocular": build_trinocular, "euroc": build_euroc}


# ----------------------------------------------------------------------------- copied samples


def copy_bumblebee2(dst: Path) -> Path:
    src = REAL / "boofcv_bumblebee2_stereo_chess"
    _fresh(dst)
    for cam in ("left", "right"):
        (dst / "images" / cam).mkdir(parents=True)
        for f in sorted(src.glob(f"{cam}[0-9][0-9].jpg")):
            shutil.copy2(f, dst / "images" / cam / f"{f.stem[len(cam):]}.jpg")
    (dst / "reference").mkdir()
    for name in ("LICENSE.TXT", "README.TXT"):
        shutil.copy2(src / name, dst / name)
    for name in ("stereo.yaml", "intrinsicLeft.yaml", "calibration_target.yaml", "info.txt"):
        shutil.copy2(src / name, dst / "reference" / name)
    return dst


def copy_opencv_stereo(dst: Path) -> Path:
    src = REAL / "opencv_samples_stereo_chess"
    _fresh(dst)
    for cam in ("left", "right"):
        (dst / "images" / cam).mkdir(parents=True)
        for f in sorted(src.glob(f"{cam}[0-9][0-9].jpg")):
            shutil.copy2(f, dst / "images" / cam / f"{f.stem[len(cam):]}.jpg")
    shutil.copytree(src / "licenses", dst / "licenses")
    shutil.copytree(src / "reference_scikit-surgeryimage", dst / "reference_scikit-surgeryimage")
    shutil.copy2(src / "stereo_calib.xml", dst / "stereo_calib.xml")
    return dst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outdir", nargs="?", help="where to build the linked datasets")
    ap.add_argument("names", nargs="*", help=f"any of {', '.join(BUILDERS)} (default: all)")
    ap.add_argument("--samples", action="store_true", help="re-copy the two small sets into samples/real/")
    args = ap.parse_args(argv)
    if not REAL.is_dir():
        print(f"make_datasets: {REAL} not found (the shared real-image sets)", file=sys.stderr)
        return 2
    if args.samples:
        # images and licences only: rig.yaml, target.yaml and README.md are written by hand
        for name, fn in (("bumblebee2", copy_bumblebee2), ("opencv_stereo", copy_opencv_stereo)):
            keep = {f: (HERE / name / f).read_text() for f in ("rig.yaml", "target.yaml", "README.md")
                    if (HERE / name / f).is_file()}
            fn(HERE / name)
            for f, text in keep.items():
                (HERE / name / f).write_text(text)
            print(f"samples/real/{name}")
    if args.outdir:
        bad = [n for n in args.names if n not in BUILDERS]
        if bad:
            print(f"make_datasets: unknown set {', '.join(bad)}; expected {', '.join(BUILDERS)}", file=sys.stderr)
            return 2
        for name in args.names or list(BUILDERS):
            print(BUILDERS[name](Path(args.outdir) / name))
    elif not args.samples:
        ap.print_usage(sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
