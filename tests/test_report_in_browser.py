"""Open the reports in headless Chromium at a 1400 px window, as a reader would: every image
loads, nothing logs an error, every section is there, and the learning curves are drawn large
enough to read (Fig. 3's and Fig. 4's panels at least ~400 px wide, the figure across the
content column, sharp at 2x pixel density). Needs Debian's chromium and chromium-driver
(`.ci/run` installs them)."""

import base64
import os
import shutil
from pathlib import Path
from typing import Any

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By

from replicate.cli.main import main
from replicate.figures.fig3 import rebuild_figure3
from replicate.figures.plots import png_panels
from replicate.grids.profiles import get_profile

WINDOW_WIDTH = 1400  # a laptop's browser window
MIN_PANEL_PX = 400  # narrower, and a panel's curves, bands and ticks run together
ROOT = Path(__file__).resolve().parents[1]

SECTIONS = (
    "claims",
    "figure",
    "aggregate",
    "final-returns",
    "budgets",
    "demonstrations",
    "runs",
    "provenance",
    "smoke-warning",
)


def chromium_driver() -> webdriver.Chrome:
    browser, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not (browser and driver):
        reason = "headless Chromium is needed: apt-get install chromium chromium-driver"
        if os.environ.get("REPLICATE_REQUIRE_BROWSER") == "1":  # set by .ci/run
            pytest.fail(reason)
        pytest.skip(reason)
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in (
        "--headless=new",
        f"--window-size={WINDOW_WIDTH},1000",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
    ):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(executable_path=driver), options=options)


@pytest.fixture(scope="module")
def smoke_reports(smoke_fig3, tmp_path_factory):
    table1, fig4 = tmp_path_factory.mktemp("table1"), tmp_path_factory.mktemp("fig4")
    assert main(["table1", "--out", str(table1)]) == 0
    assert (
        main(
            [
                "fig4",
                "--profile",
                "smoke",
                "--env",
                "MountainCarContinuous-v0",
                "--seeds",
                "2",
                "--store",
                str(smoke_fig3[0]),
                "--out",
                str(fig4),
            ]
        )
        == 0
    )
    return {"fig3": smoke_fig3[1], "table1": table1, "fig4": fig4}


@pytest.mark.parametrize(
    "report, sections",
    [
        ("fig3", SECTIONS),
        ("table1", ("dimensions", "demonstrations")),
        ("fig4", ("figure", "pairs", "claims", "provenance", "smoke-warning")),
    ],
)
def test_report_renders_in_chromium(smoke_reports, report, sections):
    driver = chromium_driver()
    try:
        driver.get((smoke_reports[report] / "index.html").as_uri())
        for section in sections:
            assert driver.find_elements(By.ID, section), f"section {section} missing"
        images = driver.find_elements(By.TAG_NAME, "img")
        for image in images:
            loaded = driver.execute_script(
                "return arguments[0].complete && arguments[0].naturalWidth > 0", image
            )
            assert loaded, f"image {image.get_attribute('alt')!r} did not load"
        if report in ("fig3", "fig4"):
            assert len(images) >= 1
        errors = [entry for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]
        assert not errors, errors
    finally:
        driver.quit()


def rendered_figure(driver: webdriver.Chrome, html: Path) -> dict[str, Any]:
    """The learning-curve figure of a report as the page lays it out: its displayed width and
    height, its natural width in image pixels, the width of the column it sits in, and its
    panels' plotting areas (fractions of the figure, recorded in the PNG)."""
    driver.get(html.as_uri())
    image = driver.find_element(By.CSS_SELECTOR, "#figure img")
    figure = driver.execute_script(
        "const img = arguments[0], box = img.getBoundingClientRect();"
        "return {width: box.width, height: box.height, natural: img.naturalWidth,"
        "        column: img.parentElement.clientWidth, window: window.innerWidth};",
        image,
    )
    source = image.get_attribute("src")
    assert source.startswith("data:image/png;base64,")
    figure["panels"] = png_panels(base64.b64decode(source.split(",", 1)[1]))
    return figure


def assert_readable(figure: dict[str, Any], panels: int, what: str) -> None:
    """Drawn across the column, every panel's plotting area at least ``MIN_PANEL_PX`` wide
    and 0.55 of that tall on the page, and two image pixels to each CSS pixel."""
    assert figure["window"] == WINDOW_WIDTH
    assert figure["width"] >= 0.9 * figure["column"], (
        f"{what} is drawn {figure['width']:.0f} px wide in a {figure['column']} px column"
    )
    assert len(figure["panels"]) == panels
    widths = [w * figure["width"] for _, _, w, _ in figure["panels"]]
    heights = [h * figure["height"] for _, _, _, h in figure["panels"]]
    assert min(widths) >= MIN_PANEL_PX, (
        f"{what}'s panels are {min(widths):.0f} px wide at a {WINDOW_WIDTH} px window, under "
        f"{MIN_PANEL_PX}: their curves, bands and ticks run together"
    )
    assert min(heights) >= 0.55 * MIN_PANEL_PX, f"{what}'s panels are {min(heights):.0f} px tall"
    assert figure["natural"] >= 1.98 * figure["width"], (
        f"{what} has {figure['natural']} image px for {figure['width']:.0f} CSS px: blurred at "
        "2x pixel density"
    )


@pytest.mark.parametrize("report, panels", [("fig3", 1), ("fig4", 2)])
def test_smoke_learning_curves_are_drawn_large_enough_to_read(smoke_reports, report, panels):
    driver = chromium_driver()
    try:
        figure = rendered_figure(driver, smoke_reports[report] / "index.html")
    finally:
        driver.quit()
    assert_readable(figure, panels, f"the smoke {report} figure")


def test_reduced_fig3_panels_are_each_at_least_400_px_wide(tmp_path):
    """The committed reduced runs' Fig. 3 (five envs), rebuilt as a reader gets it."""
    report = rebuild_figure3("reduced", store=ROOT / "runs", out_dir=tmp_path / "fig3")
    assert report is not None, "the committed reduced runs are missing from runs/"
    driver = chromium_driver()
    try:
        figure = rendered_figure(driver, report)
    finally:
        driver.quit()
    assert_readable(figure, len(get_profile("reduced").steps), "the reduced Fig. 3")
