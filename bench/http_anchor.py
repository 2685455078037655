"""The HTTP anchor of the request goals (issue 21): the floor a request pays on this machine at
this moment before any of the API's own work. A bare ASGI app on the API's server (uvicorn, its
httptools protocol, asyncio's loop) reads the request's body and answers 201 with a canned JSON
body of ``SPACEARM_ANCHOR_BYTES`` bytes (a paper plan's answer). No FastAPI, no engine, no
database: what the machine's sockets, the server and the clients cost.

Run: ``.venv/bin/python bench/http_anchor.py --port 8123 --bytes 80712`` (``bench_goals.py`` starts
it, and reports the API's p50 and rate beside it as ratios, measured in the same run)."""

from __future__ import annotations

import argparse
import os
from typing import Any

import uvicorn

BYTES = int(os.environ.get("SPACEARM_ANCHOR_BYTES", "80000"))


def _canned(size: int) -> bytes:
    """A JSON object of ``size`` bytes (at least 32): an array of floats, as a plan's trajectory
    is, padded with spaces to the size."""
    numbers: list[str] = []
    head = b'{"trajectory": ['
    while len(head) + sum(len(n) + 2 for n in numbers) + 24 < size:
        numbers.append(repr(0.123456789012345 + len(numbers) * 1e-7))
    body = head + ", ".join(numbers).encode() + b"]"
    return body + b" " * max(0, size - len(body) - 1) + b"}"


BODY = _canned(BYTES)
HEADERS = [(b"content-type", b"application/json"), (b"content-length", str(len(BODY)).encode())]


async def app(scope: dict[str, Any], receive: Any, send: Any) -> None:
    if scope["type"] != "http":
        return
    more = True
    while more:
        message = await receive()
        more = message.get("more_body", False)
    await send({"type": "http.response.start", "status": 201, "headers": HEADERS})
    await send({"type": "http.response.body", "body": BODY})


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--bytes", type=int, default=BYTES, help="the answer's size (a paper plan's: about 80 kB)")
    args = parser.parse_args()
    os.environ["SPACEARM_ANCHOR_BYTES"] = str(args.bytes)
    uvicorn.run(
        "http_anchor:app",
        host="127.0.0.1",
        port=args.port,
        http="httptools",
        loop="asyncio",
        log_level="warning",
        access_log=False,
        app_dir=os.path.dirname(os.path.abspath(__file__)),
    )


if __name__ == "__main__":
    main()
