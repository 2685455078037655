"""The HTTP guards (:mod:`service.infra.server`) around requests that arrive while other answers are
under way, on a small app of their own served in this process by uvicorn with the guards' protocol
and 2 s header and body timeouts: an answer sent before the body was read, a pipelined request
queued behind two slow answers, and a large body pipelined behind a streamed answer. Each case is one
a review of the move to httptools found broken; then a refusal behind an answer under way, a body
the server has not asked for yet (``Expect: 100-continue``), and an answer its client does not read
(2 s send timeout); last, the bodies of the guards' own refusals."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import threading
import time
from collections.abc import AsyncIterator, Iterator
from typing import Any

import pytest
import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import PlainTextResponse, Response, StreamingResponse
from starlette.routing import Route

from service.errors import PROBLEM_BASE, TITLES
from service.infra.server import MAX_HEAD_BYTES, protocol_for
from service.infra.settings import Settings
from tests.service.conftest import free_port
from tests.service.test_hostile_load import _until_closed


async def slow(request: Request) -> PlainTextResponse:
    await asyncio.sleep(float(request.query_params["s"]))
    return PlainTextResponse(f"slept {request.query_params['s']}")


async def stream(request: Request) -> StreamingResponse:
    async def ticks() -> AsyncIterator[str]:
        for i in range(12):
            yield f"tick{i}\n"
            await asyncio.sleep(0.25)

    return StreamingResponse(ticks(), media_type="text/plain")


async def echo(request: Request) -> PlainTextResponse:
    return PlainTextResponse(f"got {len(await request.body())}")


BIG = 32 * 2**20


async def big(request: Request) -> Response:
    return Response(b"x" * BIG, media_type="application/octet-stream")


async def late_read(request: Request) -> PlainTextResponse:
    await asyncio.sleep(float(request.query_params["s"]))
    return await echo(request)


APP = Starlette(
    routes=[
        Route("/slow", slow),
        Route("/big", big),
        Route("/stream", stream),
        Route("/echo", echo, methods=["POST"]),
        Route("/late-read", late_read, methods=["POST"]),
    ]
)


@pytest.fixture(scope="module")
def port() -> Iterator[int]:
    chosen = free_port()
    settings = Settings(header_timeout_s=2, body_timeout_s=2, body_min_rate=1000, send_timeout_s=2)
    config = uvicorn.Config(
        APP, host="127.0.0.1", port=chosen, http=protocol_for(settings), loop="asyncio", log_level="warning", timeout_keep_alive=3
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started
    yield chosen
    server.should_exit = True
    thread.join(10)


def test_an_answer_before_the_body_leaves_a_timer(port: int) -> None:
    """A 404 sent before the body was read, then the body's rest, then silence: uvicorn's keep-alive
    timer stopped at those bytes, and the connection stayed open for ever."""
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(b'POST /nope HTTP/1.1\r\nHost: x\r\nContent-Length: 10\r\n\r\n{"a"')
        time.sleep(0.5)
        sock.sendall(b": 1}  ")
        answer, closed = _until_closed(sock, 15.0)
    assert answer.startswith(b"HTTP/1.1 404") and closed is not None and closed < 8.0, (answer, closed)
    assert b"408" not in answer


def test_a_queued_body_is_timed_from_its_turn_without_cutting_the_answers_before(port: int) -> None:
    """Two slow requests and a POST whose body never comes, pipelined: both answers arrive whole, then
    the POST's 408 (its body timer had fired during the second answer and replaced it)."""
    heads = b"GET /slow?s=1 HTTP/1.1\r\nHost: x\r\n\r\nGET /slow?s=4 HTTP/1.1\r\nHost: x\r\n\r\n"
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(heads + b"POST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n{")
        answer, closed = _until_closed(sock, 20.0)
    assert b"slept 1" in answer and b"slept 4" in answer, answer
    assert answer.index(b"slept 4") < answer.index(b"HTTP/1.1 408"), answer
    assert closed is not None


def test_a_large_body_pipelined_behind_a_stream_is_a_body(port: int) -> None:
    """A 40 kB body sent a kilobyte at a time behind a streamed answer: its bytes were read as a head
    (431 in the middle of the stream)."""
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(b"GET /stream HTTP/1.1\r\nHost: x\r\n\r\nPOST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: 40000\r\n\r\n")
        for _ in range(40):
            sock.sendall(b"a" * 1000)
            time.sleep(0.01)
        sock.settimeout(10.0)
        answer = b""
        while b"got 40000" not in answer:
            chunk = sock.recv(65536)
            assert chunk, answer
            answer += chunk
    assert b"431" not in answer and b"tick11" in answer, answer


def test_a_refusal_waits_for_the_answer_owed_before_it(port: int) -> None:
    """A head over 16 KiB pipelined behind a slow answer: the answer comes whole, then the connection
    closes (the 431 had been written in its place)."""
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(b"GET /slow?s=1 HTTP/1.1\r\nHost: x\r\n\r\n")
        time.sleep(0.2)
        sock.sendall(b"GET /slow?s=0 HTTP/1.1\r\nHost: x\r\nCookie: " + b"a" * 17_000 + b"\r\n\r\n")
        answer, closed = _until_closed(sock, 10.0)
    assert answer.startswith(b"HTTP/1.1 200") and b"slept 1" in answer and b"431" not in answer, answer
    assert closed is not None


@pytest.mark.parametrize("asked_after_s", [1.9, 3.0])
def test_a_body_is_timed_from_when_the_server_asks_for_it(port: int, asked_after_s: float) -> None:
    """``Expect: 100-continue`` and a handler that reads the body 1.9 or 3 s after the head (the body
    timeout is 2 s), the client sending it 0.3 s after the server asks: its answer comes (a 408 did,
    the body's clock having run from the head)."""
    with socket.create_connection(("127.0.0.1", port)) as sock:
        head = f"POST /late-read?s={asked_after_s} HTTP/1.1\r\nHost: x\r\nExpect: 100-continue\r\nContent-Length: 5\r\n\r\n"
        sock.sendall(head.encode())
        sock.settimeout(10.0)
        assert sock.recv(1000).startswith(b"HTTP/1.1 100")
        time.sleep(0.3)
        sock.sendall(b"hello")
        answer = b""
        while b"got" not in answer and (chunk := sock.recv(65536)):
            answer += chunk
    assert answer.startswith(b"HTTP/1.1 200") and b"got 5" in answer, answer


def test_an_answer_nobody_reads_is_cut_after_the_send_timeout(port: int) -> None:
    """A 32 MiB answer to a client that reads none of it for 5 s (a 4 kB receive buffer): the
    connection stayed open, the answer held in the server, for as long as the client waited; it is
    aborted once nothing went out for 2 s. A client that reads gets it whole."""
    with socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.connect(("127.0.0.1", port))
        sock.sendall(b"GET /big HTTP/1.1\r\nHost: x\r\n\r\n")
        time.sleep(5.0)
        answer, closed = _until_closed(sock, 10.0)
    assert answer.startswith(b"HTTP/1.1 200") and len(answer) < BIG and closed is not None, (len(answer), closed)
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(b"GET /big HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        answer, closed = _until_closed(sock, 30.0)
    assert len(answer) > BIG and answer.endswith(b"x" * 1000) and closed is not None, (len(answer), closed)


def test_an_answer_read_slowly_is_not_cut(port: int) -> None:
    """The 32 MiB answer read at about 5 MB/s, some 6 s against the 2 s send timeout: it comes
    whole (it was cut after 2 s: the timeout counted from the first pause of writing, and a whole
    answer written at once keeps writing paused until nearly all of it is out)."""
    with socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 65536)
        sock.connect(("127.0.0.1", port))
        sock.sendall(b"GET /big HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        sock.settimeout(10.0)
        start, received, tail = time.monotonic(), 0, b""
        while chunk := sock.recv(65536):
            received += len(chunk)
            tail = (tail + chunk)[-1000:]
            time.sleep(max(0.0, received / 5e6 - (time.monotonic() - start)))
    assert received > BIG and tail == b"x" * 1000 and time.monotonic() - start > 4.0, received


def _problem(answer: bytes) -> tuple[int, dict[str, str], dict[str, Any]]:
    """The status, headers and JSON body of a whole HTTP/1.1 answer."""
    head, _, body = answer.partition(b"\r\n\r\n")
    status_line, *lines = head.decode("latin-1").split("\r\n")
    headers = {name.lower(): value.strip() for name, _, value in (line.partition(":") for line in lines)}
    assert int(headers["content-length"]) == len(body), answer
    return int(status_line.split()[1]), headers, json.loads(body)


def _refused_as_problems(answers: dict[tuple[int, str], bytes]) -> None:
    for (status, says), answer in answers.items():
        got, headers, body = _problem(answer)
        assert says in body["detail"], body
        assert got == status and headers["content-type"] == "application/problem+json", answer
        assert headers["connection"] == "close" and headers["x-content-type-options"] == "nosniff", answer
        assert "date" in headers and "server" in headers, answer  # a 4xx has a Date (RFC 9110), as the app's have
        assert body["status"] == status and body["type"].startswith(PROBLEM_BASE) and body["detail"], body
        assert body["title"] == TITLES[status], body


def test_the_guards_refusals_are_problems(port: int) -> None:
    """The 408, 431 and 503 the guards send before any app sees the request carry a problem+json
    body, as every other error of the API does (they had none)."""
    answers: dict[tuple[int, str], bytes] = {}
    sent = {
        (408, "header timeout"): b"GET /slow?s=0 HTTP/1.1\r\nHost: x\r\n",  # and no more
        (408, "body timeout"): b"POST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: 10\r\n\r\n12345",  # half the body
        (431, f"more than {MAX_HEAD_BYTES} bytes"): b"GET /slow?s=0 HTTP/1.1\r\nHost: x\r\nX-Long: " + b"a" * MAX_HEAD_BYTES,
    }
    for key, request_bytes in sent.items():
        with socket.create_connection(("127.0.0.1", port)) as sock:
            with contextlib.suppress(OSError):  # refused mid-send
                sock.sendall(request_bytes)
            answers[key], closed = _until_closed(sock, 10.0)
            assert closed is not None, key
    chosen = free_port()
    config = uvicorn.Config(APP, host="127.0.0.1", port=chosen, http=protocol_for(Settings(max_connections=1)), loop="asyncio")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        with socket.create_connection(("127.0.0.1", chosen)) as held:
            held.sendall(b"GET /slow?s=0 HTTP/1.1\r\nHost: x\r\n\r\n")
            assert held.recv(65536).startswith(b"HTTP/1.1 200")  # open, and counted
            with socket.create_connection(("127.0.0.1", chosen)) as sock:
                answers[(503, "SPACEARM_MAX_CONNECTIONS")], closed = _until_closed(sock, 10.0)
                assert closed is not None
    finally:
        server.should_exit = True
        thread.join(10)
    assert _problem(answers[(503, "SPACEARM_MAX_CONNECTIONS")])[1]["retry-after"] == "1"
    _refused_as_problems(answers)


@pytest.mark.parametrize(
    ("request_bytes", "reason"),
    [
        (b"GET /slow?s=0 HTTP/1.1\r\nHost: x\r\nIdempotency-Key: bad \x01\r\n\r\n", "Invalid header value char"),
        (b"POST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", "Content-Length"),
        (b"GARBAGE\r\n\r\n", "Invalid method"),
        (b"GET http://a:99999999/ HTTP/1.1\r\nHost: x\r\n\r\n", "invalid url"),  # raised in uvicorn's callback
    ],
)
def test_a_request_the_parser_refuses_is_a_problem_with_its_reason(port: int, request_bytes: bytes, reason: str) -> None:
    """uvicorn answered these "Invalid HTTP request received." as text/plain."""
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(request_bytes)
        answer, closed = _until_closed(sock, 10.0)
    assert closed is not None
    status, headers, body = _problem(answer)
    assert status == 400 and headers["content-type"] == "application/problem+json", answer
    assert body["detail"].startswith("not a valid HTTP request: ") and reason in body["detail"], body
    assert body["status"] == 400 and body["title"] == "Bad Request" and "date" in headers, body


def test_a_request_the_parser_refuses_behind_an_answer_under_way_waits_for_it(port: int) -> None:
    """A malformed request pipelined behind one whose answer is under way: that answer whole, then
    the connection closes (the 400 had replaced it, or landed inside a streamed answer); a body
    that breaks its framing after its request's answer has started gets no second answer."""
    for first in (b"GET /slow?s=0.3 HTTP/1.1\r\nHost: x\r\n\r\n", b"GET /stream HTTP/1.1\r\nHost: x\r\n\r\n"):
        with socket.create_connection(("127.0.0.1", port)) as sock:
            sock.sendall(first + b"GARBAGE\r\n\r\n")
            answer, closed = _until_closed(sock, 10.0)
        assert closed is not None and answer.startswith(b"HTTP/1.1 200"), answer
        assert b"400" not in answer and (b"slept 0.3" in answer or answer.endswith(b"tick11\n\r\n0\r\n\r\n")), answer
    chunked = b"POST /nope HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(chunked)
        time.sleep(0.3)  # the 404 is sent without reading the body
        sock.sendall(b"zz\r\nbad\r\n")  # not a chunk-size line
        answer, closed = _until_closed(sock, 10.0)
    assert closed is not None and answer.startswith(b"HTTP/1.1 404") and answer.count(b"HTTP/1.1") == 1, answer
