"""Open the smoke report in headless Chromium: every image loads, nothing logs an error,
every section is there. Needs Debian's chromium and chromium-driver (`.ci/run` installs them)."""

import os
import shutil

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By

from replicate.cli import main

SECTIONS = ("claims", "figure", "aggregate", "final-returns", "budgets", "demonstrations", "runs",
            "provenance", "smoke-warning")


def chromium_driver() -> webdriver.Chrome:
    browser, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not (browser and driver):
        reason = "headless Chromium is needed: apt-get install chromium chromium-driver"
        if os.environ.get("REPLICATE_REQUIRE_BROWSER") == "1":  # set by .ci/run
            pytest.fail(reason)
        pytest.skip(reason)
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(executable_path=driver), options=options)


@pytest.fixture(scope="module")
def smoke_reports(smoke_fig3, tmp_path_factory):
    table1, fig4 = tmp_path_factory.mktemp("table1"), tmp_path_factory.mktemp("fig4")
    assert main(["table1", "--out", str(table1)]) == 0
    assert main(["fig4", "--profile", "smoke", "--env", "MountainCarContinuous-v0", "--seeds",
                 "2", "--store", str(smoke_fig3[0]), "--out", str(fig4)]) == 0
    return {"fig3": smoke_fig3[1], "table1": table1, "fig4": fig4}


@pytest.mark.parametrize("report, sections", [
    ("fig3", SECTIONS), ("table1", ("dimensions", "demonstrations")),
    ("fig4", ("figure", "pairs", "claims", "provenance", "smoke-warning"))])
def test_report_renders_in_chromium(smoke_reports, report, sections):
    driver = chromium_driver()
    try:
        driver.get((smoke_reports[report] / "index.html").as_uri())
        for section in sections:
            assert driver.find_elements(By.ID, section), f"section {section} missing"
        images = driver.find_elements(By.TAG_NAME, "img")
        for image in images:
            loaded = driver.execute_script(
                "return arguments[0].complete && arguments[0].naturalWidth > 0", image)
            assert loaded, f"image {image.get_attribute('alt')!r} did not load"
        if report in ("fig3", "fig4"):
            assert len(images) >= 1
        errors = [entry for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]
        assert not errors, errors
    finally:
        driver.quit()
