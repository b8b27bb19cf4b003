"""The study's questionnaire, database and report, on fixture databases.

The p-values are checked against the binomial sums done by hand:
smoothness 5 of 9 favour 80%: P(X >= 5) = (126 + 84 + 36 + 9 + 1) / 512;
safety 8 of 10: (45 + 10 + 1) / 1024; preference 7 of 10:
(120 + 45 + 10 + 1) / 1024.
"""

from __future__ import annotations

import csv
import json
import sqlite3
import tomllib
from pathlib import Path

import pytest

from jaxround.apps.cli.main import main
from jaxround.scenario.config import load_config
from jaxround.study.protocol import MAX_MESSAGE_BYTES, BadMessageError, parse_message
from jaxround.study.questions import PAPER_COUNTS, paper_option, worded_questions
from jaxround.study.report import (
    build_report,
    sign_test,
    tables_markdown,
    telemetry_markdown,
)
from jaxround.study.settings import StudySettings
from jaxround.study.storage import (
    COLUMNS,
    AnswerExistsError,
    NotYetError,
    StudyDatabase,
    UnknownParticipantError,
)

ROOT = Path(__file__).resolve().parents[2]
QUESTIONS = ("smoothness", "safety", "preference")


def drive_both_rides(database: StudyDatabase, pid: str) -> None:
    """Store a first and a second ride that ran their course."""
    for kind, status in (("first", "arrived"), ("second", "time_limit")):
        record = ride(f"{pid}-{kind}", pid, 0.2, status)
        record["ride"]["kind"] = kind
        database.save_ride(record)


def paper_database(path: Path) -> StudyDatabase:
    """Ten unblinded participants who answer exactly as the paper's ten did."""
    database = StudyDatabase(path)
    for i in range(10):
        pid, _ = database.add_participant(blind=False)
        drive_both_rides(database, pid)
        for question in QUESTIONS:
            counts = PAPER_COUNTS[question]
            # the i-th answer in the order of the paper's options
            option = next(o for o in range(5) if i < sum(counts[: o + 1]))
            database.add_answer(pid, question, option)
        database.finish(pid)
    return database


def ride(ride_id: str, pid: str, share: float, status: str, **values: object) -> dict:
    row = {"ride_id": ride_id, "participant_id": pid, "kind": "first", "share": share,
           "status": status, **values}  # fmt: skip
    return {"ride": row, "steps": [], "events": []}


def test_the_report_gives_the_papers_counts_and_hand_checked_p_values(
    tmp_path: Path,
) -> None:
    report = build_report(paper_database(tmp_path / "study.sqlite"))
    assert report["participants"] == report["completed"] == 10
    assert report["orders"] == {"20-80": 5, "80-20": 5}
    for question in QUESTIONS:
        table = report["tables"][question]
        assert table["counts"] == list(PAPER_COUNTS[question])
        assert table["sign_test"] == table["paper_sign_test"]
    tests = {q: report["tables"][q]["sign_test"] for q in QUESTIONS}
    assert (tests["smoothness"]["k"], tests["smoothness"]["n"]) == (5, 9)
    assert tests["smoothness"]["p_one_sided"] == 256 / 512
    assert tests["smoothness"]["p_two_sided"] == 1.0
    assert tests["safety"]["p_one_sided"] == 56 / 1024
    assert tests["safety"]["p_two_sided"] == 112 / 1024
    assert tests["preference"]["p_one_sided"] == 176 / 1024
    assert tests["preference"]["p_two_sided"] == 352 / 1024
    assert sign_test(0, 0)["p_one_sided"] is None


def test_blind_answers_are_mapped_back_by_the_ride_order(tmp_path: Path) -> None:
    database = StudyDatabase(tmp_path / "blind.sqlite")
    first, order_1 = database.add_participant(blind=True)
    second, order_2 = database.add_participant(blind=True)
    assert (order_1, order_2) == ("20-80", "80-20")  # counterbalanced
    for pid in (first, second):  # "ride A was definitely smoother than ride B"
        drive_both_rides(database, pid)
        database.add_answer(pid, "smoothness", 0)
        database.add_answer(pid, "safety", 4)
        database.add_answer(pid, "preference", 4 if pid == second else 1)
        database.finish(pid)
    table = build_report(database)["tables"]
    assert table["smoothness"]["counts"] == [1, 0, 0, 1, 0]  # A was 20%, then 80%
    assert table["preference"]["counts"] == [0, 1, 0, 0, 1]
    assert [paper_option(o, "80-20", True) for o in range(5)] == [3, 2, 1, 0, 4]
    assert [paper_option(o, "80-20", False) for o in range(5)] == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match="option 5"):
        paper_option(5, "20-80", True)


def test_answers_wait_for_both_rides_and_the_survey_for_every_answer(
    tmp_path: Path,
) -> None:
    database = StudyDatabase(tmp_path / "study.sqlite")
    pid, _ = database.add_participant(blind=False)
    with pytest.raises(NotYetError, match="the first ride and the second ride have"):
        database.add_answer(pid, "safety", 2)
    database.save_ride(ride("r1", pid, 0.2, "arrived"))
    second = ride("r2", pid, 0.8, "abandoned")
    second["ride"]["kind"] = "second"
    database.save_ride(second)  # cut short: not driven to the end
    with pytest.raises(NotYetError, match="the second ride has not been driven"):
        database.add_answer(pid, "safety", 2)
    second = ride("r3", pid, 0.8, "time_limit")
    second["ride"]["kind"] = "second"
    database.save_ride(second)
    database.add_answer(pid, "safety", 2)
    with pytest.raises(NotYetError, match=r"\['smoothness', 'preference'\]"):
        database.finish(pid)
    assert database.participant(pid)["finished_utc"] is None  # rolled back
    assert [a["question"] for a in database.rows("answers")] == ["safety"]


def insert_answer_directly(db: Path, pid: str, question: str, option: int) -> None:
    """An answer written past the server's checks (as an older server stored
    them): the report must still leave it out."""
    with sqlite3.connect(db) as conn:
        conn.execute("INSERT INTO answers VALUES (?, ?, ?, ?, 'x')",
                     (pid, question, option, option))  # fmt: skip


def test_the_report_counts_completed_participants_only(tmp_path: Path) -> None:
    db = tmp_path / "study.sqlite"
    database = StudyDatabase(db)
    # Four completed participants; safety answers 3, 3, 2, 1.
    for safety in (3, 3, 2, 1):
        pid, _ = database.add_participant(blind=False)
        drive_both_rides(database, pid)
        for question in QUESTIONS:
            database.add_answer(pid, question, safety if question == "safety" else 4)
        database.finish(pid)
    # Non-finishers who all "answered" that 80% was partially safer.
    consent_only, _ = database.add_participant(blind=False)
    practice, _ = database.add_participant(blind=False)
    practice_ride = ride("p", practice, 0.0, "arrived")
    practice_ride["ride"]["kind"] = "practice"
    database.save_ride(practice_ride)
    one_ride, _ = database.add_participant(blind=False)
    database.save_ride(ride("o", one_ride, 0.2, "arrived"))
    unfinished, _ = database.add_participant(blind=False)
    drive_both_rides(database, unfinished)
    database.add_answer(unfinished, "safety", 2)
    for pid in (consent_only, practice, one_ride):
        insert_answer_directly(db, pid, "safety", 2)
    report = build_report(database)
    assert (report["participants"], report["completed"]) == (8, 4)
    assert report["by_status"] == {
        "consent_only": 1,
        "practice_driven": 1,
        "first_ride_driven": 1,
        "both_rides_driven": 1,
        "completed": 4,
    }
    safety = report["tables"]["safety"]
    assert safety["counts"] == [0, 1, 1, 2, 0]
    # 3 of 4 favour 80%: P(X >= 3) = (4 + 1) / 16, P(X <= 3) = 15 / 16
    test = safety["sign_test"]
    assert (test["k"], test["n"]) == (3, 4)
    assert test["p_one_sided"] == 5 / 16 and test["p_two_sided"] == 10 / 16
    assert report["tables"]["smoothness"]["counts"] == [0, 0, 0, 0, 4]
    assert report["tables"]["smoothness"]["sign_test"]["p_one_sided"] is None
    text = tables_markdown(report)
    assert (
        "Completed participants (both rides driven to the end, three answers): 4"
        in text
    )
    assert ("1 consent only, 1 practice driven, 1 first ride driven, "
            "1 both rides driven (8 participants in all)") in text  # fmt: skip


def test_telemetry_counts_completed_rides_per_scenario(tmp_path: Path) -> None:
    database = StudyDatabase(tmp_path / "rides.sqlite")
    pid, _ = database.add_participant(blind=False)
    database.save_ride(ride("a", pid, 0.2, "arrived", min_ttc_s=1.0, hard_brakings=1,
                            crossing_time_s=20.0, collisions=1))  # fmt: skip
    database.save_ride(ride("b", pid, 0.2, "arrived", min_ttc_s=3.0, hard_brakings=2,
                            crossing_time_s=30.0, collisions=0))  # fmt: skip
    database.save_ride(ride("c", pid, 0.2, "abandoned", min_ttc_s=0.1))
    database.save_ride(ride("d", pid, 0.8, "time_limit", hard_brakings=0))
    telemetry = build_report(database)["telemetry"]
    low, high = telemetry["20%"], telemetry["80%"]
    assert (low["rides"], low["arrived"], low["collisions"]) == (2, 2, 1)
    assert low["min_ttc_s_median"] == 2.0 and low["min_ttc_s_lowest"] == 1.0
    assert low["hard_brakings_mean"] == 1.5
    assert low["crossing_time_s_mean"] == 25.0
    assert (high["rides"], high["arrived"], high["min_ttc_s_median"]) == (1, 0, None)


def test_telemetry_counts_the_egos_lane_changes_on_two_lane_roads(
    tmp_path: Path,
) -> None:
    database = StudyDatabase(tmp_path / "lanes.sqlite")
    pid, _ = database.add_participant(blind=False)
    asked = {"kind": "lane_change", "other": None,
             "detail": "left to in_0_1, asked for"}  # fmt: skip
    route = {"kind": "lane_change", "other": None,
             "detail": "right to ring_2_0, for the route"}  # fmt: skip
    crash = {"kind": "collision", "other": "hv", "detail": "collision: ..."}
    record = ride("a", pid, 0.2, "arrived")
    events = (asked, asked, route, crash)
    record["events"] = [{"time_s": t, **e} for t, e in enumerate(events)]
    database.save_ride(record)
    database.save_ride(ride("b", pid, 0.2, "arrived"))  # kept its lanes
    report = build_report(database)
    low = report["telemetry"]["20%"]
    assert (low["lane_changes_asked_mean"], low["lane_changes_route_mean"]) == (
        1.0,
        0.5,
    )
    table = telemetry_markdown(report)
    assert "asked / for the route" in table and "| 1.00 / 0.50 |" in table
    one_lane = StudyDatabase(tmp_path / "one_lane.sqlite")
    pid, _ = one_lane.add_participant(blind=False)
    one_lane.save_ride(ride("c", pid, 0.2, "arrived"))
    assert "lane changes" not in telemetry_markdown(build_report(one_lane))


def test_report_and_export_commands_write_files_and_refuse_to_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = tmp_path / "study.sqlite"
    paper_database(db)
    out = tmp_path / "report"
    assert main(["study", "report", "--db", str(db), "--out", str(out)]) == 0
    assert "Table 6" in capsys.readouterr().out
    rows = list(csv.DictReader((out / "tables.csv").open()))
    assert len(rows) == 15
    assert [int(r["count"]) for r in rows if r["question"] == "safety"] == [
        0,
        2,
        2,
        6,
        0,
    ]
    assert json.loads((out / "report.json").read_text())["participants"] == 10
    assert (out / "telemetry.png").stat().st_size > 0
    assert main(["study", "report", "--db", str(db), "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    export = tmp_path / "csv"
    assert main(["study", "export", "--db", str(db), "--out", str(export)]) == 0
    answers = list(csv.DictReader((export / "answers.csv").open()))
    assert len(answers) == 30 and set(answers[0]) == set(COLUMNS["answers"])
    missing = tmp_path / "none.sqlite"
    assert main(["study", "report", "--db", str(missing), "--out", str(out)]) == 2
    assert not missing.exists()  # nothing created


def test_the_database_refuses_foreign_files_and_keeps_first_answers(
    tmp_path: Path,
) -> None:
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as conn:
        conn.execute("CREATE TABLE t (x)")
    with pytest.raises(ValueError, match="not a jaxround study database"):
        StudyDatabase(other)
    text = tmp_path / "notes.sqlite"
    text.write_text("not a database, but someone's notes")
    with pytest.raises(ValueError, match="not a SQLite database"):
        StudyDatabase(text)
    assert text.read_text() == "not a database, but someone's notes"
    database = StudyDatabase(tmp_path / "study.sqlite")
    pid, _ = database.add_participant(blind=False)
    drive_both_rides(database, pid)
    database.add_answer(pid, "safety", 3)
    with pytest.raises(AnswerExistsError):
        database.add_answer(pid, "safety", 0)
    assert database.rows("answers")[0]["option_shown"] == 3
    with pytest.raises(UnknownParticipantError):
        database.add_answer("nobody-at-all", "safety", 0)
    with pytest.raises(ValueError, match="question 'speed'"):
        database.add_answer(pid, "speed", 0)
    with sqlite3.connect(tmp_path / "study.sqlite") as conn:
        for table, columns in COLUMNS.items():
            info = conn.execute(f"PRAGMA table_info({table})").fetchall()
            assert tuple(row[1] for row in info) == columns
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_the_questions_are_worded_as_in_the_paper() -> None:
    plain = {q["id"]: q for q in worded_questions(blind=False)}
    assert plain["smoothness"]["options"][0] == (
        "Traffic in the scenario with 20% of AVs was definitely smoother than in "
        "the scenario with 80% AVs"
    )
    assert plain["safety"]["options"][2] == (
        "Traffic in the scenario with 20% of AVs was partially less safe than in "
        "the scenario with 80% AVs"
    )
    assert plain["preference"]["options"][3] == (
        "I definitely preferred the scenario with 80% AVs with respect to the "
        "scenario with 20% AVs"
    )
    assert plain["smoothness"]["options"][4] == "I did not perceive differences"
    assert plain["preference"]["heading"] == (
        "Globally, which of the two scenarios did you prefer?"
    )
    blind = {q["id"]: q for q in worded_questions(blind=True)}
    assert blind["safety"]["options"][1] == (
        "Traffic in ride A was partially safer than in ride B"
    )
    assert not any("%" in o for q in blind.values() for o in q["options"])


@pytest.mark.parametrize(
    ("text", "complaint"),
    [
        ("{not json", "not JSON"),
        ("[1, 2]", "JSON object"),
        ('{"type": "honk"}', "type 'honk'"),
        ('{"type": "start", "x": 1}', "unknown fields ['x']"),
        ('{"type": "input", "seq": 1, "throttle": 0.5}', "missing fields ['brake']"),
        ('{"type": "input", "seq": -1, "throttle": 0, "brake": 0}', "input.seq"),
        ('{"type": "input", "seq": true, "throttle": 0, "brake": 0}', "input.seq"),
        ('{"type": "input", "seq": 1, "throttle": 1.5, "brake": 0}', "input.throttle"),
        ('{"type": "input", "seq": 1, "throttle": NaN, "brake": 0}', "input.throttle"),
        ('{"type": "input", "seq": 1, "throttle": "1", "brake": 0}', "input.throttle"),
        ('{"type": "latency", "seq": 1, "ms": 1e9}', "latency.ms"),
        ('{"type": "lane", "direction": "up"}', "lane.direction: 'up'"),
        ('{"type": "lane"}', "missing fields ['direction']"),
        ('{"type": "start"}' + " " * MAX_MESSAGE_BYTES, "bytes"),
    ],
)
def test_bad_browser_messages_are_named(text: str, complaint: str) -> None:
    with pytest.raises(BadMessageError, match=complaint.replace("[", r"\[")):
        parse_message(text)


def test_good_browser_messages_pass() -> None:
    message = parse_message('{"type": "input", "seq": 4, "throttle": 1, "brake": 0.25}')
    assert message == {"type": "input", "seq": 4, "throttle": 1, "brake": 0.25}
    assert parse_message('{"type": "start"}') == {"type": "start"}
    lane = '{"type": "lane", "direction": "left"}'
    assert parse_message(lane) == {"type": "lane", "direction": "left"}


def test_the_pages_are_package_data_and_load_nothing_from_elsewhere() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    patterns = project["tool"]["setuptools"]["package-data"]["jaxround.study"]
    static = ROOT / "jaxround" / "study"
    files = [p.relative_to(static).as_posix()
             for p in (static / "static").rglob("*") if p.is_file()]  # fmt: skip
    assert "static/vendor/three/three.module.js" in files
    assert "static/vendor/three/LICENSE" in files
    packaged = {
        p.relative_to(static).as_posix()
        for pattern in patterns
        for p in static.glob(pattern)
    }  # setuptools' globs: "*" stays within a folder
    assert set(files) <= packaged, set(files) - packaged
    for name in ("index.html", "app.js", "drive.js", "scene.js", "hud.js"):
        text = (static / "static" / name).read_text()
        assert "http://" not in text and "https://" not in text, name


def test_the_consent_pages_estimate_follows_the_settings() -> None:
    cfg = load_config("milan")
    settings = StudySettings(policy=Path("policy.npz"))
    # practice 90 s, two rides of 180 s with 30 s of warm-up each, 180 s of forms
    assert settings.estimated_minutes() == 12  # 690 s
    shorter = settings.replace(ride_s=60.0, practice_s=30.0)
    assert shorter.estimated_minutes() == 7  # 390 s
    for name in ("passes", "practice_passes"):
        with pytest.raises(ValueError, match=f"{name}: 0, expected 1-50"):
            settings.replace(**{name: 0}).validate(cfg)
