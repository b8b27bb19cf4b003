"""Helpers of the browser tests: Debian's chromium through chromedriver, and
`jaxround study serve` as a subprocess on a free port of 127.0.0.1.

Without a browser a test is skipped, unless ``JAXROUND_REQUIRE_BROWSER=1``
(set by ``.ci/run``), under which it fails.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from jaxround.scenario.config import load_config
from jaxround.study.load import free_port, write_standin_policy

BROWSERS = ("chromium", "chromium-browser", "google-chrome")


def browser_paths() -> tuple[str, str] | None:
    browser = next((p for p in map(shutil.which, BROWSERS) if p), None)
    driver = shutil.which("chromedriver")
    return (browser, driver) if browser and driver else None


@contextlib.contextmanager
def chromium_driver() -> Iterator[object]:
    """A headless Chromium under Selenium (skips or fails without one)."""
    paths = browser_paths()
    if paths is None:
        message = "no chromium and chromedriver on PATH (apt-get install chromium " \
                  "chromium-driver)"  # fmt: skip
        if os.environ.get("JAXROUND_REQUIRE_BROWSER") == "1":
            pytest.fail(message + "; JAXROUND_REQUIRE_BROWSER=1 asks for the browser")
        pytest.skip(message)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = paths[0]
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                 "--window-size=1280,720", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader"):  # fmt: skip
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(paths[1]), options=options)
    try:
        yield driver
    finally:
        driver.quit()


@contextlib.contextmanager
def study_server(folder: Path, *options: str) -> Iterator[tuple[str, Path]]:
    """`jaxround study serve` with a stand-in policy and `options`: (base, db)."""
    policy = write_standin_policy(folder, load_config("milan"))
    db, port = folder / "study.sqlite", free_port()
    command = [sys.executable, "-m", "jaxround", "study", "serve", "--policy",
               str(policy), "--db", str(db), "--port", str(port),
               *options]  # fmt: skip
    server = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                with urllib.request.urlopen(f"{base}/api/study", timeout=5):
                    break
            except OSError:
                assert server.poll() is None and time.monotonic() < deadline
                time.sleep(0.2)
        yield base, db
    finally:
        server.terminate()
        server.wait(timeout=30)
