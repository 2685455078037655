"""``spacearm migrate | serve | worker | run | plan`` (``spacearm --help`` lists every option and the
``SPACEARM_*`` environment variables)."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from pydantic import ValidationError

from service.infra.collector import pause_collector
from service.infra.logs import Say, configure, messenger
from service.infra.settings import Settings

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def package_version() -> str:
    try:
        return version("spacearm")
    except PackageNotFoundError:  # pragma: no cover - running from a tree that was never installed
        return "unknown"


def _default(name: str) -> Any:
    return Settings.model_fields[name].default


def environment_help() -> str:
    """The ``SPACEARM_*`` variables (:class:`Settings`), for the epilog of ``--help``."""
    lines = ["environment variables (read by every command; options given on the command line win):"]
    for name, field in Settings.model_fields.items():
        default = "unset" if field.default is None else field.default
        if hasattr(default, "get_secret_value"):
            default = "unset"
        lines.append(f"  SPACEARM_{name.upper()} (default: {default})")
        lines.append(f"      {field.description}")
    return "\n".join(lines)


def non_negative(text: str) -> int:
    number = int(text)
    if number < 0:
        raise argparse.ArgumentTypeError(f"{number} is negative")
    return number


def api_processes(text: str) -> int:
    number = int(text)
    if not 1 <= number <= 64:
        raise argparse.ArgumentTypeError(f"{number} is not between 1 and 64")
    return number


def build_parser() -> argparse.ArgumentParser:
    logs = argparse.ArgumentParser(add_help=False)
    group = logs.add_argument_group("logging")
    group.add_argument(
        "--log-format",
        choices=["text", "json"],
        default=None,
        help=f"log lines as text or as JSON objects (default: $SPACEARM_LOG_FORMAT, else {_default('log_format')})",
    )
    group.add_argument(
        "--log-level",
        choices=["debug", "info", "warning", "error"],
        default=None,
        help=f"lowest level logged (default: $SPACEARM_LOG_LEVEL, else {_default('log_level')})",
    )
    group.add_argument(
        "-v", "--verbose", action="store_true", help="also log Alembic's steps while migrating (default: off; on at debug level)"
    )

    parser = argparse.ArgumentParser(
        prog="spacearm",
        description="spacearm: singularity-robust path planning of free-floating space robots; REST service and GA tuning jobs",
        epilog=environment_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="command")
    db_help = f"the database is $SPACEARM_DATABASE_URL (default: {_default('database_url')})"

    m = sub.add_parser(
        "migrate",
        parents=[logs],
        help="upgrade the database to the head revision (Alembic) and add the presets",
        description=f"Upgrade the database to a revision and add the robot presets; {db_help}.",
    )
    m.add_argument("--revision", default="head", help="Alembic revision to upgrade to (default: head)")
    m.add_argument(
        "--no-presets",
        action="store_true",
        help="only the schema; the API or a worker adds the presets when it starts (default: off)",
    )

    def listen_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--host", default=None, help=f"address to bind (default: $SPACEARM_HOST, else {_default('host')})")
        p.add_argument(
            "--port", type=int, default=None, help=f"port to listen on (default: $SPACEARM_PORT, else {_default('port')})"
        )

    s = sub.add_parser(
        "serve",
        parents=[logs],
        help="run the API (uvicorn, one process)",
        description=f"Run the API. {db_help}; set SPACEARM_API_KEYS before binding to anything but loopback.",
    )
    listen_options(s)

    w = sub.add_parser(
        "worker",
        parents=[logs],
        help="claim and run tuning jobs",
        description=f"Claim and run tuning jobs from the queue; {db_help}. SIGTERM/Ctrl-C puts a running job back.",
    )
    w.add_argument("--once", action="store_true", help="run at most one job, then exit (default: run until stopped)")

    c = sub.add_parser(
        "compile",
        parents=[logs],
        help="compile the engine's kernels into their cache (once per install, upgrade or CPU), with progress",
        description="Compile the engine's numba kernels into their on-disk cache, in one process per part at once, "
        "saying how far it is every 10 s; nothing to do when they were compiled for this CPU already. `spacearm run` "
        "does this before starting the API and the workers; the Docker image does it when built.",
    )
    c.add_argument("--force", action="store_true", help="compile even if the cache says it is complete (default: off)")

    r = sub.add_parser(
        "run",
        parents=[logs],
        help="migrate, then run the API and workers; print the URL once ready (what `make run` does)",
        description="Migrate the database, start the API and the workers as child processes, print the URL once "
        f"/readyz answers, and stop them all on Ctrl-C or SIGTERM. {db_help}.",
    )
    listen_options(r)
    r.add_argument("--workers", type=non_negative, default=1, help="worker processes to start (default: 1)")
    r.add_argument(
        "--api-processes",
        type=api_processes,
        default=None,
        help="API processes behind the one port, 1 to 64 (default: SPACEARM_API_PROCESSES, else 1); more than one share the "
        "port (SO_REUSEPORT) and their metrics (PROMETHEUS_MULTIPROC_DIR, a temporary folder unless set)",
    )
    r.add_argument(
        "--ready-timeout",
        type=float,
        default=600.0,
        help="seconds to wait for /readyz before giving up (default: 600; the first run compiles the kernels, 30 s to a minute)",
    )

    p = sub.add_parser(
        "plan",
        parents=[logs],
        help="plan a task from a JSON file, without a server, and print its metrics",
        description="Plan the request in FILE (the body of POST /v1/plans: robot_id, a preset here, or an inline "
        "robot; task; method; options) in this process, without a server or a database, and print the verdict and "
        "the metrics table. Exit status: 0 the plan succeeded, 1 it failed (infeasible: the message says where), "
        "2 the request is invalid.",
    )
    p.add_argument("file", help="the plan request, JSON ('-': standard input; no default)")
    p.add_argument(
        "--trajectory",
        metavar="OUT",
        default=None,
        help="also write the trajectory to OUT, in the format of its extension: .csv, .mat, .npz, .json or .ros.json "
        "(default: none)",
    )
    p.add_argument("--json", action="store_true", help="print the plan's JSON summary instead of the table (default: off)")
    return parser


def display_url(url: str) -> str:
    """``url`` without its password."""
    from sqlalchemy.engine import make_url

    return make_url(url).render_as_string(hide_password=True)


def migrate(settings: Settings, revision: str, say: Say, presets: bool = True) -> int:
    from service.infra.migrate import MigrationError, upgrade

    try:
        upgrade(settings.database_url, revision)
    except MigrationError as exc:
        say(f"spacearm migrate: {exc}", True)
        return 1
    if presets:
        from service.infra.db import Database
        from service.infra.revision import missing_presets

        db = Database(settings.database_url, settings.sqlite_busy_timeout_ms)
        try:
            if missing_presets(db.engine):
                from service.usecases.robots import seed_presets  # the engine: only when a preset is missing

                seed_presets(db)
        finally:
            db.dispose()
    say(f"database {display_url(settings.database_url)} at {revision}", False)
    return 0


def compile_command(force: bool, say: Say) -> int:
    """``spacearm compile``: fill the kernel cache unless it is complete for this CPU."""
    from engine.kernels.cache import compiled
    from engine.kernels.jit import CACHE_DIR
    from engine.warmup import PARTS, CompileError, Progress, compile_kernels
    from service.run import PROGRESS_FD

    if compiled() and not force:
        say(f"engine kernels: compiled already for this CPU (cache {CACHE_DIR})", False)
        return 0
    say(
        f"compiling the engine's kernels for this CPU into {CACHE_DIR} (once per install, upgrade or CPU; "
        f"30 s to a minute on 2 cores), {len(PARTS)} parts at once",
        False,
    )

    told = os.environ.pop(PROGRESS_FD, "")  # spacearm run's pipe: a line as each part ends
    parts_done = 0

    def progress(p: Progress) -> None:
        nonlocal parts_done
        running = f"; compiling: {', '.join(p.running)}" if p.running else ""
        say(f"compiling kernels: {p.done} of {p.total} parts done after {p.seconds:.0f} s{running}", False)
        if told.isdigit() and p.done > parts_done:
            with contextlib.suppress(OSError):  # the launcher is gone: nobody to tell
                os.write(int(told), f"{p.done} of {p.total}\n".encode())
        parts_done = p.done

    try:
        seconds = compile_kernels(progress)
    except CompileError as exc:
        say(f"spacearm compile: {exc}", True)
        return 1
    say(f"engine kernels compiled in {seconds:.0f} s", False)
    return 0


def _stop_while_starting(logger: str) -> None:
    """Until the worker installs its own handlers (which finish the current generation first): a
    SIGTERM or Ctrl-C while it imports its code or waits at ``spacearm run``'s gate ends it at once,
    saying so, instead of the silent default."""

    def handle(signum: int, _frame: Any) -> None:
        logging.getLogger(logger).info("signal %s: stopping after the current generation", signum)
        raise SystemExit(0)

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, handle)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        settings = Settings()
    except ValidationError as exc:  # a line per variable, not a traceback
        for error in exc.errors():
            name = "SPACEARM_" + "_".join(str(part) for part in error["loc"]).upper()
            print(f"spacearm: {name}={error.get('input')!r}: {error['msg']}", file=sys.stderr)
        return 2
    log_format = args.log_format or settings.log_format
    log_level = args.log_level or settings.log_level
    log_config = configure(log_format, log_level, verbose=args.verbose)
    say = messenger(log_format, f"spacearm.{args.command}")

    if args.command == "migrate":
        return migrate(settings, args.revision, say, presets=not args.no_presets)
    if args.command == "compile":
        return compile_command(args.force, say)
    if args.command == "serve":
        pause_collector()
        from service.app import create_app
        from service.infra.server import serve
        from service.run import pass_gate

        if not pass_gate():  # started by `spacearm run`, whose migration or compilation failed
            return 1

        settings = settings.model_copy(update={"host": args.host or settings.host, "port": args.port or settings.port})
        if not settings.keys() and settings.host not in LOCAL_HOSTS:
            logging.getLogger("spacearm.api").warning(
                "authentication is OFF and the API listens on %s: set SPACEARM_API_KEYS before exposing it", settings.host
            )
        serve(create_app(settings, freeze_heap=True), settings, log_level, log_config)
        return 0
    if args.command == "worker":
        _stop_while_starting("spacearm.worker")
        pause_collector()
        from service.run import pass_gate
        from service.worker import run_worker

        if not pass_gate():
            return 1
        run_worker(settings, once=args.once, freeze_heap=True)
        return 0
    if args.command == "plan":
        from service.plan_file import plan_file

        return plan_file(args.file, args.trajectory, args.json, settings)
    if args.command == "run":
        from service.run import child_env, run

        # The launcher only starts and watches processes: the migration (SQLAlchemy, Alembic, and
        # the engine for the presets) and the kernels' compilation run in children, side by side,
        # while the API and the workers import their code; the launcher imports none of them.
        env = child_env(log_format, log_level)
        return run(
            args.host or settings.host,
            args.port or settings.port,
            args.workers,
            args.ready_timeout,
            env,
            say,
            verbose=args.verbose,
            api_processes=args.api_processes or settings.api_processes,
        )
    return 2


if __name__ == "__main__":
    sys.exit(main())
