"""The check to run on a GPU (or TPU) machine, in under 8 minutes:

    python -m jaxround.apps.bench.device_check --out device-check

It runs, each as its own ``jaxround`` command with a time limit, and keeps
their JSON in the folder:

1. ``jaxround bench --json``: the JAX environment at the device's batches
   (`jaxround.apps.bench.device`), SUMO in one process and on every core,
   PPO at the device's batch (``n_envs: auto``), the exported policy in JAX
   and with SUMO in the loop -> ``bench.json``;
2. ``jaxround run --quick``: the main job (training at the device's batch,
   evaluation in JAX and in SUMO, whose workers must keep JAX on the CPU)
   -> ``run/results.json``;

and ``device_check.json``: for each step its command, exit status, seconds
and the last lines it printed, and the device as the bench saw it. This
process starts no JAX of its own (it would take the GPU's memory). A machine
without network access installs jaxround from a packed wheel folder first
(``pip install --no-index --find-links WHEELS jaxround "jax[cuda12]"``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

#: Seconds each step may take (together under 8 minutes).
BENCH_LIMIT_S = 270
RUN_LIMIT_S = 180


def check_steps(out: Path) -> list[tuple[str, list[str], int, Path | None]]:
    """(name, argv, time limit in seconds, JSON written) of each step."""
    cli = [sys.executable, "-m", "jaxround"]
    return [
        ("bench", [*cli, "bench", "--json", "--no-progress"], BENCH_LIMIT_S,
         out / "bench.json"),
        ("run", [*cli, "run", "--quick", "--force", "--no-progress", "--out",
                 str(out / "run")], RUN_LIMIT_S, out / "run" / "results.json"),
    ]  # fmt: skip


def run_step(
    name: str, argv: list[str], limit_s: int, json_path: Path | None
) -> dict[str, Any]:
    """Run one step; its record (stdout is the JSON of ``bench --json``)."""
    started = time.perf_counter()
    try:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=limit_s)
        code, stdout, stderr = done.returncode, done.stdout, done.stderr
    except subprocess.TimeoutExpired as err:
        code, stdout, stderr = None, _text(err.stdout), _text(err.stderr)
    if name == "bench" and code == 0 and json_path is not None:
        json_path.write_text(_json_document(stdout))
    return {
        "name": name,
        "command": argv[1:],
        "exit_status": code,  # None: stopped at its time limit
        "seconds": round(time.perf_counter() - started, 1),
        "limit_s": limit_s,
        "json": str(json_path) if json_path and json_path.exists() else None,
        "stderr_tail": stderr[-3000:],
        "stdout_tail": "" if name == "bench" else stdout[-3000:],
    }


def _json_document(stdout: str) -> str:
    """The JSON document of ``bench --json`` from its stdout: from the first
    line that opens an object (libraries in worker processes may print
    warnings to stdout before it, as libsumo does beside another pyarrow)."""
    lines = stdout.splitlines(keepends=True)
    for i, line in enumerate(lines):
        if line.startswith("{"):
            return "".join(lines[i:])
    return stdout


def _text(data: bytes | str | None) -> str:
    if isinstance(data, bytes):
        return data.decode(errors="replace")
    return data or ""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("device-check"))
    parser.add_argument("--only", choices=["bench", "run"], default=None)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {"device": None, "steps": []}
    for name, command, limit, json_path in check_steps(args.out):
        if args.only not in (None, name):
            continue
        print(f"device check: {name} (at most {limit} s)", file=sys.stderr)
        step = run_step(name, command, limit, json_path)
        record["steps"].append(step)
        if name == "bench" and step["json"]:
            try:
                record["device"] = json.loads(json_path.read_text()).get("device")
            except json.JSONDecodeError as err:
                step["json_error"] = str(err)
        print(f"  exit {step['exit_status']} in {step['seconds']} s", file=sys.stderr)
        (args.out / "device_check.json").write_text(json.dumps(record, indent=1))
    return 0 if all(s["exit_status"] == 0 for s in record["steps"]) else 1


if __name__ == "__main__":
    sys.exit(main())
