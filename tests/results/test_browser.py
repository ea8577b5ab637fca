"""The report and `rigcal view`'s page in headless Chromium: the pages load from a file with
no network, log no console errors, and every plot draws (2D plots their SVG traces, 3D
plots a WebGL canvas with something on it). Full-page screenshots go to tests/artifacts/.

Needs Debian's `chromium` and `chromium-driver` (make test / .ci/run install them when
they can) and selenium (test extras); skipped with the reason when either is missing.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from rigcal.results import view
from rigcal.core.io import atomic_write_text

from tests.support.report_page import FIGURE_IDS, synthetic_report_html

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
WIDTH = 1400
# Root in a container: no sandbox, no GPU; nothing that talks to the network. WebGL then runs
# on SwiftShader, which Chromium wants opted into explicitly (the pages are our own files).
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-unsafe-swiftshader", "--disable-dev-shm-usage", f"--window-size={WIDTH},1000"]
LOAD_TIMEOUT_S = 120

# Every plotly div has its SVG scaffold, and 3D scenes their WebGL canvas.
RENDERED_JS = """
const divs = Array.from(document.querySelectorAll('.plotly-graph-div'));
return document.readyState === 'complete' && divs.length > 0 && divs.every(d =>
    d._fullLayout && d.querySelector('svg.main-svg') && (!d._fullLayout.scene || d.querySelector('canvas')));
"""
PLOTS_JS = """
return Array.from(document.querySelectorAll('.plotly-graph-div')).map(d => {
    const r = d.getBoundingClientRect();
    return {id: d.id, traces: (d._fullData || []).length, svg: d.querySelectorAll('svg.main-svg').length,
            scene: !!d._fullLayout.scene, trace_groups: d.querySelectorAll('g.trace, g.hm').length,
            canvas: Array.from(d.querySelectorAll('canvas')).filter(c => c.width > 0 && c.height > 0).length,
            box: [r.left + window.scrollX, r.top + window.scrollY, r.width, r.height]};
});
"""


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    if not CHROMIUM or not CHROMEDRIVER:
        pytest.skip("headless Chromium is not installed (Debian packages chromium and chromium-driver; "
                    "make test installs them when run as root)")
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install -e '.[test]')")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS + [f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}"]:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # An explicit driver path: selenium does not run its downloader (Selenium Manager).
    d = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
    d.set_page_load_timeout(LOAD_TIMEOUT_S)
    yield d
    d.quit()


def open_page(driver, path: Path, shot: str) -> tuple[list[dict], list[dict], str]:
    """Load a page, wait for every plot, save a full-page screenshot to ARTIFACTS/shot.
    Returns (plots, console log entries, page text)."""
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get_log("browser")  # drop anything logged before this page
    driver.set_window_size(WIDTH, 1000)
    driver.get(path.as_uri())
    WebDriverWait(driver, LOAD_TIMEOUT_S, poll_frequency=0.25).until(lambda d: d.execute_script(RENDERED_JS))
    height = int(driver.execute_script("return document.documentElement.scrollHeight"))
    driver.set_window_size(WIDTH, height + 200)  # the window chrome takes some of it; the page must fit
    WebDriverWait(driver, LOAD_TIMEOUT_S, poll_frequency=0.25).until(lambda d: d.execute_script(RENDERED_JS))
    driver.execute_script("window.scrollTo(0, 0)")
    plots = driver.execute_script(PLOTS_JS)
    ARTIFACTS.mkdir(exist_ok=True)
    assert driver.save_screenshot(str(ARTIFACTS / shot))
    return plots, driver.get_log("browser"), driver.execute_script("return document.body.innerText")


def inked_fraction(png: Path, box: list[float]) -> float:
    """Fraction of the pixels in box [x, y, w, h] (CSS px) of a screenshot that are not
    near-white: 0 for a plot area left empty."""
    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    x, y, w, h = (int(round(v)) for v in box)
    crop = img[max(y, 0):y + h, max(x, 0):x + w]
    assert crop.size, f"plot box {box} lies outside the {img.shape[1]}x{img.shape[0]} screenshot"
    return float(np.mean(crop < 200))


def check_plots(plots: list[dict], png: Path) -> None:
    for p in plots:
        assert p["traces"] > 0, p
        assert p["svg"] >= 1, p
        if p["scene"]:
            assert p["canvas"] >= 1, f"{p['id']}: 3D plot without a WebGL canvas"
        else:
            assert p["trace_groups"] >= 1, f"{p['id']}: 2D plot drew no trace"
        assert inked_fraction(png, p["box"]) > 0.01, f"{p['id']}: plot area is blank in the screenshot"


def severe(log: list[dict]) -> list[str]:
    return [e["message"] for e in log if e["level"] == "SEVERE"]


@pytest.mark.slow
def test_report_renders_in_chromium(driver, tmp_path):
    page = tmp_path / "report.html"
    atomic_write_text(page, synthetic_report_html())
    plots, log, text = open_page(driver, page, "report.png")
    assert severe(log) == []
    assert [p["id"] for p in plots] == FIGURE_IDS
    assert sum(p["scene"] for p in plots) == 2  # the rig and the board/frame poses
    check_plots(plots, ARTIFACTS / "report.png")
    assert "WebGL is not supported" not in text
    for words in ("rigcal calibration report: drone-stereo-back", "front_left / front_right", "Per-frame RMS"):
        assert words in text


def test_view_page_renders_in_chromium(driver, tmp_path):
    page = tmp_path / "view.html"
    view.run(ROOT / "rigs" / "drone-stereo-back.yaml", page)
    plots, log, text = open_page(driver, page, "view.png")
    assert severe(log) == []
    assert len(plots) == 1 and plots[0]["scene"]
    assert plots[0]["traces"] == 3 + 4 * 3  # body F, L, U; x, y, z and frustum per camera
    check_plots(plots, ARTIFACTS / "view.png")
    assert "WebGL is not supported" not in text
