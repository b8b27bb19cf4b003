"""Wheels and pedals without the standard mapping, in a real headless Chromium.

The page's ``navigator.getGamepads`` is replaced (before any script of the
page runs) by one that returns plain objects the test changes: a wheel
whose pedals are axes 2 (throttle) and 3 (brake), resting at +1, pressed at
-1 and read as 0 until they first move, as some browsers report them. The
participant sets the pedals up on the page before the practice drive, drives
with the wheel's throttle, and the ride's steps in SQLite show it; a server
default (``--pedal-map``) drives a pad with one combined pedal axis.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from jaxround.apps.cli.main import main
from jaxround.scenario.config import load_config
from jaxround.study.load import write_standin_policy
from jaxround.study.pedals import read_pedal_map
from jaxround.study.storage import StudyDatabase
from tests.study.study_browser import chromium_driver, study_server

WHEEL = "Fake Racing Wheel (Vendor: 1234 Product: 5678)"
LAB_PEDALS = "Lab Pedals (Vendor: abcd Product: 0001)"
#: The lab's combined pedal axis: throttle towards -1, brake towards +1.
PEDAL_MAP = {
    LAB_PEDALS: {
        "throttle": {"kind": "axis", "index": 1, "rest": 0.0, "pressed": -1.0},
        "brake": {"kind": "axis", "index": 1, "rest": 0.0, "pressed": 1.0},
    }
}
PRACTICE_S = 5.0
FAKE_PADS = """
const button = () => ({ pressed: false, touched: false, value: 0 });
const pad = (id, axes) => ({ id, index: 0, connected: true, mapping: "", timestamp: 0,
  axes, buttons: Array.from({ length: 12 }, button) });
window.fakePads = { wheel: pad(WHEEL, [0, 0, 0, 0]), lab: pad(LAB, [0, 0, 0]) };
window.fakeShown = ["wheel"];
Object.defineProperty(Navigator.prototype, "getGamepads", { configurable: true,
  value: () => [0, 1, 2, 3].map((i) => window.fakePads[window.fakeShown[i]] || null) });
""".replace("WHEEL", json.dumps(WHEEL)).replace("LAB", json.dumps(LAB_PEDALS))


@pytest.fixture(scope="module")
def chromium() -> Iterator[Any]:
    with chromium_driver() as driver:
        driver.execute_cdp_cmd(
            "Page.addScriptToEvaluateOnNewDocument", {"source": FAKE_PADS}
        )
        yield driver


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    folder = tmp_path_factory.mktemp("pedal-study")
    (folder / "pedals.json").write_text(json.dumps(PEDAL_MAP))
    options = ("--practice-s", str(PRACTICE_S), "--pedal-map",
               str(folder / "pedals.json"))  # fmt: skip
    with study_server(folder, *options) as running:
        yield running


class Page:
    """The study's page in Chromium, with the fake pads' axes at hand."""

    def __init__(self, driver: Any, base: str) -> None:
        from selenium.webdriver.support.ui import WebDriverWait

        self.driver, self.wait = driver, WebDriverWait(driver, 60)
        driver.get(base + "/")
        driver.execute_script("sessionStorage.clear(); localStorage.clear();")
        driver.get(base + "/")

    def element(self, element_id: str) -> Any:
        from selenium.webdriver.common.by import By

        return self.wait.until(
            lambda d: (
                d.find_element(By.ID, element_id).is_displayed()
                and d.find_element(By.ID, element_id)
            )
        )

    def text(self, element_id: str, part: str) -> str:
        from selenium.webdriver.common.by import By

        self.wait.until(lambda d: part in d.find_element(By.ID, element_id).text)
        return self.driver.find_element(By.ID, element_id).text

    def axis(self, pad: str, index: int, *values: float, every_s: float = 0.06) -> None:
        """Move an axis through `values`, one every `every_s`."""
        for value in values:
            self.driver.execute_script(
                "window.fakePads[arguments[0]].axes[arguments[1]] = arguments[2];",
                pad, index, value,
            )  # fmt: skip
            time.sleep(every_s)

    def to_practice_intro(self, pads: list[str]) -> str:
        self.driver.execute_script("window.fakeShown = arguments[0];", pads)
        self.element("consent-box").click()
        self.element("consent-go").click()
        self.element("demo-go").click()
        self.text("intro-title", "Practice")
        state = self.driver.execute_script(
            "return sessionStorage.getItem('jaxround-study');"
        )
        return json.loads(state)["participant_id"]

    def drive(self, moves: list[tuple[str, int, float, float]]) -> str:
        """Start the drive; each move holds an axis at a value for seconds."""
        self.element("intro-go").click()
        self.text("drive-status", "s left")
        for pad, index, value, seconds in moves:
            self.axis(pad, index, value, every_s=seconds)
        text = self.element("drive-end-text").text
        self.element("drive-end-go").click()
        return text

    def saved(self) -> dict:
        return json.loads(
            self.driver.execute_script("return localStorage.getItem('jaxround-pedals')")
            or "{}"
        )


def ride_steps(db: Path, participant_id: str) -> list[dict]:
    database = StudyDatabase(db)
    (ride,) = database.rows("rides", "WHERE participant_id = ?", (participant_id,))
    assert ride["status"] == "time_limit"
    return database.rows("ride_steps", "WHERE ride_id = ?", (ride["ride_id"],))


@pytest.mark.sumo
def test_a_wheel_is_set_up_on_the_page_and_drives(
    chromium: Any, study: tuple[str, Path]
) -> None:
    page = Page(chromium, study[0])
    pid = page.to_practice_intro(["wheel"])
    assert "not set up" in page.text("pedal-status", "Fake Racing Wheel")
    page.element("pedal-setup").click()
    page.text("pedal-step", "throttle")
    assert not page.element("intro-go").is_enabled()  # no drive during the set-up
    page.axis("wheel", 0, 0.15)  # the wheel turned a little: not a pedal
    page.axis("wheel", 2, 0.95, 0.4, -0.3, -1.0, -1.0, -1.0, -1.0, -0.2, 0.6, 1.0)
    page.text("pedal-step", "brake")
    page.axis("wheel", 2, -1.0, 1.0)  # the throttle again: not taken for the brake
    page.axis("wheel", 3, 0.9, 0.2, -0.7, -1.0, -1.0, -1.0, -1.0, 0.1, 1.0)
    page.text("pedal-note", "Pedals set up")
    axis = {"kind": "axis", "rest": 1.0, "pressed": -1.0}
    assert page.saved() == {
        WHEEL: {"throttle": {**axis, "index": 2}, "brake": {**axis, "index": 3}}
    }
    status = page.text("pedal-status", "set up in this browser")
    assert "Now: throttle 0%, brake 0%" in status
    assert page.element("intro-go").is_enabled()

    text = page.drive([("wheel", 2, -1.0, 2.0), ("wheel", 2, 1.0, 0.1)])
    assert "time limit" in text
    steps = ride_steps(study[1], pid)
    assert max(s["throttle"] for s in steps) == pytest.approx(1.0)
    assert max(s["brake"] for s in steps) == 0.0  # a pedal at rest is released
    assert max(s["speed_mps"] for s in steps) > 3.0

    page.text("intro-title", "Ride 1 of 2")
    page.element("pedal-reset").click()
    page.text("pedal-status", "not set up")
    assert page.saved() == {}
    assert [e for e in chromium.get_log("browser") if e["level"] == "SEVERE"] == []


@pytest.mark.sumo
def test_the_study_default_set_up_drives_a_combined_pedal_axis(
    chromium: Any, study: tuple[str, Path]
) -> None:
    page = Page(chromium, study[0])
    pid = page.to_practice_intro(["lab"])
    assert "set up by the study" in page.text("pedal-status", "Lab Pedals")
    reset = chromium.find_element("id", "pedal-reset")
    assert not reset.is_displayed()  # nothing set up in this browser
    moves = [("lab", 1, -1.0, 1.5), ("lab", 1, 1.0, 0.8), ("lab", 1, 0.0, 0.1)]
    assert "time limit" in page.drive(moves)
    steps = ride_steps(study[1], pid)
    assert max(s["throttle"] for s in steps) == pytest.approx(1.0)
    assert max(s["brake"] for s in steps) == pytest.approx(1.0)
    braking = [s for s in steps if s["brake"] > 0]
    assert all(s["throttle"] == 0 for s in braking)  # one axis: never both


def test_a_pedal_map_is_checked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "pedals.json"
    path.write_text(json.dumps(PEDAL_MAP))
    assert read_pedal_map(path) == PEDAL_MAP
    bad = {"Pad": {"throttle": {"kind": "axis", "index": 2, "rest": 1.0,
                                "pressed": 0.95}}}  # fmt: skip
    for data, message in (
        (bad, "'Pad'.throttle: Value error, rest 1.0 and pressed 0.95 are closer"),
        ({"Pad": {}}, "neither a throttle nor a brake"),
        ({"Pad": {"clutch": {}}}, "'Pad'.clutch: Extra inputs are not permitted"),
        ([], "expected an object of gamepad ids"),
    ):
        path.write_text(json.dumps(data))
        with pytest.raises(ValueError, match=message):
            read_pedal_map(path)
    with pytest.raises(ValueError, match="No such file"):
        read_pedal_map(tmp_path / "none.json")
    policy = write_standin_policy(tmp_path, load_config("milan"))
    argv = ["study", "serve", "--policy", str(policy), "--pedal-map", str(path),
            "--db", str(tmp_path / "s.sqlite")]  # fmt: skip
    assert main(argv) == 2  # refused before the server starts
    assert "expected an object of gamepad ids" in capsys.readouterr().err


#: Press-and-release traces of one axis for the set-up's detection, sampled
#: every 20 ms (each value held 0.2 s, the last one 0.8 s): what it finds.
CAUGHT = [
    ("rests at +1", [1, 0.3, -1, -1, 0.2, 1], {"rest": 1, "pressed": -1}),
    ("rests at -1", [-1, 0, 1, 1, 0, -1], {"rest": -1, "pressed": 1}),
    ("pressed and held", [1, 0.3, -1, -1], None),
    ("read as 0 until moved", [0, 0.9, -1, -1, 0.2, 1], {"rest": 1, "pressed": -1}),
    ("read as 0, held", [0, 0.9, -0.5, -1, -1], None),
    ("read as 0, caught mid-press", [0, -0.5, -1, 0.1, 1], {"rest": 1, "pressed": -1}),
    ("combined axis, throttle", [0, -0.5, -1, -0.4, 0], {"rest": 0, "pressed": -1}),
    ("a small move", [0, 0.2, 0.3, 0], None),
]
DETECT = """
const [cases, done] = arguments;
import("/static/pedals.js").then(({ PedalCatcher }) => done(cases.map(([, values]) => {
  const catcher = new PedalCatcher();
  let t = 0, caught = null;
  values.forEach((v, i) => {
    for (let k = 0; k < (i === values.length - 1 ? 40 : 10); k += 1, t += 20) {
      const axes = [0.1, v];  // axis 0: a wheel held still
      caught = caught || catcher.sample([{ id: "P", axes, buttons: [] }], t);
    }
  });
  return caught && caught.input;
})));
"""


@pytest.mark.sumo
def test_the_set_up_finds_a_press_and_release_of_any_pedal_axis(
    chromium: Any, study: tuple[str, Path]
) -> None:
    chromium.get(study[0] + "/")
    found = chromium.execute_async_script(DETECT, CAUGHT)
    names = [name for name, _, _ in CAUGHT]
    expected = [e and {"kind": "axis", "index": 1, **e} for _, _, e in CAUGHT]
    assert dict(zip(names, found)) == dict(zip(names, expected))
