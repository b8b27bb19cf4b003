"""``jaxround study serve|export|report|load``: the study's subcommands."""

from __future__ import annotations

import argparse
import json
import secrets
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from jaxround.apps.cli.arguments import UsageError, fresh_output_dir
from jaxround.study.settings import (
    MAX_PARTICIPANTS_LIMIT,
    MIN_CONNECT_TIMEOUT_S,
    StudySettings,
)

if TYPE_CHECKING:
    from jaxround.scenario.config import ScenarioConfig
    from jaxround.study.storage import StudyDatabase


def _participants(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 1 <= n <= MAX_PARTICIPANTS_LIMIT:
        raise argparse.ArgumentTypeError(f"{n}: expected 1-{MAX_PARTICIPANTS_LIMIT}")
    return n


def _seconds(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not x >= 0:
        raise argparse.ArgumentTypeError(f"{text}: expected 0 or more seconds")
    return x


def cmd_serve(args: argparse.Namespace) -> None:
    from jaxround.scenario.config import load_config
    from jaxround.study.storage import StudyDatabase

    settings = StudySettings(
        policy=args.policy,
        config=args.config or "milan",
        max_participants=args.max_participants,
        warmup_s=args.warmup_s,
        ride_s=args.ride_s,
        passes=args.passes,
        practice_s=args.practice_s,
        practice_passes=args.practice_passes,
        blind=args.blind,
        seed=args.seed,
        ego_origin=args.ego_from,
        ego_destination=args.ego_to,
        connect_timeout_s=args.connect_timeout_s,
        pedal_map=args.pedal_map,
    )
    cfg = load_config(settings.config)
    try:
        settings.validate(cfg)
        check_av_driver(str(settings.policy), cfg)
        database = StudyDatabase(args.db)
        _check_port(args.host, args.port)
    except (ValueError, FileNotFoundError, OSError) as err:
        raise UsageError(str(err)) from None
    import uvicorn

    from jaxround.study.logs import log_to_stderr
    from jaxround.study.priority import SERVER_RT_PRIORITY, raise_priority
    from jaxround.study.protocol import MAX_MESSAGE_BYTES
    from jaxround.study.server import create_app

    token = secrets.token_urlsafe(18)
    log_to_stderr()
    app = create_app(settings, database, token)
    print(f"jaxround study: open http://{args.host}:{args.port}/ in a browser")
    print(
        f"  database {database.path}; up to {settings.max_participants} "
        f"participants drive at once"
    )
    print(f"  admin token (report and export endpoints): {token}", flush=True)
    priority = raise_priority(SERVER_RT_PRIORITY)
    print(f"  scheduling priority: {priority} (see docs/study.md)", flush=True)
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"  listening on {args.host}: reachable from other machines", flush=True)
    uvicorn.run(
        app,
        host=args.host,
        port=args.port,
        ws_max_size=MAX_MESSAGE_BYTES,
        log_level="warning",
    )


def check_av_driver(spec: str, cfg: ScenarioConfig) -> None:
    """Refuse an AV driver the study cannot run on `cfg`, before it starts.

    A driver is an exported policy, a scripted controller or
    ``uncontrolled`` (`jaxround.apps.drivers`). A policy must have been
    trained on `cfg`'s roads and drivers; a policy or a scripted controller
    reads its observer from the lane paths that the JAX step has
    (`jaxround.envs.supported.check_jax_lanes`).

    Raises:
        ValueError: naming the driver and what is wrong.
    """
    from jaxround.apps.drivers import parse_driver
    from jaxround.envs.supported import check_jax_lanes

    driver = parse_driver(spec)
    if driver.kind == "policy":
        from agents.common.export import check_scenario, load_policy
        from sumo_export.controller import policy_observer

        policy_observer(spec)
        check_scenario(load_policy(spec)[1], cfg)
    if driver.kind != "uncontrolled":
        check_jax_lanes(cfg)


def _check_port(host: str, port: int) -> None:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does
        try:
            s.bind((host, port))
        except OSError as err:
            raise OSError(
                f"--host {host} --port {port}: cannot listen there "
                f"({err.strerror}); give another --port"
            ) from None


def _database(path: Path) -> StudyDatabase:
    from jaxround.study.storage import StudyDatabase

    if not path.is_file():
        raise UsageError(f"--db {path}: no such file")
    try:
        return StudyDatabase(path)
    except ValueError as err:
        raise UsageError(str(err)) from None


def cmd_export(args: argparse.Namespace) -> None:
    from jaxround.study.storage import export_names

    database = _database(args.db)
    out = fresh_output_dir(args.out, args.force, export_names())
    for path in database.export_csv(out):
        print(f"wrote {path}")


def cmd_report(args: argparse.Namespace) -> None:
    from jaxround.study.report import REPORT_FILES, tables_markdown, write_report

    database = _database(args.db)
    out = fresh_output_dir(args.out, args.force, REPORT_FILES)
    paths = write_report(database, out)
    report = json.loads((out / "report.json").read_text())
    print(tables_markdown(report))
    print("wrote " + ", ".join(str(p) for p in paths))


def cmd_load(args: argparse.Namespace) -> None:
    from jaxround.study.load import format_figures, run_load

    try:
        figures = run_load(
            args.participants,
            args.seconds,
            policy=args.policy,
            config=args.config or "milan",
            warmup_s=args.warmup_s,
        )
    except (ValueError, RuntimeError) as err:
        raise UsageError(str(err)) from None
    if args.json:
        json.dump(figures, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_figures(figures))


def add_study_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``study`` and its subcommands to the ``jaxround`` parser."""
    parser = sub.add_parser("study", help="the human-in-the-loop study in a browser")
    study = parser.add_subparsers(
        dest="study_command", required=True, metavar="STUDY_COMMAND"
    )

    p = study.add_parser("serve", help="the study's web app (FastAPI, uvicorn)")
    p.add_argument(
        "--policy",
        required=True,
        metavar="DRIVER",
        help="who drives the AVs: an exported policy (policy.npz), a scripted "
        "controller (e.g. eco, or eco+gap:10 with a lane rule on two-lane "
        "roads) or uncontrolled (their vType)",
    )
    p.add_argument("--config", default=None, help="scenario YAML or built-in name")
    p.add_argument(
        "--db",
        type=Path,
        default=Path("study.sqlite"),
        help="SQLite file (created, or continued) (default study.sqlite)",
    )
    p.add_argument("--host", default="127.0.0.1", help="address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8765, help="port (default 8765)")
    p.add_argument(
        "--max-participants",
        type=_participants,
        default=4,
        help="participants driving at once, one SUMO each (default 4)",
    )
    p.add_argument(
        "--warmup-s",
        type=_seconds,
        default=120.0,
        help="simulated seconds of traffic before the ego enters",
    )
    p.add_argument(
        "--ride-s",
        type=_seconds,
        default=180.0,
        help="longest ride, seconds (default 180)",
    )
    p.add_argument(
        "--passes",
        type=int,
        default=8,
        help="times the ego drives through the roundabout in a ride, each "
        "time in again from its entry (default 8: about 70 s of driving with "
        "the throttle held)",
    )
    p.add_argument(
        "--practice-passes",
        type=int,
        default=2,
        help="passes of the practice ride (default 2)",
    )
    p.add_argument(
        "--practice-s",
        type=_seconds,
        default=90.0,
        help="longest practice ride, seconds (default 90)",
    )
    p.add_argument(
        "--blind",
        action="store_true",
        help="call the rides A and B instead of naming their AV shares",
    )
    p.add_argument("--seed", type=int, default=None, help="traffic schedule seed")
    p.add_argument("--ego-from", default="east", help="leg the ego enters from")
    p.add_argument("--ego-to", default="south", help="leg the ego leaves at")
    p.add_argument(
        "--connect-timeout-s",
        type=_seconds,
        default=60.0,
        help="seconds a ride waits after its warm-up for the browser to start "
        "it; a ride asked for and never driven holds its place until then, "
        f"and is stored as not_started (default 60, at least "
        f"{MIN_CONNECT_TIMEOUT_S:g})",
    )
    p.add_argument(
        "--pedal-map",
        type=Path,
        default=None,
        help="JSON file of pedal set-ups per gamepad id, for wheels without the "
        "standard mapping (the page's 'Set up pedals' shows one); a browser's "
        "own set-up comes first",
    )
    p.set_defaults(func=cmd_serve)

    for name, func, what in (
        ("export", cmd_export, "every table as CSV"),
        ("report", cmd_report, "Tables 5-7, sign tests, telemetry"),
    ):
        p = study.add_parser(name, help=what)
        p.add_argument("--db", type=Path, required=True, help="the study's SQLite file")
        p.add_argument("--out", type=Path, required=True, help="folder to write into")
        p.add_argument("--force", action="store_true", help="overwrite files in --out")
        p.set_defaults(func=func)

    p = study.add_parser("load", help="scripted riders at once: the server's delay")
    p.add_argument(
        "--participants",
        type=_participants,
        default=4,
        help="rides at once (default 4)",
    )
    p.add_argument(
        "--seconds",
        type=_seconds,
        default=60.0,
        help="longest ride, seconds (default 60, at most 600)",
    )
    p.add_argument(
        "--policy",
        type=Path,
        default=None,
        help="policy for the AVs (default: a full-throttle stand-in)",
    )
    p.add_argument("--config", default=None, help="scenario YAML or built-in name")
    p.add_argument(
        "--warmup-s",
        type=_seconds,
        default=120.0,
        help="simulated seconds of traffic before each ego enters",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_load)
