"""index.html in headless Chromium: a click on a column header sorts the table, the tabs switch.

Needs Debian's `chromium` and `chromium-driver` (`.ci/run` installs them, then runs this file with
`python -m pytest -m browser`) and selenium (the [dev] extra).  Browsers downloaded by test tools do
not run here, so both binaries are named explicitly; when they are missing the test fails and says
how to install them.
"""

from __future__ import annotations

import os

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By

from deint_env.leaderboard import Scope, build

# Not in the default run (pyproject's addopts): `python -m pytest -m browser`, which .ci/run does after
# installing the browser, so that there a missing browser fails the run.
pytestmark = pytest.mark.browser

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--no-first-run", "--window-size=1400,1000"]


def test_header_click_sorts_the_table(tmp_path):
    for path in (CHROMIUM, CHROMEDRIVER):
        assert os.path.exists(path), f"{path} is missing: apt-get install -y chromium chromium-driver"
    scope = Scope("core-v0", ("core-n2-spread1.5-jitter0.05", "core-n3-spread4-jitter0.2"), max_seeds=2)
    build(scope, ["genie", "random", "nearest-prior"], workers=1, root=tmp_path, progress=False, reps=200)
    options = Options()
    options.binary_location = CHROMIUM
    for flag in FLAGS + [f"--user-data-dir={tmp_path / 'profile'}"]:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        driver.get((tmp_path / "core-v0" / "index.html").as_uri())
        table = driver.find_element(By.ID, "board-0")  # the online division's table: all three have lag 0
        heads = [th.text for th in table.find_elements(By.CSS_SELECTOR, "thead th")]
        col = heads.index("accuracy")

        def column(i: int) -> list[str]:
            return [tr.find_elements(By.TAG_NAME, "td")[i].get_attribute("data-v")
                    for tr in table.find_elements(By.CSS_SELECTOR, "tbody tr")]

        policies = heads.index("policy")
        assert column(policies)[0] == "genie"  # ranked by score mean: the oracle first
        header = table.find_elements(By.CSS_SELECTOR, "thead th")[col]
        header.click()
        values = [float(v) for v in column(col)]
        assert values == sorted(values) and column(policies)[0] == "random"
        assert header.get_attribute("aria-sort") == "ascending"
        header.click()
        assert [float(v) for v in column(col)] == sorted(values, reverse=True)
        table.find_elements(By.CSS_SELECTOR, "thead th")[policies].click()
        assert column(policies) == sorted(column(policies))
        shot = tmp_path / "leaderboard.png"
        assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 1000

        assert driver.find_element(By.ID, "tab-tag-jitter").is_displayed() is False
        driver.find_element(By.CSS_SELECTOR, 'button[data-tab="tab-tag-jitter"]').click()
        assert driver.find_element(By.ID, "tab-tag-jitter").is_displayed()
        assert not table.is_displayed()
        assert all(img.get_property("naturalWidth") > 0 for img in driver.find_elements(By.TAG_NAME, "img"))
    finally:
        driver.quit()
