"""Killing the study server mid-study loses no answer already given.

`jaxround study serve` runs as a subprocess; a participant answers, a ride
is under way, the server gets SIGKILL (no shutdown code runs). The answers
are in the database, the ride's process ends by itself, and a server
started again on the same file lets the participant go on.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from websockets.sync.client import connect

from jaxround.scenario.config import load_config
from jaxround.study.load import free_port, write_standin_policy
from jaxround.study.storage import StudyDatabase

pytestmark = pytest.mark.sumo


def post(base: str, path: str, body: dict) -> tuple[int, Any]:
    request = urllib.request.Request(
        base + path,
        data=json.dumps(body).encode(),
        method="POST",
        headers={"Content-Type": "application/json"},
    )
    try:
        with urllib.request.urlopen(request, timeout=30) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def start_server(policy: Path, db: Path, port: int) -> subprocess.Popen:
    command = [sys.executable, "-m", "jaxround", "study", "serve", "--policy",
               str(policy), "--db", str(db), "--port", str(port),
               "--practice-s", "60"]  # fmt: skip
    server = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    banner = server.stdout.readline()  # printed before uvicorn starts
    assert f"http://127.0.0.1:{port}/" in banner
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/study") as r:
                if r.status == 200:
                    return server
        except OSError:
            time.sleep(0.1)
    server.kill()
    raise AssertionError("the server did not start")


def children(pid: int) -> set[int]:
    """Processes whose parent is `pid` (from /proc)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.add(int(entry.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1]
    except OSError:
        return False
    return state.split()[0] != "Z"


def drove_both_rides(db: Path, pid: str) -> None:
    """The participant's two rides, stored as having run their course (the
    answers come after them; driving them is `test_study_browser`'s part)."""
    for kind in ("first", "second"):
        StudyDatabase(db).save_ride({"ride": {
            "ride_id": f"{pid}-{kind}", "participant_id": pid, "kind": kind,
            "status": "time_limit"}, "steps": [], "events": []})  # fmt: skip


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_killing_the_server_loses_no_answer(tmp_path: Path) -> None:
    policy = write_standin_policy(tmp_path, load_config("milan"))
    db = tmp_path / "study.sqlite"
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    server = start_server(policy, db, port)
    try:
        status, body = post(base, "/api/participants", {"consent": True})
        pid = body["participant_id"]
        about = {"gender": "female", "age": 27, "driving_years": 8}
        assert post(base, f"/api/participants/{pid}/demographics", about)[0] == 200
        drove_both_rides(db, pid)
        for question, option in (("smoothness", 2), ("safety", 3)):
            assert post(base, f"/api/participants/{pid}/answers",
                        {"question": question, "option": option})[0] == 201  # fmt: skip
        status, ride = post(base, "/api/rides", {"participant_id": pid,
                                                 "kind": "practice"})  # fmt: skip
        url = base.replace("http", "ws") + f"/ws/rides/{ride['ride_id']}"
        with connect(f"{url}?token={ride['token']}") as ws:
            while json.loads(ws.recv(timeout=60))["type"] != "ready":
                pass
            ws.send(json.dumps({"type": "start"}))
            assert json.loads(ws.recv(timeout=10))["type"] == "frame"
            ride_processes = children(server.pid)
            assert ride_processes
            os.kill(server.pid, signal.SIGKILL)
            server.wait(timeout=30)
    finally:
        if server.poll() is None:
            server.kill()
    database = StudyDatabase(db)
    answers = database.rows("answers", "WHERE participant_id = ?", (pid,))
    assert {(a["question"], a["option_shown"]) for a in answers} == {
        ("smoothness", 2), ("safety", 3)}  # fmt: skip
    (who,) = database.rows("participants")
    assert (who["gender"], who["age"], who["driving_years"]) == ("female", 27, 8)
    deadline = time.monotonic() + 20  # the ride's process sees its pipe close
    while any(alive(p) for p in ride_processes) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(alive(p) for p in ride_processes)

    server = start_server(policy, db, port)  # the same file, continued
    try:
        assert post(base, f"/api/participants/{pid}/answers",
                    {"question": "preference", "option": 4})[0] == 201  # fmt: skip
        assert post(base, f"/api/participants/{pid}/answers",
                    {"question": "safety", "option": 0})[0] == 409  # fmt: skip
    finally:
        server.terminate()
        server.wait(timeout=30)
    answers = StudyDatabase(db).rows("answers")
    assert len(answers) == 3
