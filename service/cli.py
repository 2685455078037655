"""``spacearm migrate | serve | worker``."""

from __future__ import annotations

import argparse
import logging
import sys

from service.settings import Settings


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="spacearm", description="spacearm REST service")
    sub = parser.add_subparsers(dest="command", required=True)
    m = sub.add_parser("migrate", help="upgrade the database to the head revision (Alembic)")
    m.add_argument("--revision", default="head")
    s = sub.add_parser("serve", help="run the API (uvicorn)")
    s.add_argument("--host", default=None)
    s.add_argument("--port", type=int, default=None)
    w = sub.add_parser("worker", help="claim and run tuning jobs")
    w.add_argument("--once", action="store_true", help="run at most one job, then exit")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings = Settings()

    if args.command == "migrate":
        from service.db import Database
        from service.migrate import MigrationError, seed_presets, upgrade

        try:
            upgrade(settings.database_url, args.revision)
        except MigrationError as exc:
            print(f"spacearm migrate: {exc}", file=sys.stderr)
            return 1
        db = Database(settings.database_url, settings.sqlite_busy_timeout_ms)
        seed_presets(db)
        db.dispose()
        print(f"database {settings.database_url} at {args.revision}")
        return 0
    if args.command == "serve":
        import uvicorn

        from service.app import create_app
        from service.logs import uvicorn_log_config

        host = args.host or settings.host
        if not settings.keys() and host not in ("127.0.0.1", "localhost", "::1"):
            logging.getLogger("spacearm.api").warning(
                "authentication is OFF and the API listens on %s: set SPACEARM_API_KEYS before exposing it", host
            )
        uvicorn.run(
            create_app(settings), host=host, port=args.port or settings.port, log_level="info", log_config=uvicorn_log_config()
        )
        return 0
    if args.command == "worker":
        from service.worker import run_worker

        run_worker(settings, once=args.once)
        return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
