"""The whole study in a real headless Chromium, end to end.

`jaxround study serve` runs as a subprocess on a free port of 127.0.0.1;
Selenium drives Debian's ``chromium`` through ``chromedriver`` (nothing is
downloaded). The first test goes through the whole study with short rides:
consent, demographics, the practice drive and both rides with scripted key
presses, the three questions; then the rows in SQLite and the report's
counts are checked. The second drives one ride of the default length with
the throttle held (and the brake tapped to measure the input-to-frame
latency part by part, which it prints).

Without a browser the test is skipped, unless ``JAXROUND_REQUIRE_BROWSER=1``
(set by ``.ci/run``), under which it fails.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from jaxround.apps.cli.main import main
from jaxround.study.settings import StudySettings
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


#: The parts of the input-to-frame latency, in their order (docs/study.md).
LATENCY_PARTS = ("event", "websocket", "relay_in", "wait", "sumo", "frame",
                 "relay_out", "draw", "total")  # fmt: skip
#: Seconds between two taps of the brake (each a press and a release).
TAP_EVERY_S = 1.5


@pytest.fixture(scope="module")
def default_study(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[str, Path]]:
    folder = tmp_path_factory.mktemp("browser-default")
    with study_server(folder, "--practice-passes", "1") as running:
        yield running


def latency_table(records: list[dict]) -> str:
    lines = [f"{'part':>10} {'median':>8} {'p90':>8} ms ({len(records)} inputs)"]
    for part in LATENCY_PARTS:
        values = sorted(r[part] for r in records if r.get(part) is not None)
        if values:
            p90 = values[min(len(values) - 1, int(0.9 * len(values)))]
            lines.append(f"{part:>10} {statistics.median(values):8.1f} {p90:8.1f}")
    return "\n".join(lines)


def test_a_ride_of_the_default_length_and_the_latency_part_by_part(
    chromium: object, default_study: tuple[str, Path]
) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import WebDriverWait

    driver = chromium
    base, db = default_study
    wait = WebDriverWait(driver, 120)

    def visible(element_id: str) -> object:
        return wait.until(lambda d: d.find_element(By.ID, element_id).is_displayed()
                          and d.find_element(By.ID, element_id))  # fmt: skip

    def status() -> str:
        return driver.find_element(By.ID, "drive-status").text

    driver.get(base + "/")
    driver.execute_script("sessionStorage.clear()")
    driver.get(base + "/")
    minutes = StudySettings(policy=Path("p")).estimated_minutes()
    assert visible("consent-minutes").text == str(minutes)
    visible("consent-box").click()
    visible("consent-go").click()
    visible("demo-go").click()
    visible("intro-go").click()  # the practice: one pass, the throttle held
    wait.until(lambda d: "s left" in status())
    ActionChains(driver).key_down(Keys.ARROW_UP).perform()
    visible("drive-end-text")
    ActionChains(driver).key_up(Keys.ARROW_UP).perform()
    visible("drive-end-go").click()

    visible("intro-go").click()  # the first ride, among traffic
    assert visible("drive-wait").is_displayed()  # the waiting screen, not the view
    wait.until(lambda d: "s left" in status())
    assert not driver.find_element(By.ID, "drive-wait").is_displayed()
    driver.execute_script("window.studyLatency = []")
    ActionChains(driver).key_down(Keys.ARROW_UP).perform()
    end = driver.find_element(By.ID, "drive-end")
    while not end.is_displayed():
        time.sleep(TAP_EVERY_S)
        ActionChains(driver).key_down(Keys.SPACE).perform()
        time.sleep(0.08)
        ActionChains(driver).key_up(Keys.SPACE).perform()
    ActionChains(driver).key_up(Keys.ARROW_UP).perform()
    text = visible("drive-end-text").text
    records = driver.execute_script("return window.studyLatency")

    database = StudyDatabase(db)
    (ride,) = database.rows("rides", "WHERE kind = 'first'")
    steps = database.rows("ride_steps", "WHERE ride_id = ?", (ride["ride_id"],))
    driving_s = sum(s["on_road"] for s in steps) * ride["step_s"]
    throttle = [s["throttle"] for s in steps if s["on_road"]]
    print(f"\ndefault ride: {ride['status']}, {driving_s:.1f} s of driving, "
          f"{ride['steps']} steps, crossing {ride['crossing_time_s']} s per pass; "
          f"{text}")  # fmt: skip
    print(latency_table(records))
    assert ride["status"] == "arrived" and "8 times" in text
    assert driving_s >= 60.0
    assert statistics.median(throttle) > 0.9  # held
    assert len(records) >= 20
    # the server's parts of each input (a timing message a slow page dropped,
    # counted in frames_dropped, leaves one record without them)
    told = [r for r in records if r.get("wait") is not None]
    assert len(told) >= 0.9 * len(records)
    assert statistics.median(r["total"] for r in records) < 100.0
