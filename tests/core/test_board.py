"""`rigcal board`: printable boards measured to scale (PNG pixels, PDF page size)."""

from __future__ import annotations

import re
import struct
import zlib

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core.target import parse_target

runner = CliRunner()

TWO = """boards:
  - {name: front, type: charuco, dictionary: DICT_5X5_1000, squares: [6, 4], square_length: 0.04, marker_length: 0.03}
  - {name: back, type: charuco, dictionary: DICT_5X5_1000, squares: [5, 5], square_length: 0.035, marker_length: 0.025,
     first_marker_id: 12, legacy_pattern: true}
"""
CHESS = "boards:\n  - {name: chess, type: chessboard, inner_corners: [7, 5], square_length: 0.025}\n"


def _fit_pitch(corners: np.ndarray, ids: np.ndarray, nx: int) -> float:
    """Least-squares pitch (px per square) of corners with ids on an nx-wide grid."""
    ij = np.column_stack([ids % nx, ids // nx]).astype(float)
    A = np.column_stack([ij, np.ones(len(ij))])
    coef_u, *_ = np.linalg.lstsq(A, corners[:, 0], rcond=None)
    coef_v, *_ = np.linalg.lstsq(A, corners[:, 1], rcond=None)
    return float(np.hypot(coef_u[0], coef_v[0])), float(np.hypot(coef_u[1], coef_v[1]))


def _png_px_per_m(data: bytes) -> int:
    i = data.index(b"pHYs")
    ppm_x, ppm_y, unit = struct.unpack(">IIB", data[i + 4:i + 13])
    assert unit == 1 and ppm_x == ppm_y
    return ppm_x


def _edges(row: np.ndarray) -> np.ndarray:
    """Sub-pixel positions of the black/white edges along one image row of an exact
    area-coverage raster: the mixed pixel's grey says where in it the edge lies
    (pixel i spans [i, i+1) here)."""
    v = row.astype(float) / 255.0
    dark = v < 0.5
    out = []
    for i in np.nonzero(dark[1:] != dark[:-1])[0]:
        # the transition is inside pixel i or i+1, whichever is mixed (neither: on the boundary)
        j = i if 0 < v[i] < 1 else i + 1
        if dark[i]:  # black -> white: white fraction of pixel j lies right of the edge
            out.append(j + (1 - v[j]) if 0 < v[j] < 1 else i + 1)
        else:  # white -> black
            out.append(j + v[j] if 0 < v[j] < 1 else i + 1)
    return np.array(out)


def _pitch_from_edges(img: np.ndarray, y: int) -> float:
    e = _edges(img[y])
    k = np.arange(len(e))
    return float(np.polyfit(k, e, 1)[0])


def test_png_is_to_scale(tmp_path):
    (tmp_path / "t.yaml").write_text(CHESS)
    out = tmp_path / "chess.png"
    r = runner.invoke(app, ["board", str(tmp_path / "t.yaml"), "--out", str(out), "--dpi", "150"])
    assert r.exit_code == 0, r.output
    assert "chess" in r.output and "150 dpi" in r.output
    data = out.read_bytes()
    assert _png_px_per_m(data) == round(150 / 0.0254)  # PNG stores whole pixels per metre
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    expected = 0.025 * 150 / 0.0254  # 147.6378 px per square
    margin = 75  # half an inch
    # the page: the pattern plus the margins
    assert img.shape == (int(np.ceil(6 * expected)) + 2 * margin, int(np.ceil(8 * expected)) + 2 * margin)
    # edges along a row through the first row of squares: exactly one pitch apart, from the margin on
    e = _edges(img[margin + int(expected / 2)])
    assert len(e) == 8  # paper | 8 squares, black first, the last one white like the paper
    assert np.abs(e - (margin + np.arange(8) * expected)).max() < 0.01
    ok, found = cv2.findChessboardCorners(img, (7, 5))
    assert ok
    px, py = _fit_pitch(found.reshape(-1, 2), np.arange(35), 7)
    # a detector agrees too (to its own sub-pixel accuracy)
    assert px == pytest.approx(expected, abs=0.05) and py == pytest.approx(expected, abs=0.05)


def test_png_per_board_and_charuco_scale(tmp_path):
    (tmp_path / "t.yaml").write_text(TWO)
    out = tmp_path / "boards.png"
    r = runner.invoke(app, ["board", str(tmp_path / "t.yaml"), "--out", str(out), "--dpi", "200"])
    assert r.exit_code == 0, r.output
    assert not out.exists()
    target = parse_target(TWO)
    margin = 100
    for b in target.boards:
        img = cv2.imread(str(tmp_path / f"boards-{b.name}.png"), cv2.IMREAD_GRAYSCALE)
        expected = b.square_length * 200 / 0.0254
        # a row in the white gap between the first row's square edges and its markers
        y = margin + int(0.5 * (b.square_length - b.marker_length) / 2 * 200 / 0.0254)
        e = _edges(img[y])
        assert len(e) >= b.squares[0] - 1
        assert np.abs(e - (margin + np.arange(len(e)) * expected)).max() < 0.01, b.name
        corners, ids, _, _ = cv2.aruco.CharucoDetector(b.cv_board()).detectBoard(img)
        assert len(ids.reshape(-1)) == b.n_corners


def _pdf_pages(data: bytes) -> list[tuple[list[float], int, int, bytes]]:
    """(MediaBox, image width, height, decoded pixels) per page of the PDFs rigcal writes."""
    assert data.startswith(b"%PDF-1.4") and data.rstrip().endswith(b"%%EOF")
    boxes = [[float(x) for x in m.groups()] for m in re.finditer(rb"/MediaBox \[([\d.]+) ([\d.]+) ([\d.]+) ([\d.]+)\]", data)]
    images = []
    for m in re.finditer(rb"/Width (\d+) /Height (\d+) .*?/Length (\d+) >>\nstream\n", data):
        n = int(m.group(3))
        raw = zlib.decompress(data[m.end():m.end() + n])
        images.append((int(m.group(1)), int(m.group(2)), raw))
    # the xref offsets must point at the objects
    xref = int(re.search(rb"startxref\n(\d+)", data).group(1))
    assert data[xref:xref + 4] == b"xref"
    count = int(re.search(rb"xref\n0 (\d+)", data).group(1))
    table = data[xref:].split(b"\n")[3:3 + count - 1]
    for k, row in enumerate(table, start=1):
        off = int(row[:10])
        assert data[off:].startswith(b"%d 0 obj" % k)
    return [(b, w, h, raw) for b, (w, h, raw) in zip(boxes, images)]


def test_pdf_page_size_is_the_physical_board(tmp_path):
    (tmp_path / "t.yaml").write_text(TWO)
    out = tmp_path / "boards.pdf"
    r = runner.invoke(app, ["board", str(tmp_path / "t.yaml"), "--out", str(out), "--dpi", "300"])
    assert r.exit_code == 0, r.output
    pages = _pdf_pages(out.read_bytes())
    target = parse_target(TWO)
    assert len(pages) == 2
    for (box, w, h, raw), b in zip(pages, target.boards):
        bw, bh = b.size_m
        # 72 points per inch; the pattern plus half an inch each side, within one pixel
        assert box[:2] == [0.0, 0.0]
        assert box[2] == pytest.approx((bw / 0.0254 + 1.0) * 72, abs=72 / 300)
        assert box[3] == pytest.approx((bh / 0.0254 + 1.0) * 72, abs=72 / 300)
        assert box[2] == pytest.approx(w * 72 / 300, abs=1e-4) and box[3] == pytest.approx(h * 72 / 300, abs=1e-4)
        img = np.frombuffer(raw, np.uint8).reshape(h, w)
        corners, ids, _, _ = cv2.aruco.CharucoDetector(b.cv_board()).detectBoard(img)
        px, _ = _fit_pitch(corners.reshape(-1, 2), ids.reshape(-1), b.inner_corners[0])
        assert px == pytest.approx(b.square_length * 300 / 0.0254, abs=0.02)


def test_label_in_margin(tmp_path):
    (tmp_path / "t.yaml").write_text(CHESS)
    out = tmp_path / "c.png"
    assert runner.invoke(app, ["board", str(tmp_path / "t.yaml"), "--out", str(out), "--dpi", "100"]).exit_code == 0
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    bottom = img[-50:]  # the half-inch bottom margin holds the text
    assert (bottom < 128).sum() > 200
    assert (img[:10] == 255).all()  # the top margin is blank paper


@pytest.mark.parametrize("args, msg", [
    (["--out", "{d}/x.jpg"], "must end in .png or .pdf"),
    (["--out", "{d}/x.png", "--dpi", "0"], "--dpi"),
    (["--out", "{d}/x.png", "--dpi", "100000"], "lower --dpi"),
])
def test_bad_board_arguments(tmp_path, args, msg):
    (tmp_path / "t.yaml").write_text(CHESS)
    args = [a.format(d=tmp_path) for a in args]
    r = runner.invoke(app, ["board", str(tmp_path / "t.yaml")] + args)
    assert r.exit_code == 2
    assert msg in r.output and len(r.output.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.yaml"]


def test_bad_target_and_unwritable(tmp_path):
    (tmp_path / "t.yaml").write_text(CHESS.replace("0.025", "-1"))
    r = runner.invoke(app, ["board", str(tmp_path / "t.yaml"), "--out", str(tmp_path / "x.png")])
    assert r.exit_code == 2 and "square_length" in r.output
    (tmp_path / "t.yaml").write_text(CHESS)
    (tmp_path / "file").write_text("")
    r = runner.invoke(app, ["board", str(tmp_path / "t.yaml"), "--out", str(tmp_path / "file" / "x.png")])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1
