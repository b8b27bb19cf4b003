"""The whole study in a real headless Chromium, end to end.

`jaxround study serve` runs as a subprocess on a free port of 127.0.0.1 with
short rides; Selenium drives Debian's ``chromium`` through ``chromedriver``
(nothing is downloaded): consent, demographics, the practice drive and both
rides with scripted key presses, the three questions. Then the rows in
SQLite and the report's counts are checked.

Without a browser the test is skipped, unless ``JAXROUND_REQUIRE_BROWSER=1``
(set by ``.ci/run``), under which it fails.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from jaxround.apps.cli.main import main
from jaxround.study.storage import StudyDatabase
from tests.study.study_browser import chromium_driver, study_server

pytestmark = pytest.mark.sumo

RIDE_S, PRACTICE_S = 6.0, 5.0
#: The answers given, as option numbers on the page (unblinded: the paper's).
ANSWERS = {"smoothness": 3, "safety": 2, "preference": 0}


@pytest.fixture(scope="module")
def chromium() -> Iterator[object]:
    with chromium_driver() as driver:
        yield driver


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    folder = tmp_path_factory.mktemp("browser-study")
    options = ("--warmup-s", "15", "--ride-s", str(RIDE_S), "--practice-s",
               str(PRACTICE_S))  # fmt: skip
    with study_server(folder, *options) as running:
        yield running


def test_a_participant_completes_the_study_in_chromium(
    chromium: object, study: tuple[str, Path], tmp_path: Path
) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import Select, WebDriverWait

    driver = chromium
    base, db = study
    wait = WebDriverWait(driver, 90)

    def visible(element_id: str) -> object:
        return wait.until(lambda d: d.find_element(By.ID, element_id).is_displayed()
                          and d.find_element(By.ID, element_id))  # fmt: skip

    def hold(key: str, seconds: float) -> None:
        ActionChains(driver).key_down(key).perform()
        time.sleep(seconds)
        ActionChains(driver).key_up(key).perform()

    def drive(brake: bool) -> str:
        visible("intro-go").click()
        wait.until(lambda d: "s left" in d.find_element(By.ID, "drive-status").text)
        hold(Keys.ARROW_UP, 1.5)
        if brake:
            hold(Keys.SPACE, 0.6)
        text = visible("drive-end-text").text
        visible("drive-end-go").click()
        return text

    driver.get(base + "/")
    visible("consent-box").click()
    visible("consent-go").click()
    Select(visible("demo-gender")).select_by_value("female")
    visible("demo-age").send_keys("31")
    visible("demo-years").send_keys("12")
    visible("demo-go").click()
    assert "time limit" in drive(brake=False)
    for _ in ("first", "second"):
        assert "time limit" in drive(brake=True)
    for number, option in enumerate(ANSWERS.values(), start=1):
        wait.until(lambda d, n=number: d.find_element(By.ID, "survey-number").text
                   == str(n))  # fmt: skip
        visible(f"option-{option}").click()
        visible("survey-go").click()
    visible("page-thanks")
    errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    assert errors == []

    database = StudyDatabase(db)
    (who,) = database.rows("participants")
    assert (who["gender"], who["age"], who["driving_years"]) == ("female", 31, 12)
    assert who["finished_utc"] is not None and who["ride_order"] == "20-80"
    answers = {a["question"]: a["option_paper"] for a in database.rows("answers")}
    assert answers == ANSWERS
    rides = {r["kind"]: r for r in database.rows("rides")}
    assert set(rides) == {"practice", "first", "second"}
    assert (rides["first"]["share"], rides["second"]["share"]) == (0.2, 0.8)
    for kind, ride in rides.items():
        assert ride["status"] == "time_limit"
        steps = database.rows("ride_steps", "WHERE ride_id = ?", (ride["ride_id"],))
        assert len(steps) == ride["steps"] > 0
        assert max(s["throttle"] for s in steps) > 0  # the key presses arrived
        assert (max(s["brake"] for s in steps) > 0) == (kind != "practice")
        assert ride["latency_samples"] >= 1 and ride["delay_median_ms"] > 0

    out = tmp_path / "report"
    assert main(["study", "report", "--db", str(db), "--out", str(out)]) == 0
    tables = json.loads((out / "report.json").read_text())["tables"]
    for question, option in ANSWERS.items():
        assert tables[question]["counts"] == [int(i == option) for i in range(5)]
