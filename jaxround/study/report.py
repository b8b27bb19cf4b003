"""The study's results: the paper's Tables 5, 6 and 7, sign tests, telemetry.

Only participants who completed the study count: both rides driven to the
end (status 'arrived' or 'time_limit') and the three questions answered. The
others are listed by how far they got (`participant_status`). Each table
counts the completed participants' answers per option in the paper's order
beside the paper's own counts. "80% preferred" is tested per question with an exact
binomial (sign) test: answers favouring the 80% ride against those favouring
the 20% ride, "no difference" / "cannot say" left out, under H0 p = 1/2.
The one-sided p-value is P(X >= k) for k answers favouring 80% of n; the
two-sided one doubles the smaller tail (at most 1).

Telemetry per scenario covers the rides that ran their course (the ego left
the network or the ride reached its time limit).
"""

from __future__ import annotations

import csv
import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from jaxround.study.questions import (
    FAVOUR_HIGH,
    FAVOUR_LOW,
    N_OPTIONS,
    PAPER_COUNTS,
    PAPER_TABLE,
    QUESTION_IDS,
    QUESTIONS,
    ride_names,
)
from jaxround.study.settings import HIGH_SHARE, LOW_SHARE, share_label
from jaxround.study.storage import COMPLETED, SURVEYED_RIDES, StudyDatabase

#: How far a participant got, in the study's order (`participant_status`).
STATUSES = (
    "consent_only",
    "practice_driven",
    "first_ride_driven",
    "both_rides_driven",
    "completed",
)
#: Files `write_report` writes.
REPORT_FILES = (
    "tables.md",
    "tables.csv",
    "report.json",
    "telemetry.md",
    "telemetry.csv",
    "telemetry.png",
)


def sign_test(favour_high: int, favour_low: int) -> dict[str, float | int | None]:
    """Exact binomial test of "the 80% ride is preferred".

    Returns:
        n (answers with a side), k (favouring 80%), p_one_sided
        (P(X >= k)), p_two_sided; p-values are None when n is 0.
    """
    n = favour_high + favour_low
    if n == 0:
        return {"n": 0, "k": 0, "p_one_sided": None, "p_two_sided": None}
    upper = sum(math.comb(n, i) for i in range(favour_high, n + 1)) / 2**n
    lower = sum(math.comb(n, i) for i in range(0, favour_high + 1)) / 2**n
    return {
        "n": n,
        "k": favour_high,
        "p_one_sided": upper,
        "p_two_sided": min(1.0, 2 * min(upper, lower)),
    }


def answer_tables(answers: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Counts per question and option (paper's order), the paper's, the test."""
    tables = {}
    names = ride_names(blind=False)
    for question in QUESTIONS:
        counts = Counter(
            a["option_paper"] for a in answers if a["question"] == question.id
        )
        ours = [counts.get(i, 0) for i in range(N_OPTIONS)]
        tables[question.id] = {
            "table": PAPER_TABLE[question.id],
            "heading": question.heading,
            "options": [o.format(**names) for o in question.options],
            "counts": ours,
            "paper_counts": list(PAPER_COUNTS[question.id]),
            "sign_test": sign_test(
                sum(ours[i] for i in FAVOUR_HIGH), sum(ours[i] for i in FAVOUR_LOW)
            ),
            "paper_sign_test": sign_test(
                sum(PAPER_COUNTS[question.id][i] for i in FAVOUR_HIGH),
                sum(PAPER_COUNTS[question.id][i] for i in FAVOUR_LOW),
            ),
        }
    return tables


def telemetry(
    rides: list[dict[str, Any]], lane_changes: dict[str, Counter] | None = None
) -> dict[str, dict[str, Any]]:
    """Per scenario (20%, 80%): rides, min TTC, hard brakings, crossing time,
    collisions, the server's delay and, on two-lane roads, the ego's lane
    changes per ride (asked for, made for the route).

    Args:
        rides: the ``rides`` rows.
        lane_changes: per ride id, its lane changes counted as ``"asked"``
            and ``"route"`` (`lane_change_counts`).
    """
    lane_changes = lane_changes or {}
    out = {}
    for share in (LOW_SHARE, HIGH_SHARE):
        mine = [
            r
            for r in rides
            if r["kind"] in ("first", "second")
            and r["status"] in COMPLETED
            and abs((r["share"] or 0.0) - share) < 1e-9
        ]

        def values(key: str, rows: list[dict] = mine) -> list[float]:
            return [r[key] for r in rows if r[key] is not None]

        out[share_label(share)] = {
            "rides": len(mine),
            "arrived": sum(r["status"] == "arrived" for r in mine),
            "min_ttc_s_median": _median(values("min_ttc_s")),
            "min_ttc_s_lowest": min(values("min_ttc_s"), default=None),
            "hard_brakings_mean": _mean(values("hard_brakings")),
            "crossing_time_s_mean": _mean(values("crossing_time_s")),
            "collisions": int(sum(values("collisions"))),
            "delay_median_ms": _median(values("delay_median_ms")),
            "delay_p99_ms_max": max(values("delay_p99_ms"), default=None),
            "lane_changes_asked_mean": _mean(
                [lane_changes.get(r["ride_id"], Counter())["asked"] for r in mine]
            ),
            "lane_changes_route_mean": _mean(
                [lane_changes.get(r["ride_id"], Counter())["route"] for r in mine]
            ),
            "per_ride": {
                k: values(k) for k in ("min_ttc_s", "hard_brakings", "crossing_time_s")
            },
        }
    return out


def lane_change_counts(events: list[dict[str, Any]]) -> dict[str, Counter]:
    """Per ride id, its ``lane_change`` events counted as ``"asked"`` (the
    participant's turn signal) and ``"route"`` (SUMO's, for the exit)."""
    counts: dict[str, Counter] = {}
    for e in events:
        if e["kind"] == "lane_change":
            why = "asked" if (e["detail"] or "").endswith("asked for") else "route"
            counts.setdefault(e["ride_id"], Counter())[why] += 1
    return counts


def participant_status(
    participant: dict[str, Any], rides: list[dict[str, Any]], answered: set[str]
) -> str:
    """How far a participant got, one of `STATUSES`.

    Args:
        participant: the ``participants`` row.
        rides: the participant's ``rides`` rows.
        answered: the questions they answered.
    """
    driven = {r["kind"] for r in rides if r["status"] in COMPLETED}
    if all(kind in driven for kind in SURVEYED_RIDES):
        done = participant["finished_utc"] is not None
        if done and answered >= set(QUESTION_IDS):
            return "completed"
        return "both_rides_driven"
    if "first" in driven:
        return "first_ride_driven"
    return "practice_driven" if "practice" in driven else "consent_only"


def build_report(database: StudyDatabase) -> dict[str, Any]:
    """The whole report as plain data (what ``/admin/report`` returns).

    The tables count the answers of completed participants only; the others
    are counted per status in ``by_status``.
    """
    participants = database.rows("participants")
    answers = database.rows("answers")
    rides = database.rows("rides")
    status = {}
    for p in participants:
        pid = p["participant_id"]
        status[pid] = participant_status(
            p,
            [r for r in rides if r["participant_id"] == pid],
            {a["question"] for a in answers if a["participant_id"] == pid},
        )
    completed = [p for p in participants if status[p["participant_id"]] == "completed"]
    counts = Counter(status.values())
    return {
        "participants": len(participants),
        "completed": len(completed),
        "by_status": {s: counts.get(s, 0) for s in STATUSES},
        "blind": sum(bool(p["blind"]) for p in completed),
        "orders": dict(Counter(p["ride_order"] for p in completed)),
        "tables": answer_tables(
            [a for a in answers if status[a["participant_id"]] == "completed"]
        ),
        "telemetry": telemetry(
            rides,
            lane_change_counts(
                database.rows("ride_events", "WHERE kind = 'lane_change'")
            ),
        ),
    }


def tables_markdown(report: dict[str, Any]) -> str:
    others = ", ".join(
        f"{n} {status.replace('_', ' ')}"
        for status, n in report["by_status"].items()
        if status != "completed" and n
    )
    lines = [
        f"Completed participants (both rides driven to the end, three answers): "
        f"{report['completed']}; the tables count these only.",
        f"Others, by how far they got: {others or 'none'} "
        f"({report['participants']} participants in all).",
    ]
    for qid in QUESTION_IDS:
        t = report["tables"][qid]
        test, paper = t["sign_test"], t["paper_sign_test"]
        lines += [
            "",
            f"### Table {t['table']}: {t['heading']}",
            "",
            "| answer | here | paper |",
            "|---|---|---|",
        ]
        lines += [
            f"| {o} | {c} | {p} |"
            for o, c, p in zip(t["options"], t["counts"], t["paper_counts"])
        ]
        lines += [
            "",
            f"Sign test of 80% preferred: {test['k']} of {test['n']}, "
            f"one-sided p = {_p(test['p_one_sided'])}, two-sided p = "
            f"{_p(test['p_two_sided'])} (paper: {paper['k']} of "
            f"{paper['n']}, one-sided p = {_p(paper['p_one_sided'])}).",
        ]
    return "\n".join(lines) + "\n"


def telemetry_markdown(report: dict[str, Any]) -> str:
    """The telemetry table; with lane-change columns where a ride changed lanes."""
    rows = report["telemetry"]
    lanes = any(
        t["lane_changes_asked_mean"] or t["lane_changes_route_mean"]
        for t in rows.values()
    )
    extra = " lane changes per ride: asked / for the route |" if lanes else ""
    lines = [
        "| AVs | rides | arrived | min TTC median (s) | lowest min TTC (s) | "
        "hard brakings per ride | crossing time (s) | collisions | server "
        f"delay median (ms) | worst ride's p99 (ms) |{extra}",
        "|---|---|---|---|---|---|---|---|---|---|" + ("---|" if lanes else ""),
    ]
    for share, t in rows.items():
        lane_cell = (
            f" {_f(t['lane_changes_asked_mean'])} / "
            f"{_f(t['lane_changes_route_mean'])} |"
            if lanes
            else ""
        )
        lines.append(
            f"| {share} | {t['rides']} | {t['arrived']} | {_f(t['min_ttc_s_median'])}"
            f" | {_f(t['min_ttc_s_lowest'])} | {_f(t['hard_brakings_mean'])} | "
            f"{_f(t['crossing_time_s_mean'])} | {t['collisions']} | "
            f"{_f(t['delay_median_ms'])} | {_f(t['delay_p99_ms_max'])} |{lane_cell}"
        )
    return "\n".join(lines) + "\n"


def write_report(database: StudyDatabase, out_dir: Path) -> list[Path]:
    """Write `REPORT_FILES` into `out_dir` (the caller refuses to overwrite)."""
    report = build_report(database)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "tables.md").write_text(tables_markdown(report))
    with (out_dir / "tables.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            ["table", "question", "option", "answer", "count", "paper_count"]
        )
        for qid in QUESTION_IDS:
            t = report["tables"][qid]
            for i, (o, c, p) in enumerate(
                zip(t["options"], t["counts"], t["paper_counts"])
            ):
                writer.writerow([t["table"], qid, i, o, c, p])
    (out_dir / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    (out_dir / "telemetry.md").write_text(telemetry_markdown(report))
    with (out_dir / "telemetry.csv").open("w", newline="") as f:
        rows = [
            {"avs": s, **{k: v for k, v in t.items() if k != "per_ride"}}
            for s, t in report["telemetry"].items()
        ]
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    telemetry_figure(report, out_dir / "telemetry.png")
    return [out_dir / name for name in REPORT_FILES]


def telemetry_figure(report: dict[str, Any], path: Path) -> None:
    """Per scenario, every ride's min TTC, hard brakings and crossing time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (
        ("min_ttc_s", "min time to collision (s)"),
        ("hard_brakings", "hard brakings per ride"),
        ("crossing_time_s", "crossing time (s)"),
    )
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.2))
    shares = list(report["telemetry"])
    for ax, (key, title) in zip(axes, panels):
        for i, share in enumerate(shares):
            values = report["telemetry"][share]["per_ride"][key]
            jitter = np.linspace(-0.12, 0.12, len(values)) if values else []
            ax.scatter(np.full(len(values), i) + jitter, values, s=18, alpha=0.7)
            if values:
                ax.hlines(np.median(values), i - 0.25, i + 0.25, color="k")
        ax.set_xticks(range(len(shares)), [f"{s} AVs" for s in shares])
        ax.set_xlim(-0.6, len(shares) - 0.4)
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _f(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def _p(x: float | None) -> str:
    return "-" if x is None else f"{x:.4f}"
