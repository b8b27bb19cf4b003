"""A practice ride on the two-lane roundabout in a real headless Chromium:
the page names the turn-signal keys, the dashboard shows the ego's lane, the
left arrow moves the ego to the inner lane, and the database keeps the lane
changes.

`jaxround study serve --config two_lane --policy eco+gap:10` runs as a
subprocess on a free port of 127.0.0.1 (its AVs under a scripted lane rule);
Selenium drives Debian's ``chromium``. Skipped without a browser, unless
``JAXROUND_REQUIRE_BROWSER=1``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from jaxround.study.storage import StudyDatabase
from tests.study.study_browser import chromium_driver, study_server

pytestmark = pytest.mark.sumo


def test_the_left_arrow_changes_the_ego_to_the_inner_lane(tmp_path: Path) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import WebDriverWait

    options = ("--config", "two_lane", "--policy", "eco+gap:10",
               "--practice-passes", "1", "--practice-s", "40")  # fmt: skip
    with chromium_driver() as driver, study_server(tmp_path, *options) as (base, db):
        wait = WebDriverWait(driver, 90)

        def visible(element_id: str) -> object:
            return wait.until(lambda d: d.find_element(By.ID, element_id).is_displayed()
                              and d.find_element(By.ID, element_id))  # fmt: skip

        def lane_text() -> str:
            box = driver.find_element(By.ID, "lane-box")
            return box.text if box.is_displayed() else ""

        driver.get(base + "/")
        visible("consent-box").click()
        visible("consent-go").click()
        visible("demo-go").click()
        assert "signals left" in visible("lane-keys").text
        visible("intro-go").click()  # the practice ride on the empty roundabout
        wait.until(lambda d: "s left" in d.find_element(By.ID, "drive-status").text)
        ActionChains(driver).key_down(Keys.ARROW_UP).perform()
        wait.until(lambda d: "lane 1 of 2" in lane_text())
        ActionChains(driver).send_keys(Keys.ARROW_LEFT).perform()
        wait.until(lambda d: "lane 2 of 2" in lane_text())
        visible("drive-end-text")
        ActionChains(driver).key_up(Keys.ARROW_UP).perform()

    database = StudyDatabase(db)
    (ride,) = database.rows("rides")
    events = database.rows("ride_events", "WHERE kind = 'lane_change'")
    details = [e["detail"] for e in events]
    assert ride["status"] == "arrived" and ride["collisions"] == 0
    assert details[0] == "left to in_0_1, asked for", details
    assert any(d.endswith("for the route") for d in details[1:]), details
