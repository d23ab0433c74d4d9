"""The appliance's HTTP server (default port 8080): ``/healthz``, ``/metrics`` and the dashboard (``/``).

aiohttp's low-level server on an asyncio loop of its own thread (``http``, background priority: the tracker comes
first). A connection costs a socket and a little memory, not a thread, and the server keeps them in bounds:

- **Connection cap** (``http.max_connections``): beyond it, a new connection closes the oldest one that has no
  request in progress (idle, or still sending its request), as nginx does when it runs short; when every one is
  busy the new one is closed. So idle or half-open connections cannot keep a health check out.
- **Request timeout** (``http.request_timeout_s``): a connection must deliver a whole request head within it
  (slowloris), its body too, and idle keep-alive connections are closed after it; a response that the client does
  not read within it is abandoned.
- **Streams** (``http.max_streams``): at most this many long responses (event streams) at once.
- **Who may ask** (:mod:`edge.httpguard`): the ``Host`` allow-list, then the route's access level and token.

Routes are exact paths with a function ``Request -> Response``: a plain function runs on a small pool of worker
threads (it may block: a broker round trip), an ``async def`` on the loop (it must not block); a response may carry
an async ``stream`` of chunks instead of a body (server-sent events). Register them with :meth:`HttpServer.route`,
naming the access level: ``open``, ``read`` (a token when one is set), ``control`` or ``stop`` (:mod:`edge.httpguard`).
"""

from __future__ import annotations

import asyncio
import errno
import inspect
import json
import logging
import socket
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast
from urllib.parse import parse_qs

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError
from aiohttp.web_protocol import RequestHandler

from edge.errors import EdgeIpsError
from edge.httpguard import Access, AccessGuard, HostAllowList, Tokens
from edge.priority import background_priority

if TYPE_CHECKING:
    from edge.config import DashboardSection, HttpSection

log = logging.getLogger("edge.http")


class _MalformedRequests(logging.Filter):
    """aiohttp logs a malformed request (a header line too long, TLS on the plain port) with a traceback, at ERROR
    for some: anyone could fill the log. It is answered 400; here it is one debug line."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            log.debug("http: malformed request: %s", " ".join(str(exc.message).split())[:200])
            return False
        return True


protocol_log = logging.getLogger("edge.http.protocol")  # aiohttp's messages about connections and requests
protocol_log.addFilter(_MalformedRequests())

MAX_BODY_BYTES = 64 * 1024  # the largest request body read (the dashboard's commands are a few hundred bytes)
MAX_HEADER_BYTES = 8190  # per request line and per header field
SECURITY_HEADERS = {
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",  # the controls cannot be framed by another page (clickjacking)
    "Referrer-Policy": "no-referrer",  # a token in a URL is not sent on
    "Server": "edge-ips",
}


@dataclass(frozen=True)
class Request:
    method: str
    path: str
    query: dict[str, list[str]]
    headers: dict[str, str]
    body: bytes
    client: str = ""  # the peer's address


@dataclass
class Response:
    status: int = 200
    body: bytes = b""
    content_type: str = "text/plain; charset=utf-8"
    headers: dict[str, str] = field(default_factory=dict)
    stream: AsyncIterator[bytes] | None = None
    close_connection: bool = False  # the request was not read whole: the connection cannot be reused


Handler = Callable[[Request], Response] | Callable[[Request], Awaitable[Response]]


@dataclass(frozen=True)
class HttpLimits:
    max_connections: int = 64
    request_timeout_s: float = 10.0
    max_streams: int = 16
    workers: int = 4


@dataclass
class HttpStats:
    """Counters for ``/metrics`` (written on the server's loop only)."""

    connections: int = 0
    evicted: int = 0  # closed to make room for a new connection
    refused: int = 0  # new connections closed because every one was busy
    timed_out: int = 0  # closed for not sending a request in time
    host_refused: int = 0
    streams_open: int = 0
    responses: dict[int, int] = field(default_factory=dict)


@dataclass(frozen=True)
class _Route:
    handler: Handler
    access: Access
    is_async: bool


@dataclass(slots=True)
class _Connection:
    transport: asyncio.Transport
    requests: int = 0
    busy: int = 0
    deadline: asyncio.TimerHandle | None = None


def json_response(status: int, data: Any) -> Response:
    body = json.dumps(data, separators=(",", ":"), allow_nan=False).encode()
    return Response(status, body, "application/json")


async def _close(stream: AsyncIterator[bytes]) -> None:
    close = getattr(stream, "aclose", None)  # an async generator's cleanup (unsubscribing) runs now, not at GC
    if close is not None:
        await close()


class _CappedServer(web.Server):
    """aiohttp's low-level server telling its owner about each connection as it opens and closes."""

    def __init__(self, owner: HttpServer, **kwargs: Any) -> None:
        super().__init__(owner._handle, **kwargs)
        self._owner = owner

    def connection_made(self, handler: RequestHandler, transport: asyncio.Transport) -> None:
        super().connection_made(handler, transport)
        self._owner._opened(handler, transport)

    def connection_lost(self, handler: RequestHandler, exc: BaseException | None = None) -> None:
        super().connection_lost(handler, exc)
        self._owner._lost(handler)


class HttpServer:
    """The HTTP server: exact-path routes for GET and POST, limits and access checks (see the module docstring)."""

    def __init__(
        self,
        host: str = "0.0.0.0",
        port: int = 8080,
        *,
        limits: HttpLimits | None = None,
        hosts: HostAllowList | None = None,
        tokens: Tokens | None = None,
    ) -> None:
        self.host, self._port = host, port
        self.limits = limits or HttpLimits()
        self.hosts = hosts or HostAllowList.for_this_board()
        self.guard = AccessGuard(tokens or Tokens())
        self.routes: dict[tuple[str, str], _Route] = {}
        self.stats = HttpStats()
        self._connections: dict[RequestHandler, _Connection] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.ServerRunner | None = None
        self._thread: threading.Thread | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._host_log_mono = -float("inf")

    @classmethod
    def from_config(cls, http: HttpSection, dashboard: DashboardSection) -> HttpServer:
        """The server as ``[http]`` says, with the tokens of ``[dashboard]``."""
        token, viewer = (s.get_secret_value() if s else None for s in (dashboard.token, dashboard.viewer_token))
        return cls(
            http.host,
            http.port,
            limits=HttpLimits(http.max_connections, http.request_timeout_s, http.max_streams),
            hosts=HostAllowList.for_this_board(http.allowed_hosts),
            tokens=Tokens(token, viewer),
        )

    @property
    def port(self) -> int:
        return self._port

    @property
    def open_connections(self) -> int:
        return len(self._connections)

    def route(self, path: str, handler: Handler, *, method: str = "GET", access: Access = "open") -> None:
        """Serve ``method path`` with ``handler``; ``access``: ``open``, ``read``, ``control`` or ``stop``."""
        self.routes[(method.upper(), path)] = _Route(handler, access, inspect.iscoroutinefunction(handler))

    # -- connections ----------------------------------------------------------------------------------------------
    def _opened(self, handler: RequestHandler, transport: asyncio.Transport) -> None:
        loop = asyncio.get_running_loop()
        conn = _Connection(transport)
        self._connections[handler] = conn
        self.stats.connections += 1
        if len(self._connections) > self.limits.max_connections:
            idle = next((h for h, c in self._connections.items() if c.busy == 0 and h is not handler), None)
            if idle is None:
                self.stats.refused += 1
                self._close(handler)
                return
            self.stats.evicted += 1
            self._close(idle)
        conn.deadline = loop.call_later(self.limits.request_timeout_s, self._first_request_due, handler)

    def _first_request_due(self, handler: RequestHandler) -> None:
        # Later requests on a kept-alive connection are timed by aiohttp itself (keepalive_timeout: a connection
        # still waiting for a whole request when it expires is closed).
        conn = self._connections.get(handler)
        if conn is not None and conn.requests == 0:
            self.stats.timed_out += 1
            self._close(handler)

    def _close(self, handler: RequestHandler) -> None:
        """Close a connection now; it stops counting at once (its transport reports the loss a little later)."""
        conn = self._connections.pop(handler, None)
        if conn is not None:
            if conn.deadline is not None:
                conn.deadline.cancel()
            conn.transport.close()

    def _lost(self, handler: RequestHandler) -> None:
        conn = self._connections.pop(handler, None)
        if conn is not None and conn.deadline is not None:
            conn.deadline.cancel()

    # -- requests -------------------------------------------------------------------------------------------------
    async def _handle(self, raw: web.BaseRequest) -> web.StreamResponse:
        conn = self._connections.get(raw.protocol)
        if conn is not None:
            conn.requests += 1
            conn.busy += 1
            if conn.deadline is not None:
                conn.deadline.cancel()
        try:
            response = await self._respond(raw)
            self.stats.responses[response.status] = self.stats.responses.get(response.status, 0) + 1
            return await self._send(raw, response)
        finally:
            if conn is not None:
                conn.busy -= 1

    def _check_host(self, raw: web.BaseRequest) -> Response | None:
        sockname = raw.transport.get_extra_info("sockname") if raw.transport is not None else None
        local = sockname[0] if isinstance(sockname, tuple) else None
        host = raw.headers.get("Host")
        if self.hosts.allows(host, local):
            return None
        self.stats.host_refused += 1
        now = time.monotonic()
        if now - self._host_log_mono > 60.0:  # at most one line a minute: a rebinding page retries in a loop
            self._host_log_mono = now
            log.warning(
                "http: refused %s from %s (%d refused so far; allow more names with http.allowed_hosts)",
                f"Host {host!r}" if host else "a request without Host",
                raw.remote,
                self.stats.host_refused,
            )
        if not host:
            return Response(400, b"a Host header is required\n")
        return Response(
            421,
            f"this board does not answer to {host!r}: add the name to http.allowed_hosts to allow it\n".encode(),
        )

    async def _respond(self, raw: web.BaseRequest) -> Response:
        refused = self._check_host(raw)
        if refused is not None:
            return refused
        method, path = raw.method.upper(), raw.path
        route = self.routes.get((method, path))
        if route is None:
            known = any(p == path for _, p in self.routes)
            return Response(405, b"method not allowed\n") if known else Response(404, b"not found\n")
        headers = dict(raw.headers.items())
        query = parse_qs(raw.query_string)
        client = raw.remote or ""
        refusal = self.guard.check(
            route.access, method=method, path=path, headers=headers, query=query, client=client, now=time.monotonic()
        )
        if refusal is not None:
            response = json_response(refusal.status, {"error": refusal.error})
            response.headers.update(refusal.headers)
            return response
        body = await self._read_body(raw)
        if isinstance(body, Response):
            return body
        request = Request(method, path, query, headers, body, client)
        try:
            if route.is_async:
                return await cast(Awaitable[Response], route.handler(request))
            handler = cast(Callable[[Request], Response], route.handler)
            return await asyncio.get_running_loop().run_in_executor(self._executor, handler, request)
        except Exception as exc:
            log.error("http %s %s failed: %s: %s", method, path, type(exc).__name__, exc)
            return Response(500, b"internal error\n")

    async def _read_body(self, raw: web.BaseRequest) -> bytes | Response:
        length = raw.content_length
        if length is not None and length > MAX_BODY_BYTES:
            return Response(413, b"request body too large\n", close_connection=True)
        if not raw.body_exists:
            return b""
        chunks: list[bytes] = []
        size = 0
        try:
            async with asyncio.timeout(self.limits.request_timeout_s):
                while size <= MAX_BODY_BYTES:
                    chunk = await raw.content.read(MAX_BODY_BYTES + 1 - size)
                    if not chunk:
                        break
                    chunks.append(chunk)
                    size += len(chunk)
        except TimeoutError:
            return Response(408, b"request body not received in time\n", close_connection=True)
        if size > MAX_BODY_BYTES:
            return Response(413, b"request body too large\n", close_connection=True)
        return b"".join(chunks)

    async def _send(self, raw: web.BaseRequest, response: Response) -> web.StreamResponse:
        headers = {**SECURITY_HEADERS, **response.headers, "Content-Type": response.content_type}
        if response.stream is None:
            out = web.Response(status=response.status, body=response.body, headers=headers)
            if response.close_connection:
                out.force_close()
            try:
                await self._timed(out.prepare(raw))
                await self._timed(out.write_eof())
            except (ConnectionError, TimeoutError):  # the client went (reset) or stopped reading: no error of ours
                raw.protocol.force_close()
            return out
        if self.stats.streams_open >= self.limits.max_streams:
            await _close(response.stream)
            return await self._send(raw, Response(503, b"too many open streams; try again later\n"))
        stream = web.StreamResponse(status=response.status, headers=headers)
        self.stats.streams_open += 1
        try:
            await self._timed(stream.prepare(raw))
            async for chunk in response.stream:
                await self._timed(stream.write(chunk))
            await self._timed(stream.write_eof())
        except (ConnectionError, TimeoutError):
            raw.protocol.force_close()  # the client went away or stopped reading: the normal end of a stream
        finally:
            self.stats.streams_open -= 1
            await _close(response.stream)
        return stream

    async def _timed(self, step: Awaitable[Any]) -> Any:
        async with asyncio.timeout(self.limits.request_timeout_s):
            return await step

    # -- life cycle -----------------------------------------------------------------------------------------------
    def _bind(self) -> socket.socket:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        try:
            return socket.create_server((self.host, self._port), family=family, backlog=128)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise EdgeIpsError(
                    f"http: port {self._port} on {self.host} is already in use; choose another with --http-port "
                    "or http.port in the configuration (or turn it off with http.enabled = false)"
                ) from exc
            raise EdgeIpsError(f"http: cannot listen on {self.host}:{self._port}: {exc.strerror}") from exc

    def start(self) -> HttpServer:
        """Bind and serve; raises :class:`EdgeIpsError` naming the port when it is taken."""
        sock = self._bind()
        self._port = int(sock.getsockname()[1])
        self._executor = ThreadPoolExecutor(
            self.limits.workers, thread_name_prefix="http-worker", initializer=background_priority
        )
        loop = asyncio.new_event_loop()
        self._loop = loop
        self._thread = threading.Thread(target=self._serve, args=(loop,), name="http", daemon=True)
        self._thread.start()
        try:
            asyncio.run_coroutine_threadsafe(self._setup(sock), loop).result(timeout=30)
        except BaseException:
            self.stop()
            sock.close()
            raise
        what = f"{self.limits.max_connections} connections, {self.limits.request_timeout_s:g} s to send a request"
        log.info("http server on %s:%d (/healthz, /metrics); at most %s", self.host, self._port, what)
        return self

    def _serve(self, loop: asyncio.AbstractEventLoop) -> None:
        background_priority()
        asyncio.set_event_loop(loop)
        try:
            loop.run_forever()
        finally:
            loop.close()

    async def _setup(self, sock: socket.socket) -> None:
        server = _CappedServer(
            self,
            handler_cancellation=True,  # a client that goes away ends its handler (an event stream) at once
            keepalive_timeout=self.limits.request_timeout_s,
            access_log=None,
            logger=protocol_log,
            max_line_size=MAX_HEADER_BYTES,
            max_field_size=MAX_HEADER_BYTES,
        )
        self._runner = web.ServerRunner(server, shutdown_timeout=2.0)
        await self._runner.setup()
        await web.SockSite(self._runner, sock).start()

    def stop(self) -> None:
        loop, self._loop = self._loop, None
        if loop is not None and self._runner is not None:
            try:
                asyncio.run_coroutine_threadsafe(self._runner.cleanup(), loop).result(timeout=10)
            except (TimeoutError, RuntimeError) as exc:
                log.warning("http: server did not stop cleanly: %s", exc or type(exc).__name__)
            self._runner = None
        if loop is not None:
            loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
