"""The appliance's small HTTP server (default port 8080): ``/healthz``, ``/metrics`` and the dashboard (``/``).

Routes are plain functions ``Request -> Response`` registered with :meth:`HttpServer.route`; a response may carry a
``stream`` of chunks (server-sent events, MJPEG) instead of a body. Runs on its own threads (one per request), so
a slow client never touches the tracker.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlsplit

from edge.errors import EdgeIpsError

log = logging.getLogger("edge.http")

MAX_BODY_BYTES = 64 * 1024  # the largest request body read (the dashboard's commands are a few hundred bytes)


@dataclass(frozen=True)
class Request:
    method: str
    path: str
    query: dict[str, list[str]]
    headers: dict[str, str]
    body: bytes


@dataclass
class Response:
    status: int = 200
    body: bytes = b""
    content_type: str = "text/plain; charset=utf-8"
    headers: dict[str, str] = field(default_factory=dict)
    stream: Iterator[bytes] | None = None


Handler = Callable[[Request], Response]


class HttpServer:
    """A threaded HTTP server with exact-path routes for GET and POST."""

    def __init__(self, host: str = "0.0.0.0", port: int = 8080) -> None:
        self.host, self._port = host, port
        self.routes: dict[tuple[str, str], Handler] = {}
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return self._port

    def route(self, path: str, handler: Handler, *, method: str = "GET") -> None:
        self.routes[(method.upper(), path)] = handler

    def _handler_class(self) -> type[BaseHTTPRequestHandler]:
        routes = self.routes

        class _Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def _serve(self, method: str) -> None:
                parts = urlsplit(self.path)
                handler = routes.get((method, parts.path))
                if handler is None:
                    known = any(p == parts.path for _, p in routes)
                    self._send(Response(405 if known else 404, b"method not allowed\n" if known else b"not found\n"))
                    return
                try:
                    length = int(self.headers.get("Content-Length") or 0)
                except ValueError:
                    length = -1
                if length < 0 or length > MAX_BODY_BYTES:
                    self.close_connection = True  # the body is not read: the connection cannot be reused
                    self._send(Response(413 if length > 0 else 400, b"request body too large or malformed\n"))
                    return
                body = self.rfile.read(length) if length > 0 else b""
                request = Request(method, parts.path, parse_qs(parts.query), dict(self.headers.items()), body)
                try:
                    response = handler(request)
                except Exception as exc:
                    log.error("http %s %s failed: %s: %s", method, parts.path, type(exc).__name__, exc)
                    response = Response(500, b"internal error\n")
                self._send(response)

            def _send(self, response: Response) -> None:
                self.send_response(response.status)
                self.send_header("Content-Type", response.content_type)
                self.send_header("Cache-Control", "no-store")
                for key, value in response.headers.items():
                    self.send_header(key, value)
                if response.stream is None:
                    self.send_header("Content-Length", str(len(response.body)))
                    self.end_headers()
                    try:
                        self.wfile.write(response.body)
                    except (BrokenPipeError, ConnectionResetError):
                        self.close_connection = True  # the client went away before the answer (a closed page)
                    return
                self.send_header("Connection", "close")
                self.end_headers()
                self.close_connection = True
                try:
                    for chunk in response.stream:
                        self.wfile.write(chunk)
                        self.wfile.flush()
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client went away: the normal end of a stream
                finally:
                    close = getattr(response.stream, "close", None)
                    if close is not None:
                        close()  # a generator's cleanup (an event stream unsubscribing) runs now, not at GC

            def handle(self) -> None:
                # a page closed while its keep-alive connection waited for the next request: nothing to report
                with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                    super().handle()

            def do_GET(self) -> None:
                self._serve("GET")

            def do_POST(self) -> None:
                self._serve("POST")

            def log_message(self, format: str, *args: object) -> None:
                log.debug("http %s %s", self.address_string(), format % args)

        return _Handler

    def start(self) -> HttpServer:
        """Bind and serve; raises :class:`EdgeIpsError` naming the port when it is taken."""
        try:
            server = ThreadingHTTPServer((self.host, self._port), self._handler_class())
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise EdgeIpsError(
                    f"http: port {self._port} on {self.host} is already in use; choose another with --http-port "
                    "or http.port in the configuration (or turn it off with http.enabled = false)"
                ) from exc
            raise EdgeIpsError(f"http: cannot listen on {self.host}:{self._port}: {exc.strerror}") from exc
        server.daemon_threads = True
        self._server = server
        self._port = int(server.server_address[1])
        self._thread = threading.Thread(target=server.serve_forever, name="http", daemon=True)
        self._thread.start()
        log.info("http server on %s:%d (/healthz, /metrics)", self.host, self._port)
        return self

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
