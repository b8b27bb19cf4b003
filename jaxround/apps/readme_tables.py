"""The README's result tables, printed from a main job's ``results.json``.

    python -m jaxround.apps.readme_tables docs/results/milan.json
    python -m jaxround.apps.readme_tables docs/results/milan.json --write README.md
    python -m jaxround.apps.readme_tables docs/results/milan.json --check README.md

The tables are `jaxround.analysis.results_tables.readme_markdown` of the
file; in the README they sit between `BEGIN` and `END`, so that a fresh
run's ``results.json`` (copied to ``docs/results/<scenario>.json``)
regenerates them, and ``--check`` (and a test) says when they differ.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from jaxround.analysis.results_tables import readme_markdown

BEGIN = "<!-- results:begin (python -m jaxround.apps.readme_tables) -->"
END = "<!-- results:end -->"


def readme_block(text: str) -> str:
    """What a README holds between `BEGIN` and `END` (without the blank
    lines beside the markers).

    Raises:
        ValueError: the markers are missing or out of order.
    """
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        raise ValueError(f"no {BEGIN} ... {END} block")
    return text[start + len(BEGIN) : end].strip("\n") + "\n"


def with_block(text: str, block: str) -> str:
    """`text` with its block replaced by `block`."""
    readme_block(text)  # raises without the markers
    start, end = text.find(BEGIN) + len(BEGIN), text.find(END)
    return f"{text[:start]}\n\n{block.strip(chr(10))}\n\n{text[end:]}"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jaxround.apps.readme_tables")
    parser.add_argument("results", type=Path, help="a main job's results.json")
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--write", type=Path, help="replace the block of this README")
    action.add_argument(
        "--check", type=Path, help="exit 1 if this README's block differs"
    )
    args = parser.parse_args(argv)
    tables = readme_markdown(json.loads(args.results.read_text()))
    if args.write is not None:
        args.write.write_text(with_block(args.write.read_text(), tables))
    elif args.check is not None:
        if readme_block(args.check.read_text()) != tables:
            print(f"{args.check}: the results block differs from {args.results}")
            return 1
    else:
        sys.stdout.write(tables)
    return 0


if __name__ == "__main__":
    sys.exit(main())
