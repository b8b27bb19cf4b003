"""The study's SQLite database: one transaction per answer and per ride.

The file is in WAL mode with ``synchronous=FULL``: an answer is on disk when
the server replies, and a server killed at any moment loses none. Every
statement is parameterised; table and column names come from this module.

Schema (``jaxround-study/1``; times are UTC, ISO 8601):

``participants``: one row per participant.
    participant_id TEXT (random, 16 characters; no names are stored),
    created_utc, ride_order ('20-80' or '80-20': AV share of ride 1 and 2),
    blind (1: rides shown as A and B), gender, age, driving_years (optional,
    as the paper reports them), finished_utc (survey done).
``answers``: one row per participant and question.
    participant_id, question ('smoothness', 'safety', 'preference'),
    option_shown (0-4 as on the page), option_paper (0-4 in the paper's
    table: 0-1 favour 20%, 2-3 favour 80%, 4 neither), answered_utc.
``rides``: one row per ride that ended (also abandoned or failed ones).
    ride_id, participant_id, kind ('practice', 'first', 'second'), share
    (AV share; 0 in practice), label (as shown), seed, warmup_s, step_s,
    status ('arrived', 'time_limit', 'abandoned', 'bad_message',
    'not_started', 'error'), error, started_utc, ended_utc, steps,
    ego_entered_s (simulated time the ego entered), crossing_time_s (entry
    to exit; NULL if it did not leave), min_gap_m, min_ttc_s (to the
    vehicle ahead; NULL if never closing), hard_brakings, collisions,
    late_steps (steps started over a step late), frames_dropped,
    delay_median_ms, delay_p99_ms (server delay per step: step start to the
    frame handed to the WebSocket), compute_median_ms, compute_p99_ms (SUMO
    step + policy + frame in the ride's process), latency_median_ms,
    latency_samples (browser: input to the frame drawn that reflects it).
``ride_steps``: one row per ride step.
    ride_id, step, time_s (simulated), on_road (ego in the network), x_m,
    y_m, speed_mps, accel_mps2, throttle, brake (pedals 0-1), gap_m,
    ttc_s, sumo_ms, policy_ms, frame_ms, delay_ms.
``ride_events``: collisions, hard brakings and the ego's lane changes.
    ride_id, time_s, kind ('collision', 'hard_braking', 'lane_change'),
    other (class of the other vehicle in a collision: 'hv' or 'av'), detail.
``browser_latency``: ride_id, seq (input number), latency_ms.
"""

from __future__ import annotations

import contextlib
import csv
import secrets
import sqlite3
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from jaxround.study.questions import ORDERS, QUESTION_IDS, paper_option

SCHEMA_VERSION = "jaxround-study/1"

#: Columns of each table, in order (the CSV export writes them so).
COLUMNS: dict[str, tuple[str, ...]] = {
    table: tuple(names.split())
    for table, names in {
        "participants": "participant_id created_utc ride_order blind gender age "
        "driving_years finished_utc",
        "answers": "participant_id question option_shown option_paper answered_utc",
        "rides": "ride_id participant_id kind share label seed warmup_s step_s "
        "status error started_utc ended_utc steps ego_entered_s crossing_time_s "
        "min_gap_m min_ttc_s hard_brakings collisions late_steps frames_dropped "
        "delay_median_ms delay_p99_ms compute_median_ms compute_p99_ms "
        "latency_median_ms latency_samples",
        "ride_steps": "ride_id step time_s on_road x_m y_m speed_mps accel_mps2 "
        "throttle brake gap_m ttc_s sumo_ms policy_ms frame_ms delay_ms",
        "ride_events": "ride_id time_s kind other detail",
        "browser_latency": "ride_id seq latency_ms",
    }.items()
}

_DDL = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE participants (
    participant_id TEXT PRIMARY KEY, created_utc TEXT NOT NULL,
    ride_order TEXT NOT NULL CHECK (ride_order IN ('20-80', '80-20')),
    blind INTEGER NOT NULL, gender TEXT, age INTEGER, driving_years INTEGER,
    finished_utc TEXT);
CREATE TABLE answers (
    participant_id TEXT NOT NULL REFERENCES participants(participant_id),
    question TEXT NOT NULL, option_shown INTEGER NOT NULL,
    option_paper INTEGER NOT NULL, answered_utc TEXT NOT NULL,
    PRIMARY KEY (participant_id, question));
CREATE TABLE rides (
    ride_id TEXT PRIMARY KEY,
    participant_id TEXT NOT NULL REFERENCES participants(participant_id),
    kind TEXT NOT NULL, share REAL, label TEXT, seed INTEGER, warmup_s REAL,
    step_s REAL, status TEXT NOT NULL, error TEXT, started_utc TEXT,
    ended_utc TEXT, steps INTEGER, ego_entered_s REAL, crossing_time_s REAL,
    min_gap_m REAL, min_ttc_s REAL, hard_brakings INTEGER, collisions INTEGER,
    late_steps INTEGER, frames_dropped INTEGER, delay_median_ms REAL,
    delay_p99_ms REAL, compute_median_ms REAL, compute_p99_ms REAL,
    latency_median_ms REAL, latency_samples INTEGER);
CREATE TABLE ride_steps (
    ride_id TEXT NOT NULL REFERENCES rides(ride_id), step INTEGER NOT NULL,
    time_s REAL, on_road INTEGER, x_m REAL, y_m REAL, speed_mps REAL,
    accel_mps2 REAL, throttle REAL, brake REAL, gap_m REAL, ttc_s REAL,
    sumo_ms REAL, policy_ms REAL, frame_ms REAL, delay_ms REAL,
    PRIMARY KEY (ride_id, step));
CREATE TABLE ride_events (
    ride_id TEXT NOT NULL REFERENCES rides(ride_id), time_s REAL,
    kind TEXT NOT NULL, other TEXT, detail TEXT);
CREATE TABLE browser_latency (
    ride_id TEXT NOT NULL REFERENCES rides(ride_id), seq INTEGER,
    latency_ms REAL);
"""


#: Ride statuses of a ride that ran its course (the ego left the network or
#: the ride reached its time limit): the rides whose participants may answer.
COMPLETED = ("arrived", "time_limit")
#: The rides a participant drives before the questions.
SURVEYED_RIDES = ("first", "second")


class AnswerExistsError(ValueError):
    """The participant has answered this question already."""


class NotYetError(ValueError):
    """A step of the study asked for before the steps it needs (the text says
    which are missing)."""


class UnknownParticipantError(KeyError):
    """No participant has this id."""


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


class StudyDatabase:
    """The study's SQLite file; each method is one transaction.

    Args:
        path: the database file; created with the schema if missing or
            empty, otherwise checked to be a study database.

    Raises:
        ValueError: the file is not a jaxround study database.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if self.path.is_dir():
            raise ValueError(f"{self.path}: is a folder, not a database file")
        try:
            with self._connect() as conn:
                tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
                if not tables:
                    conn.execute("PRAGMA journal_mode=WAL")
                    with _transaction(conn):
                        for statement in _DDL.split(";"):
                            if statement.strip():
                                conn.execute(statement)
                        conn.execute(
                            "INSERT INTO meta VALUES ('schema', ?)", (SCHEMA_VERSION,)
                        )
                    return
                version = None
                if "meta" in tables:
                    row = conn.execute(
                        "SELECT value FROM meta WHERE key = 'schema'"
                    ).fetchone()
                    version = row[0] if row else None
        except sqlite3.DatabaseError as err:
            raise ValueError(f"{self.path}: not a SQLite database ({err})") from None
        if version != SCHEMA_VERSION:
            raise ValueError(
                f"{self.path}: not a jaxround study database (schema {version!r}, "
                f"expected {SCHEMA_VERSION!r}); give another --db"
            )

    @contextlib.contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        conn = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
        try:
            conn.execute("PRAGMA synchronous=FULL")
            conn.execute("PRAGMA foreign_keys=ON")
            yield conn
        finally:
            conn.close()

    # ------------------------------------------------------------ participants

    def add_participant(self, blind: bool) -> tuple[str, str]:
        """A new participant with a random id; orders alternate (counterbalanced).

        Returns:
            (participant id, ride order '20-80' or '80-20').
        """
        participant_id = secrets.token_urlsafe(12)
        with self._connect() as conn, _transaction(conn):
            (n,) = conn.execute("SELECT COUNT(*) FROM participants").fetchone()
            order = tuple(ORDERS)[n % 2]
            conn.execute(
                "INSERT INTO participants (participant_id, created_utc, ride_order, "
                "blind) VALUES (?, ?, ?, ?)",
                (participant_id, utc_now(), order, int(blind)),
            )
        return participant_id, order

    def participant(self, participant_id: str) -> dict[str, Any]:
        """The participant's row; UnknownParticipantError if there is none."""
        with self._connect() as conn:
            conn.row_factory = sqlite3.Row
            row = conn.execute(
                "SELECT * FROM participants WHERE participant_id = ?",
                (participant_id,),
            ).fetchone()
        if row is None:
            raise UnknownParticipantError(participant_id)
        return dict(row)

    def set_demographics(
        self,
        participant_id: str,
        gender: str | None,
        age: int | None,
        driving_years: int | None,
    ) -> None:
        with self._connect() as conn, _transaction(conn):
            done = conn.execute(
                "UPDATE participants SET gender = ?, age = ?, driving_years = ? "
                "WHERE participant_id = ?",
                (gender, age, driving_years, participant_id),
            )
            if done.rowcount == 0:
                raise UnknownParticipantError(participant_id)

    def add_answer(self, participant_id: str, question: str, option_shown: int) -> int:
        """Store one answer in its own transaction; returns the paper's option.

        Raises:
            UnknownParticipantError: no such participant.
            AnswerExistsError: this question was answered before (kept as it was).
            NotYetError: the participant has not driven both rides to the end.
            ValueError: an unknown question or option.
        """
        if question not in QUESTION_IDS:
            raise ValueError(f"question {question!r}, expected one of {QUESTION_IDS}")
        with self._connect() as conn, _transaction(conn):
            row = conn.execute(
                "SELECT ride_order, blind FROM participants WHERE participant_id = ?",
                (participant_id,),
            ).fetchone()
            if row is None:
                raise UnknownParticipantError(participant_id)
            missing = _rides_not_completed(conn, participant_id)
            if missing:
                raise NotYetError(
                    "the questions come after both rides: "
                    + " and ".join(f"the {kind} ride" for kind in missing)
                    + (" has" if len(missing) == 1 else " have")
                    + " not been driven to the end"
                )
            option = paper_option(option_shown, row[0], bool(row[1]))
            try:
                conn.execute(
                    "INSERT INTO answers VALUES (?, ?, ?, ?, ?)",
                    (participant_id, question, option_shown, option, utc_now()),
                )
            except sqlite3.IntegrityError:
                raise AnswerExistsError(
                    f"question {question!r} is answered already"
                ) from None
        return option

    def finish(self, participant_id: str) -> None:
        """Mark the survey done.

        Raises:
            UnknownParticipantError: no such participant.
            NotYetError: a question is not answered yet.
        """
        with self._connect() as conn, _transaction(conn):
            answered = {
                r[0]
                for r in conn.execute(
                    "SELECT question FROM answers WHERE participant_id = ?",
                    (participant_id,),
                )
            }
            done = conn.execute(
                "UPDATE participants SET finished_utc = ? WHERE participant_id = ?",
                (utc_now(), participant_id),
            )
            if done.rowcount == 0:
                raise UnknownParticipantError(participant_id)
            missing = [q for q in QUESTION_IDS if q not in answered]
            if missing:  # rolled back with the update
                raise NotYetError(f"questions not answered yet: {missing}")

    # ------------------------------------------------------------ rides

    def save_ride(self, record: dict[str, Any]) -> None:
        """Store a ride, its steps, events and browser latencies in one transaction.

        Args:
            record: ``record["ride"]`` maps `COLUMNS["rides"]` names to values
                (missing ones are NULL); ``"steps"``, ``"events"`` and
                ``"latency"`` hold rows as dicts of their tables' columns
                (without ``ride_id``).
        """
        ride = record["ride"]
        ride_id = ride["ride_id"]
        with self._connect() as conn, _transaction(conn):
            _insert(conn, "rides", [ride])
            for table, key in (
                ("ride_steps", "steps"),
                ("ride_events", "events"),
                ("browser_latency", "latency"),
            ):
                rows = [{"ride_id": ride_id, **r} for r in record.get(key, ())]
                _insert(conn, table, rows)

    # ------------------------------------------------------------ reading

    def rows(self, table: str, where: str = "", params: tuple = ()) -> list[dict]:
        """Every row of a table of `COLUMNS` (``where``: a fixed SQL condition
        of this package with ``?`` parameters)."""
        if table not in COLUMNS:
            raise ValueError(f"table {table!r}, expected one of {sorted(COLUMNS)}")
        columns = ", ".join(COLUMNS[table])
        sql = f"SELECT {columns} FROM {table} {where}"
        with self._connect() as conn:
            conn.row_factory = sqlite3.Row
            return [dict(r) for r in conn.execute(sql, params)]

    def export_csv(self, out_dir: Path) -> list[Path]:
        """Write every table to ``<table>.csv`` in `out_dir`; returns the paths."""
        out_dir.mkdir(parents=True, exist_ok=True)
        paths = []
        for table, columns in COLUMNS.items():
            path = out_dir / f"{table}.csv"
            with path.open("w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=columns)
                writer.writeheader()
                writer.writerows(self.rows(table))
            paths.append(path)
        return paths


def _rides_not_completed(conn: sqlite3.Connection, participant_id: str) -> list[str]:
    """Which of `SURVEYED_RIDES` the participant has not driven to the end."""
    marks = ", ".join("?" for _ in COMPLETED)
    done = {
        r[0]
        for r in conn.execute(
            f"SELECT kind FROM rides WHERE participant_id = ? AND status IN ({marks})",
            (participant_id, *COMPLETED),
        )
    }
    return [kind for kind in SURVEYED_RIDES if kind not in done]


def export_names() -> list[str]:
    """The files `StudyDatabase.export_csv` writes."""
    return [f"{table}.csv" for table in COLUMNS]


@contextlib.contextmanager
def _transaction(conn: sqlite3.Connection) -> Iterator[None]:
    conn.execute("BEGIN IMMEDIATE")
    try:
        yield
    except BaseException:
        conn.execute("ROLLBACK")
        raise
    conn.execute("COMMIT")


def _insert(conn: sqlite3.Connection, table: str, rows: list[dict]) -> None:
    if not rows:
        return
    columns = COLUMNS[table]
    unknown = set().union(*rows) - set(columns)
    if unknown:
        raise ValueError(f"{table}: unknown columns {sorted(unknown)}")
    marks = ", ".join("?" for _ in columns)
    conn.executemany(
        f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({marks})",
        [tuple(r.get(c) for c in columns) for r in rows],
    )
