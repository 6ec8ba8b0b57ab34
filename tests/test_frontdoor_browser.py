"""The committed front door in headless Chromium: it loads without errors, its figure
loads, and a reviewer sees every claim's verdict in the first screen's table."""

import json
from pathlib import Path

from selenium.webdriver.common.by import By

from tests.test_report_in_browser import chromium_driver

REPORTS = Path(__file__).resolve().parents[1] / "reports"


def test_front_door_renders_with_every_verdict_on_one_screen():
    driver = chromium_driver()
    try:
        driver.set_window_size(1400, 1000)
        driver.get((REPORTS / "index.html").as_uri())
        table = driver.find_element(By.CSS_SELECTOR, "#verdicts table")
        rows = table.find_elements(By.TAG_NAME, "tr")[1:]
        assert len(rows) == 5
        reduced = json.loads((REPORTS / "reduced" / "fig3" / "summary.json").read_text())
        for row, claim in zip(rows, reduced["claims"][:4]):
            links = row.find_elements(By.TAG_NAME, "a")
            assert claim["verdict"].split(":")[0] in [a.text for a in links]
        # the verdict table starts on the first screen
        top = driver.execute_script("return arguments[0].getBoundingClientRect().top", table)
        assert top < 1000
        for image in driver.find_elements(By.TAG_NAME, "img"):
            assert driver.execute_script(
                "return arguments[0].complete && arguments[0].naturalWidth > 0", image
            )
        errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        assert not errors, errors
    finally:
        driver.quit()
