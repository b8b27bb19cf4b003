"""The run folder's CSV files: ``metrics.csv`` and ``timing.csv``, one row per
update, appended as the run goes.

    log = CsvLog(out, columns, start)   # cuts both files back to `start`
    log(update, metrics)                # a progress_fn: appends one row to each

``metrics.csv`` holds the algorithm's metrics and is deterministic (the same
config and seed on the same machine give the same file); ``timing.csv`` holds
the wall time and env steps per second of each update, kept apart so that
``metrics.csv`` stays deterministic.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

#: Columns of every run's timing.csv.
TIMING_COLUMNS = ("update", "wall_s", "env_steps_per_s")


class CsvLog:
    """A progress callback writing ``metrics.csv`` and ``timing.csv`` of a run
    folder. Made at the start of a session: it cuts both files back to the
    update the session starts from, so a resumed run has no duplicate rows."""

    def __init__(self, folder: Path, columns: tuple[str, ...], start: int) -> None:
        """
        Args:
            folder: the run's folder.
            columns: metrics.csv's columns (`agents.run.algorithms.csv_columns`).
            start: updates done before this session (0 for a fresh run).
        """
        self.metrics_csv = folder / "metrics.csv"
        self.timing_csv = folder / "timing.csv"
        self.columns = columns
        cut_csv(self.metrics_csv, columns, start)
        cut_csv(self.timing_csv, TIMING_COLUMNS, start)

    def __call__(self, update: int, metrics: dict[str, Any]) -> None:
        """Append update `update`'s row to both files."""
        row = {"update": update, **metrics}
        append_csv(self.metrics_csv, self.columns, row)
        append_csv(self.timing_csv, TIMING_COLUMNS, row)


def _format(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.9g}"
    return str(value)


def append_csv(path: Path, columns: tuple[str, ...], row: dict[str, Any]) -> None:
    """Append one row (writing the header first if the file is new)."""
    new = not path.exists()
    with path.open("a", newline="") as f:
        writer = csv.writer(f)
        if new:
            writer.writerow(columns)
        writer.writerow([_format(row[c]) for c in columns])


def cut_csv(path: Path, columns: tuple[str, ...], last_update: int) -> None:
    """Keep the header and the rows up to `last_update` (all others are dropped)."""
    rows = read_csv(path) if path.exists() else []
    kept = [r for r in rows if int(r["update"]) <= last_update]
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        writer.writerows([[r[c] for c in columns] for r in kept])
    tmp.replace(path)


def read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file, as column -> text."""
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


__all__ = ["TIMING_COLUMNS", "CsvLog", "append_csv", "cut_csv", "read_csv"]
