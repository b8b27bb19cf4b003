"""The study server against bad input: each gets a clear error or a clean end,
the ride's SUMO process is reaped, and nothing else is disturbed.

The server runs in this process (uvicorn in a thread) on a free port of
127.0.0.1; practice rides (SUMO without traffic) keep the rides quick.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import logging
import socket
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import uvicorn
from fastapi import FastAPI
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from jaxround.apps.cli.main import main
from jaxround.scenario.config import load_config
from jaxround.study.limits import MAX_BODY_BYTES
from jaxround.study.load import free_port, write_standin_policy
from jaxround.study.logs import LOGGER
from jaxround.study.protocol import MAX_MESSAGE_BYTES, MAX_MESSAGES_PER_S
from jaxround.study.server import create_app
from jaxround.study.settings import StudySettings
from jaxround.study.storage import StudyDatabase

pytestmark = pytest.mark.sumo

ADMIN = "admin-token-for-tests"
PRACTICE_S = 4.0
STEP_S = 0.1


@dataclass
class Server:
    base: str
    app: FastAPI
    database: StudyDatabase

    def http(self, method: str, path: str, body: Any = None,
             headers: dict | None = None) -> tuple[int, Any]:  # fmt: skip
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(
            self.base + path, data=data, method=method,
            headers={"Content-Type": "application/json", **(headers or {})},
        )  # fmt: skip
        try:
            with urllib.request.urlopen(request, timeout=30) as response:
                text = response.read().decode()
                status = response.status
        except urllib.error.HTTPError as err:
            text, status = err.read().decode(), err.code
        try:
            return status, json.loads(text)
        except json.JSONDecodeError:
            return status, text

    def participant(self) -> str:
        status, body = self.http("POST", "/api/participants", {"consent": True})
        assert status == 201
        return body["participant_id"]

    def ride(self, pid: str | None = None) -> dict[str, Any]:
        body = {"participant_id": pid or self.participant(), "kind": "practice"}
        status, ride = self.http("POST", "/api/rides", body)
        assert status == 201, ride
        return ride

    def socket(
        self, ride: dict[str, Any], token: str | None = None
    ) -> ClientConnection:
        url = self.base.replace("http", "ws") + f"/ws/rides/{ride['ride_id']}"
        return connect(f"{url}?token={token or ride['token']}", max_size=2**22)

    def stored_ride(self, ride_id: str, timeout_s: float = 20.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            rows = self.database.rows("rides", "WHERE ride_id = ?", (ride_id,))
            if rows:
                return rows[0]
            time.sleep(0.1)
        raise AssertionError(f"ride {ride_id} was not stored within {timeout_s} s")

    def process(self, ride: dict[str, Any]) -> Any:
        return self.app.state.manager.rides[ride["ride_id"]].process

    def drove_both_rides(self, pid: str) -> None:
        """Rides that ran their course, stored as the server stores them (a
        real one takes a warm-up among traffic; `test_study_browser` drives
        them)."""
        for kind in ("first", "second"):
            self.database.save_ride({"ride": {
                "ride_id": f"{pid}-{kind}", "participant_id": pid, "kind": kind,
                "status": "arrived"}, "steps": [], "events": []})  # fmt: skip


class LogLines(logging.Handler):
    """The server's log lines, as their fields."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[dict[str, Any]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(dict(getattr(record, "fields", {})))


@contextlib.contextmanager
def serving(folder: Path, **changes: Any) -> Iterator[Server]:
    """A study server of short practice rides, with `changes` to its settings."""
    cfg = load_config("milan")
    settings = StudySettings(
        policy=write_standin_policy(folder, cfg), practice_s=PRACTICE_S,
        ride_s=PRACTICE_S, warmup_s=10.0, **changes,
    )  # fmt: skip
    settings.validate(cfg)
    database = StudyDatabase(folder / "study.sqlite")
    app = create_app(settings, database, ADMIN)
    port = free_port()
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning",
                            ws_max_size=MAX_MESSAGE_BYTES)  # fmt: skip
    uv = uvicorn.Server(config)
    log = LogLines()
    LOGGER.addHandler(log)
    LOGGER.setLevel(logging.INFO)
    app.state.log = log
    thread = threading.Thread(target=uv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not uv.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert uv.started
    try:
        yield Server(f"http://127.0.0.1:{port}", app, database)
    finally:
        uv.should_exit = True
        thread.join(60)
        LOGGER.removeHandler(log)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    folder = tmp_path_factory.mktemp("study")
    with serving(folder, max_participants=2, connect_timeout_s=30.0) as running:
        yield running


@pytest.fixture(autouse=True)
def all_places_free(server: Server) -> None:
    """Each test starts when the rides of the one before are reaped."""
    deadline = time.monotonic() + 30
    while server.app.state.manager.rides:
        assert time.monotonic() < deadline, "a ride was never reaped"
        time.sleep(0.05)


def until(ws: ClientConnection, kind: str) -> dict[str, Any]:
    """Messages until one of this type."""
    while True:
        message = json.loads(ws.recv(timeout=60))
        if message["type"] == kind:
            return message


def drive_to_end(ws: ClientConnection) -> tuple[int, dict[str, Any]]:
    """Frames until the end message: (frames, end)."""
    frames = 0
    while True:
        message = json.loads(ws.recv(timeout=30))
        if message["type"] == "end":
            return frames, message
        frames += message["type"] == "frame"


def reaped(process: Any, timeout_s: float = 15.0) -> bool:
    """The ride's process has exited within `timeout_s`.

    The server joins the same process object in another thread; whichever
    thread's waitpid loses the race sees the child as still there for a
    moment, so this asks again until the deadline instead of once.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        process.join(0.2)
        if process.exitcode is not None:
            return True
    return False


def test_answers_and_forms_are_checked_before_anything_is_stored(
    server: Server,
) -> None:
    pid = server.participant()
    server.drove_both_rides(pid)
    path = f"/api/participants/{pid}/answers"
    status, body = server.http("POST", path, {"question": "speed", "option": 1})
    assert status == 422 and "question" in json.dumps(body)
    status, body = server.http("POST", path, {"question": "safety", "option": 7})
    assert status == 422 and "option" in json.dumps(body)
    status, body = server.http("POST", path, {"question": "safety", "option": 1,
                                              "comment": "x"})  # fmt: skip
    assert status == 422 and "comment" in json.dumps(body)
    status, body = server.http("POST", "/api/participants/nobody00/answers",
                               {"question": "safety", "option": 1})  # fmt: skip
    assert status == 404 and "no participant" in body["detail"]
    status, _ = server.http("POST", "/api/participants/../../etc/answers",
                            {"question": "safety", "option": 1})  # fmt: skip
    assert status in (404, 422)
    assert server.http("POST", path, {"question": "safety", "option": 1})[0] == 201
    status, body = server.http("POST", path, {"question": "safety", "option": 3})
    assert status == 409 and "answered already" in body["detail"]
    status, _ = server.http("POST", f"/api/participants/{pid}/demographics",
                            {"age": 3})  # fmt: skip
    assert status == 422
    assert server.http("POST", "/api/participants", {"consent": False})[0] == 422
    rows = server.database.rows("answers", "WHERE participant_id = ?", (pid,))
    assert [(r["question"], r["option_shown"]) for r in rows] == [("safety", 1)]


def test_the_survey_is_refused_before_both_rides_and_types_are_strict(
    server: Server,
) -> None:
    pid = server.participant()
    path = f"/api/participants/{pid}/answers"
    status, body = server.http("POST", path, {"question": "safety", "option": 2})
    assert status == 409
    assert body["detail"] == (
        "the questions come after both rides: the first ride and the second ride "
        "have not been driven to the end"
    )
    status, body = server.http("POST", f"/api/participants/{pid}/finish")
    assert status == 409 and "not answered yet" in body["detail"]
    server.drove_both_rides(pid)
    status, body = server.http("POST", path, {"question": "safety", "option": "2"})
    assert status == 422 and body["detail"][0]["loc"] == ["body", "option"]
    assert body["detail"][0]["type"] == "int_type"
    for bad in ({"question": "safety", "option": 2.0},
                {"question": "safety", "option": True}):  # fmt: skip
        assert server.http("POST", path, bad)[0] == 422
    status, _ = server.http("POST", f"/api/participants/{pid}/demographics",
                            {"age": "31"})  # fmt: skip
    assert status == 422
    assert server.database.rows("answers", "WHERE participant_id = ?", (pid,)) == []
    assert server.http("POST", path, {"question": "safety", "option": 2})[0] == 201


def post_raw(server: Server, path: str, body: bytes, chunked: bool = False,
             ) -> tuple[int, bytes]:  # fmt: skip
    host, port = server.base.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=30)
    headers = {"Content-Type": "application/json"}
    try:
        if chunked:
            pieces = (body[i : i + 1024] for i in range(0, len(body), 1024))
            conn.request("POST", path, pieces, headers, encode_chunked=True)
        else:
            conn.request("POST", path, body, headers)
        response = conn.getresponse()
        return response.status, response.read()
    except (BrokenPipeError, ConnectionResetError):  # refused before all was sent
        response = conn.getresponse()
        return response.status, response.read()
    finally:
        conn.close()


def test_a_body_over_the_limit_gets_413_and_no_error_echoes_the_input(
    server: Server,
) -> None:
    pid = server.participant()
    path = f"/api/participants/{pid}/answers"
    marker = b"ECHO-ME"
    huge = b'{"question": "' + marker * (5 * 2**20 // len(marker)) + b'", "option": 1}'
    for chunked in (False, True):
        status, reply = post_raw(server, path, huge, chunked=chunked)
        assert status == 413, (chunked, reply[:200])
        assert json.loads(reply) == {
            "detail": f"request body over {MAX_BODY_BYTES} bytes"
        }
    just_under = b'{"question": "' + marker * 400 + b'", "option": 1}'
    assert len(just_under) < MAX_BODY_BYTES
    status, reply = post_raw(server, path, just_under)
    assert status == 422 and marker not in reply and len(reply) < 600, reply
    status, reply = post_raw(server, path, b"{" + marker * 300)
    assert status == 422 and marker not in reply, reply
    assert server.database.rows("answers", "WHERE participant_id = ?", (pid,)) == []
    lines = server.app.state.log.lines
    access = [x for x in lines if x["event"] == "http" and "/answers" in x["route"]]
    assert [line["status"] for line in access[-4:]] == [413, 413, 422, 422]


def test_the_log_has_a_line_per_ride_with_its_status_and_no_personal_data(
    server: Server,
) -> None:
    pid = server.participant()
    server.http("POST", f"/api/participants/{pid}/demographics",
                {"gender": "female", "age": 47})  # fmt: skip
    driven, broken = server.ride(pid), server.ride(pid)
    with server.socket(driven) as ws, server.socket(broken) as ws_broken:
        until(ws, "ready")
        ws.send(json.dumps({"type": "start"}))
        until(ws_broken, "ready")
        ws_broken.send("{oops")
        drive_to_end(ws)
    server.stored_ride(broken["ride_id"])
    lines = server.app.state.log.lines
    mine = [line for line in lines if line.get("participant") == pid]
    ended = {line["ride"]: line["status"] for line in mine
             if line["event"] == "ride_ended"}  # fmt: skip
    assert ended == {driven["ride_id"]: "time_limit", broken["ride_id"]: "bad_message"}
    assert len([line for line in mine if line["event"] == "ride_ended"]) == 2
    events = [line["event"] for line in mine if line.get("ride") == driven["ride_id"]]
    assert events == ["ride_requested", "ride_ready", "ride_started",
                      "ride_priority", "ride_ended"]  # fmt: skip
    bad = [line for line in mine if line["event"] == "bad_message"]
    assert len(bad) == 1 and "not JSON" in bad[0]["reason"]
    assert [line["event"] for line in mine][:2] == ["participant_added",
                                                    "demographics_stored"]  # fmt: skip
    text = json.dumps(lines)
    assert "female" not in text
    assert not any({"age", "gender", "option"} & set(line) for line in lines)
    assert ADMIN not in text and "127.0.0.1" not in text
    sockets = [line for line in lines if line["event"] == "websocket"]
    assert sockets and all(line["route"] == "/ws/rides/{ride_id}" for line in sockets)


def test_a_malformed_message_ends_the_ride_with_a_named_error(server: Server) -> None:
    ride = server.ride()
    process = server.process(ride)
    with server.socket(ride) as ws:
        until(ws, "ready")
        ws.send("{oops")
        error = until(ws, "error")
        assert "not JSON" in error["message"]
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd.code == 1008
    assert server.stored_ride(ride["ride_id"])["status"] == "bad_message"
    assert reaped(process)


def test_an_oversized_message_closes_the_socket_and_reaps_the_ride(
    server: Server,
) -> None:
    ride = server.ride()
    process = server.process(ride)
    with server.socket(ride) as ws:
        until(ws, "ready")
        ws.send(json.dumps({"type": "start", "pad": "x" * 4 * MAX_MESSAGE_BYTES}))
        with pytest.raises(ConnectionClosed) as closed:
            while True:
                ws.recv(timeout=10)
    assert closed.value.rcvd.code == 1009  # message too big
    assert server.stored_ride(ride["ride_id"])["status"] == "bad_message"
    assert reaped(process)


def test_a_flood_of_messages_ends_the_ride(server: Server) -> None:
    ride = server.ride()
    process = server.process(ride)
    with server.socket(ride) as ws:
        until(ws, "ready")
        ws.send(json.dumps({"type": "start"}))
        for seq in range(3 * MAX_MESSAGES_PER_S):
            try:
                ws.send(json.dumps({"type": "input", "seq": seq, "throttle": 1.0,
                                    "brake": 0.0}))  # fmt: skip
            except ConnectionClosed as closed:
                # The server may close before the flood is all sent; what it
                # sent before closing is still read below.
                assert closed.rcvd is not None and closed.rcvd.code == 1008
                break
        error = until(ws, "error")
    assert f"more than {MAX_MESSAGES_PER_S} messages a second" in error["message"]
    assert server.stored_ride(ride["ride_id"])["status"] == "bad_message"
    assert reaped(process)


def test_a_second_connection_is_refused_and_the_first_rides_on(server: Server) -> None:
    ride = server.ride()
    with server.socket(ride) as first:
        until(first, "ready")
        first.send(json.dumps({"type": "start"}))
        with server.socket(ride) as second:
            error = until(second, "error")
            assert "another window" in error["message"]
            with pytest.raises(ConnectionClosed) as closed:
                second.recv(timeout=10)
            assert closed.value.rcvd.code == 4409
        frames, end = drive_to_end(first)
    assert end["status"] == "time_limit"
    assert frames >= PRACTICE_S / STEP_S - 2
    stored = server.stored_ride(ride["ride_id"])
    assert (stored["status"], stored["steps"]) == ("time_limit", PRACTICE_S / STEP_S)


def test_a_browser_that_disappears_ends_its_ride_only(server: Server) -> None:
    gone, staying = server.ride(), server.ride()
    gone_process = server.process(gone)
    with server.socket(staying) as ws_staying, server.socket(gone) as ws_gone:
        for ws in (ws_gone, ws_staying):
            until(ws, "ready")
            ws.send(json.dumps({"type": "start"}))
        until(ws_gone, "frame")
        ws_gone.socket.shutdown(socket.SHUT_RDWR)  # no closing handshake
        ws_gone.socket.close()
        assert server.stored_ride(gone["ride_id"])["status"] == "abandoned"
        assert reaped(gone_process)
        frames, end = drive_to_end(ws_staying)
    assert end["status"] == "time_limit"
    stored = server.stored_ride(staying["ride_id"])
    assert stored["steps"] == PRACTICE_S / STEP_S and stored["late_steps"] == 0


def test_the_next_participant_gets_the_busy_message(server: Server) -> None:
    taken = [server.ride(), server.ride()]
    status, body = server.http("POST", "/api/rides",
                               {"participant_id": server.participant(),
                                "kind": "practice"})  # fmt: skip
    assert status == 503 and body["busy"]
    assert "All 2 driving places are taken" in body["detail"]
    assert server.http("GET", "/api/study")[1]["places_free"] == 0
    for ride in taken:  # leaving frees the places
        with server.socket(ride) as ws:
            until(ws, "ready")
        server.stored_ride(ride["ride_id"])
    deadline = time.monotonic() + 20
    while server.http("GET", "/api/study")[1]["places_free"] < 2:
        assert time.monotonic() < deadline
        time.sleep(0.1)


def test_unknown_rides_and_admin_pages_without_the_token_are_refused(
    server: Server,
) -> None:
    with server.socket({"ride_id": "no-such-ride", "token": "x"}) as ws:
        assert "no ride" in until(ws, "error")["message"]
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd.code == 4404
    assert server.http("GET", "/admin/report")[0] == 401
    assert server.http("GET", "/admin/report", headers={
        "Authorization": "Bearer wrong"})[0] == 401  # fmt: skip
    bearer = {"Authorization": f"Bearer {ADMIN}"}
    status, report = server.http("GET", "/admin/report", headers=bearer)
    assert status == 200 and set(report["tables"]) == {"smoothness", "safety",
                                                        "preference"}  # fmt: skip
    status, text = server.http("GET", f"/admin/export/answers.csv?token={ADMIN}")
    assert status == 200 and text.startswith("participant_id,question")
    assert (
        server.http("GET", f"/admin/export/sqlite_master.csv?token={ADMIN}")[0] == 404
    )


def test_the_page_and_its_scripts_come_from_the_server(server: Server) -> None:
    status, page = server.http("GET", "/")
    assert status == 200 and "/static/app.js" in page
    status, three = server.http("GET", "/static/vendor/three/three.module.js")
    assert status == 200 and "three.core.js" in three
    assert server.http("GET", "/static/../server.py")[0] == 404
    status, roads = server.http("GET", "/api/roads")
    lanes = {lane["id"] for lane in roads["lanes"]}
    assert {"in_0_0", "ring_0_0", "out_3_0"} <= lanes


HOLD_S = 3.0


@pytest.fixture(scope="module")
def one_place(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    folder = tmp_path_factory.mktemp("one-place")
    with serving(folder, max_participants=1, connect_timeout_s=HOLD_S) as running:
        yield running


def test_a_ride_never_connected_holds_its_place_until_the_timeout(
    one_place: Server,
) -> None:
    server = one_place
    held = server.ride()
    asked = time.monotonic()
    process = server.process(held)
    waiting = {"participant_id": server.participant(), "kind": "practice"}
    busy = []
    while time.monotonic() - asked < HOLD_S:  # the ride cannot end before this
        busy.append(server.http("POST", "/api/rides", waiting))
        time.sleep(0.5)
    assert len(busy) >= 3
    assert all(status == 503 and "driving place is taken" in body["detail"]
               for status, body in busy), busy  # fmt: skip
    stored = server.stored_ride(held["ride_id"])
    assert time.monotonic() - asked >= HOLD_S
    assert (stored["status"], stored["steps"]) == ("not_started", 0)
    assert stored["error"] == "the browser did not start it"
    assert reaped(process) and process.exitcode == 0
    deadline = time.monotonic() + 15
    while server.app.state.manager.rides:
        assert time.monotonic() < deadline, "the place was not freed"
        time.sleep(0.05)
    ride = server.ride(waiting["participant_id"])  # the next participant drives
    with server.socket(ride) as ws:
        until(ws, "ready")
        ws.send(json.dumps({"type": "start"}))
        frames, end = drive_to_end(ws)
    assert end["status"] == "time_limit" and frames > 0


def test_serve_states_the_hold_and_refuses_a_timeout_below_the_countdown(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        main(["study", "serve", "--help"])
    assert "--connect-timeout-s" in capsys.readouterr().out
    policy = write_standin_policy(tmp_path, load_config("milan"))
    argv = ["study", "serve", "--policy", str(policy), "--db",
            str(tmp_path / "s.sqlite"), "--connect-timeout-s", "1"]  # fmt: skip
    assert main(argv) == 2
    assert "connect timeout: 1.0 s, expected at least 3.0 s" in capsys.readouterr().err
    assert not (tmp_path / "s.sqlite").exists()  # refused before anything
