"""The HTTP server (uvicorn, its httptools protocol) with the guards uvicorn has no setting for:
slow clients are cut off, open connections are capped, request heads are bounded, and running
out of file descriptors is logged once instead of once a second with a traceback.

- **Header timeout.** A request's line and headers must arrive within ``header_timeout_s`` of the
  connection's start (or of the first byte of a later request on a kept-alive connection; the
  silence between requests is uvicorn's keep-alive timeout). Then a 408 and the connection closes.
- **Body timeout.** A body must arrive within ``body_timeout_s``, plus a second for every
  ``body_min_rate`` bytes received (Apache's ``mod_reqtimeout`` rule: a large body sent at a
  decent rate is never cut, a trickle is). Then a 408 (if no response has started) and the
  connection closes; the handler waiting for the body sees the client gone.
- **Send timeout.** An answer whose client reads nothing of it for ``send_timeout_s`` (writing
  paused, and the transport's buffer no smaller than it was ``send_timeout_s`` before) is cut:
  the connection is aborted (nginx's ``send_timeout``: the time between two successive writes,
  not for the whole answer). A client that sent requests and never read held its connection, its
  slot under the cap and its answers' bytes in the server for ever (300 pipelined
  ``GET /openapi.json``: 61 MB waiting in the API).
- **Head size.** A request's line and headers take at most :data:`MAX_HEAD_BYTES` (16 KiB, h11's
  limit, which uvicorn's h11 protocol applied); a longer head is a 431 and the connection closes.
  httptools has no limit of its own: it would gather a header without end.
- **Connection cap.** At most ``max_connections`` connections are open; a new one beyond gets a
  503 with ``Retry-After`` and is closed at once (a refusal costs a file descriptor for a moment
  only). By default the cap is 1000, or less when the process's file-descriptor limit
  (``ulimit -n``) is lower: the limit less a reserve for the database connections, the
  process's own files and the connections a burst brings in before they are refused (asyncio
  accepts up to :data:`BACKLOG` at a time), so the accept loop does not run out of descriptors.
- **Refusals.** The guards' 408, 431 and 503, and the 400 of a request the parser refuses (with
  the parser's reason; uvicorn sent it as plain text), are problem+json like the app's errors
  (:class:`Canned`), and none of them replaces an answer owed before it.
- **Out of descriptors.** When accepting fails for want of descriptors anyway, asyncio reports it
  to the event loop's exception handler with a traceback for every connection waiting, and pauses
  accepting for a second; here it is one warning a minute (with the count of the others).

The protocol is httptools' (llhttp, in C) rather than h11's (pure Python): parsing a request and
writing its response took 0.13 ms less of the server's CPU a request (a paper plan's request with
its answer made in advance, alternated servers, 40 rounds of 50 requests).

A front proxy (nginx's ``client_header_timeout``, ``client_body_timeout``, ``limit_conn``,
``large_client_header_buffers``) may do the same in front of the API; these guards hold without one.
"""

from __future__ import annotations

import array
import asyncio
import logging
import resource
import socket
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, ClassVar

import httptools
import uvicorn
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from service.errors import PROBLEM_JSON, TITLES, problem_body
from service.infra.jsonio import dumps
from service.infra.settings import Settings

log = logging.getLogger("spacearm.api")

DEFAULT_MAX_CONNECTIONS = 1000
#: File descriptors kept for the process itself (logs, libraries), besides the database's.
RESERVED_FDS = 64
#: The listening socket's backlog, which is also how many connections asyncio accepts at a time.
BACKLOG = 128
#: The most bytes a request's line and headers may take (with the blank line that ends them).
MAX_HEAD_BYTES = 16 * 1024


@dataclass(frozen=True)
class Canned:
    """An answer the guards send before any request reaches the app: ``status`` with a problem+json
    body as every other error of the API has (:func:`service.errors.problem_body`), then the
    connection closes."""

    status: int
    detail: str
    headers: tuple[tuple[bytes, bytes], ...] = ()

    def encode(self, default_headers: Iterable[tuple[bytes, bytes]] = ()) -> bytes:
        """The whole HTTP/1.1 answer, with uvicorn's ``default_headers`` (``date``, ``server``)."""
        body = dumps(problem_body(self.status, self.detail))
        head = [f"HTTP/1.1 {self.status} {TITLES[self.status]}\r\n".encode("latin-1")]
        for name, value in (*default_headers, *self.headers):
            head += [name, b": ", value, b"\r\n"]
        head.append(
            f"content-type: {PROBLEM_JSON}\r\nx-content-type-options: nosniff\r\nconnection: close\r\n"
            f"content-length: {len(body)}\r\n\r\n".encode("latin-1")
        )
        return b"".join(head) + body


REFUSED = Canned(
    503,
    "the API has as many connections open as it takes (SPACEARM_MAX_CONNECTIONS): try again in a second",
    ((b"retry-after", b"1"),),
)
HEAD_TIMED_OUT = Canned(
    408, "the request's line and headers did not arrive within the header timeout (SPACEARM_HEADER_TIMEOUT_S)"
)
BODY_TIMED_OUT = Canned(
    408,
    "the request's body did not arrive within the body timeout (SPACEARM_BODY_TIMEOUT_S, plus a second per "
    "SPACEARM_BODY_MIN_RATE bytes received)",
)
HEAD_TOO_LARGE = Canned(
    431, f"the request's line and headers take more than {MAX_HEAD_BYTES} bytes (a chunked body's framing counts alike)"
)
HEAD_END = b"\r\n\r\n"
#: How often a connection whose awaited bytes the server holds back checks whether they flow again.
HELD_POLL_S = 0.5
ACCEPT_EXHAUSTED = "socket.accept() out of system resource"


@dataclass(frozen=True)
class Guards:
    """The limits of :class:`GuardedProtocol`."""

    max_connections: int
    header_timeout_s: float
    body_timeout_s: float
    body_min_rate: float
    send_timeout_s: float


def fd_limit() -> int:
    """The soft limit of open file descriptors of this process."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return soft if soft != resource.RLIM_INFINITY else 1 << 20


def guards_of(settings: Settings) -> Guards:
    """The guards of ``settings``; the default connection cap fits the file-descriptor limit (each
    SQLite connection of the pools holds up to three: the database, its WAL and shared memory; a
    burst may bring in two backlogs' worth before they are refused)."""
    reserve = RESERVED_FDS + 3 * (settings.pool_size() + 2) + 2 * BACKLOG
    fits = max(16, fd_limit() - reserve)
    cap = settings.max_connections or min(DEFAULT_MAX_CONNECTIONS, fits)
    if cap > fits:
        log.warning(
            "SPACEARM_MAX_CONNECTIONS=%d is above what the file-descriptor limit (%d) leaves for connections (%d): "
            "the API may run out of descriptors",
            cap,
            fd_limit(),
            fits,
        )
    return Guards(cap, settings.header_timeout_s, settings.body_timeout_s, float(settings.body_min_rate), settings.send_timeout_s)


class _Parser(httptools.HttpRequestParser):
    """httptools' request parser, keeping the reason of the error that ends the connection (uvicorn
    catches it and says only "Invalid HTTP request received.")."""

    reason = ""

    def feed_data(self, data: bytes | bytearray | memoryview | array.array[int]) -> None:
        try:
            super().feed_data(data)
        except httptools.HttpParserError as exc:
            cause = exc.__context__ if isinstance(exc, httptools.HttpParserCallbackError) else exc
            if isinstance(cause, httptools.HttpParserError):  # the parser's, or the URL parser's in a callback
                self.reason = str(cause)
            else:  # a callback failed (the server's fault, not the request's): say so in the log
                log.error("parsing a request failed in a callback", exc_info=cause)
            raise


class _Throttled:
    """Logs a warning at most once per ``every_s`` (with the count of the events in between)."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.last = -float("inf")
        self.suppressed = 0

    def warn(self, message: str, *args: Any) -> None:
        now = time.monotonic()
        if now - self.last < self.every_s:
            self.suppressed += 1
            return
        more = f" ({self.suppressed} more since the last warning)" if self.suppressed else ""
        log.warning(message + more, *args)
        self.last, self.suppressed = now, 0


REFUSALS = _Throttled(60.0)
STALLED = _Throttled(60.0)


class GuardedProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with the header and body timeouts, the head size limit and the
    connection cap of :attr:`guards` (a subclass per server sets it: :func:`protocol_for`)."""

    guards: ClassVar[Guards]

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.parser = _Parser(self)  # as uvicorn's, with its leniency
        self.parser.set_dangerous_leniencies(lenient_data_after_close=True)
        # what the connection waits for from the client: "headers" (a head under way), "body" (the
        # body of the request last headed), "idle" (nothing, after a request answered before its
        # body was read: uvicorn's keep-alive timer stopped at that body), or None (nothing: an
        # answer is under way, or uvicorn keeps the connection alive); a pending timer finds
        # nothing to do in None
        self._phase: str | None = None
        self._deadline = 0.0  # the phase's, on the loop's clock (a body's grows with its bytes)
        self._body_bytes = 0
        self._framing = 0  # bytes read in a body since its last body byte (chunk lines, trailers)
        # the deadline passed while an earlier request's answer was under way: checked at its end
        self._overdue = False
        self._close_after = False  # refused while an answer was under way: close once it is out
        # the server held back the bytes awaited (flow control, Expect: 100-continue) when the timer
        # last fired: it fires every HELD_POLL_S until they flow, then gives them their full time
        self._held = False
        # one timer at a time, re-armed when it fires early: two timers a request cost 0.03 ms
        self._timer: asyncio.TimerHandle | None = None
        self._send_timer: asyncio.TimerHandle | None = None  # armed while writing is paused
        self._send_left = 0  # bytes the transport held when the send timer was armed
        self._head_bytes = 0  # of the head being received, before this read
        self._head_tail = b""  # its last bytes (its end may straddle two reads)

    def send_400_response(self, msg: str) -> None:
        """A request the parser refused (a malformed line or header, a control character in a
        header value, a body framed both by ``Content-Length`` and chunks): a problem+json 400 with
        the parser's reason, where uvicorn sends ``msg`` ("Invalid HTTP request received.") as
        plain text, then the connection closes; as a 408 or 431 does, it waits for an answer owed
        before it (:meth:`_refuse`), and a request whose answer has started gets no second one."""
        reason = self.parser.reason if isinstance(self.parser, _Parser) else ""
        detail = f"not a valid HTTP request: {reason}" if reason else "not a valid HTTP request"
        if self._phase == "body" and not self.pipeline and self.cycle is not None and self.cycle.response_started:
            self._phase = None  # its body broke its framing after its answer started: that answer, then close
            if self.cycle.response_complete:
                self.transport.close()
            else:
                self._close_after = True
                self.transport.pause_reading()
            return
        self._refuse(Canned(400, detail))

    def _send(self, answer: Canned) -> None:
        self.transport.write(answer.encode(self.server_state.default_headers))

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        if len(self.server_state.connections) >= self.guards.max_connections:
            self.transport = transport  # for connection_lost
            transport.write(REFUSED.encode(self.server_state.default_headers))
            transport.close()
            REFUSALS.warn("refused connections: %d are open (SPACEARM_MAX_CONNECTIONS)", self.guards.max_connections)
            return
        super().connection_made(transport)
        self._start("headers")

    def connection_lost(self, exc: Exception | None) -> None:
        self._phase = None
        for timer in (self._timer, self._send_timer):
            if timer is not None:
                timer.cancel()
        self._timer = self._send_timer = None
        super().connection_lost(exc)

    def pause_writing(self) -> None:
        super().pause_writing()
        if self._send_timer is None:
            self._arm_send_timer()

    def resume_writing(self) -> None:
        super().resume_writing()
        if self._send_timer is not None:
            self._send_timer.cancel()
            self._send_timer = None

    def _arm_send_timer(self) -> None:
        self._send_left = self.transport.get_write_buffer_size()
        self._send_timer = self.loop.call_later(self.guards.send_timeout_s, self._send_stalled)

    def _send_stalled(self) -> None:
        """Writing stayed paused for the send timeout: if the client read some of the answer
        meanwhile (the buffer shrank; a whole answer is written at once, so it stays above the
        low-water mark until nearly all of it is out), time it again; else abort (a close would
        wait to send the rest)."""
        self._send_timer = None
        if not self.flow.write_paused:
            return
        if self.transport.get_write_buffer_size() < self._send_left:
            self._arm_send_timer()
            return
        timeout = self.guards.send_timeout_s
        STALLED.warn("cut an answer whose client read nothing of it for %g s (SPACEARM_SEND_TIMEOUT_S)", timeout)
        self.transport.abort()

    def data_received(self, data: bytes) -> None:
        if self._close_after:
            return  # refused: what follows is not read
        if self._phase != "body":  # the bytes are (the start of) a request's head
            if self._head_too_large(data):
                self._refuse(HEAD_TOO_LARGE)
                return
            if self._phase in (None, "idle") and data:
                # any byte starts a head's clock: llhttp skips a CR LF before a request line without
                # a callback, and uvicorn's keep-alive timer stops at any byte
                self._start("headers")
        in_body, before = self._phase == "body", self._body_bytes
        super().data_received(data)
        if not (in_body and self._phase == "body") or self.transport.is_closing():
            return
        # a chunked body's lines and trailers reach no callback until complete: httptools gathers
        # a trailer without end (quadratically); bounded as a head is, between body bytes
        self._framing = self._framing + len(data) if self._body_bytes == before else 0
        if self._framing > MAX_HEAD_BYTES:
            self._refuse(HEAD_TOO_LARGE)

    def _refuse(self, answer: Canned) -> None:
        """Refuse the request being received: ``answer`` and close, or, while an earlier request's
        answer is under way (it is owed first), read no more and close once it is out."""
        earlier = self._earlier_answer()  # of the phase the refusal ends
        self._phase = None
        if earlier:
            self._close_after = True
            self.transport.pause_reading()
        else:
            self._send(answer)
            self.transport.close()

    def _head_too_large(self, data: bytes) -> bool:
        """Whether the head being received, with ``data``, is over :data:`MAX_HEAD_BYTES`. Bytes
        after a head's end in the same read (a pipelined request's head) count from the next read
        on: a head takes at most the limit and one read (asyncio reads 256 KiB at most)."""
        window = self._head_tail + data[: MAX_HEAD_BYTES + len(HEAD_END)]
        end = window.find(HEAD_END)
        if end < 0:
            size = self._head_bytes + len(data)
            self._head_bytes, self._head_tail = size, window[-(len(HEAD_END) - 1) :]
        else:
            size = self._head_bytes + end + len(HEAD_END) - len(self._head_tail)
            self._head_bytes, self._head_tail = 0, b""
        return size > MAX_HEAD_BYTES

    def on_message_begin(self) -> None:
        super().on_message_begin()
        if self._phase != "headers":
            self._start("headers")

    def on_headers_complete(self) -> None:
        super().on_headers_complete()
        self._body_bytes = self._framing = self._head_bytes = 0
        self._head_tail = b""
        if self._upgrading():
            self._phase = None  # the connection is the WebSocket protocol's from here
        else:
            self._start("body")  # until the message is complete
            if self.cycle.waiting_for_100_continue:  # the client waits until the handler asks
                self._held = True
                self._poll()

    def on_body(self, body: bytes) -> None:
        super().on_body(body)
        self._body_bytes += len(body)

    def on_message_complete(self) -> None:
        super().on_message_complete()
        if self._upgrading():
            return  # the connection is the WebSocket protocol's
        if self._answering():
            self._phase = None  # the rest is the handler's
        else:  # answered before its body was read (a 404, a refusal): kept alive from here
            self._start("idle")

    def on_response_complete(self) -> None:
        if self._close_after:
            self.transport.close()  # the answer owed before a refused request is out
        super().on_response_complete()  # starts the next queued request, if any
        if self.transport.is_closing():
            return
        phase = self._phase
        if phase == "body" or (phase == "headers" and self._overdue):
            # what uvicorn did not read while an earlier answer was under way (a queued request's
            # body, the rest of a head; or the body of a request answered early): its time from now
            self._overdue = False
            self._start(phase)

    def _upgrading(self) -> bool:
        """Whether the request being read hands the connection to the WebSocket protocol (as
        uvicorn decides it)."""
        return bool(self.parser.should_upgrade()) and self._should_upgrade()

    def _answering(self) -> bool:
        """Whether an answer is under way (``self.cycle`` is the last request headed; the ones
        before it are answered first)."""
        return self.cycle is not None and not self.cycle.response_complete

    def _earlier_answer(self) -> bool:
        """Whether the answer of a request before the one awaited is under way (the awaited one's
        timeout must not cut it)."""
        if self._phase == "body":
            return bool(self.pipeline)  # the awaited request is queued behind another
        return self._answering()  # a head under way: every request headed came before it

    def _timeout_s(self, phase: str) -> float:
        """The time a phase gets: the guards' for a head or a body, uvicorn's keep-alive when idle."""
        if phase == "headers":
            return self.guards.header_timeout_s
        return self.guards.body_timeout_s if phase == "body" else float(self.config.timeout_keep_alive)

    def _start(self, phase: str) -> None:
        self._phase = phase
        self._held = False
        self._deadline = self.loop.time() + self._timeout_s(phase)
        if self._timer is not None and self._timer.when() > self._deadline:
            self._timer.cancel()  # it would fire too late
            self._timer = None
        if self._timer is None:
            self._timer = self.loop.call_at(self._deadline, self._expire)

    def _poll(self) -> None:
        """Fire again in :data:`HELD_POLL_S` (instead of at the deadline)."""
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.loop.call_later(HELD_POLL_S, self._expire)

    def _expire(self) -> None:
        self._timer = None
        if self._phase is None or self.transport is None or self.transport.is_closing():
            return
        now = self.loop.time()
        if self._phase != "idle":
            held = self.flow is not None and self.flow.read_paused  # the server holds the bytes back
            if self._phase == "body":  # nor has it asked for the body yet (Expect: 100-continue)
                held = held or (self.cycle is not None and self.cycle.waiting_for_100_continue)
            if held:
                self._held = True
                self._poll()
                return
            if self._held:  # they flow again: their full time from now
                self._held = False
                self._deadline = max(self._deadline, now + self._timeout_s(self._phase))
        deadline = self._deadline
        if self._phase == "body":
            deadline += self._body_bytes / self.guards.body_min_rate  # a second more per body_min_rate bytes
        if now < deadline:  # armed for an earlier phase, or the body is flowing
            self._timer = self.loop.call_at(deadline, self._expire)
            return
        if self._earlier_answer():
            self._overdue = True  # checked again when that answer is out
            return
        if self._phase == "idle":
            self.transport.close()  # kept alive long enough: nothing to answer
            return
        # a 408 answers the request awaited, unless it has had an answer (sent before its body)
        if self._phase == "headers":
            self._send(HEAD_TIMED_OUT)
        elif not self.cycle.response_started:
            self._send(BODY_TIMED_OUT)
        self._phase = None
        self.transport.close()


def protocol_for(settings: Settings) -> type[GuardedProtocol]:
    """A :class:`GuardedProtocol` with the guards of ``settings``."""
    return type("GuardedProtocol", (GuardedProtocol,), {"guards": guards_of(settings)})


OUT_OF_DESCRIPTORS = _Throttled(60.0)


def _exception_handler(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    if context.get("message") == ACCEPT_EXHAUSTED:
        OUT_OF_DESCRIPTORS.warn(
            "cannot accept connections: %s (raise the file-descriptor limit, ulimit -n, or lower "
            "SPACEARM_MAX_CONNECTIONS); accepting again in a second",
            context.get("exception") or "out of file descriptors",
        )
        return
    loop.default_exception_handler(context)


class GuardedServer(uvicorn.Server):
    """uvicorn's server with :func:`_exception_handler` on its event loop."""

    async def startup(self, sockets: Any = None) -> None:
        asyncio.get_running_loop().set_exception_handler(_exception_handler)
        await super().startup(sockets=sockets)


def serve(app: Any, settings: Settings, log_level: str, log_config: dict[str, Any] | None) -> None:
    """Run ``app`` on ``settings.host:settings.port`` until stopped (SIGTERM, Ctrl-C)."""
    protocol = protocol_for(settings)
    log.info(
        "HTTP guards: at most %d connections, headers within %g s, bodies within %g s + 1 s per %d bytes, "
        "answers read within %g s",
        protocol.guards.max_connections,
        settings.header_timeout_s,
        settings.body_timeout_s,
        settings.body_min_rate,
        settings.send_timeout_s,
    )
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        http=protocol,
        # asyncio's loop, even where uvloop is installed (uvicorn's "auto" would take it): the
        # guards above rely on asyncio's accept loop and exception handler (with uvloop, running
        # out of descriptors was not logged at all)
        loop="asyncio",
        backlog=BACKLOG,
        log_level=log_level,
        log_config=log_config,
    )
    if settings.api_processes > 1:
        GuardedServer(config).run(sockets=[shared_port_socket(settings.host, settings.port)])
    else:
        GuardedServer(config).run()


def shared_port_socket(host: str, port: int) -> socket.socket:
    """A socket bound to ``host:port`` with ``SO_REUSEPORT``: the API processes of one
    ``spacearm run`` bind the same port, and the kernel spreads new connections over them."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # IPPROTO_TCP named, not left 0: asyncio sets TCP_NODELAY only on connections whose socket says
    # it (the accepted ones inherit the listener's), and without it Nagle's algorithm held each
    # response's body behind its headers until the client's delayed ACK, 40 ms later
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    sock.bind((host, port))
    return sock
