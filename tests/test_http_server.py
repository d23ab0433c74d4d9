"""The HTTP server under abuse: idle and half-open connections, slow requests, oversized bodies, foreign Host
names, wrong tokens. First on a server in this process with small limits, then on a real ``edge-ips start``.

Waits are on sockets (the server closing one, a reply arriving) with generous guards; nothing asserts a time.
"""

from __future__ import annotations

import asyncio
import http.client
import json
import logging
import socket
import struct
import threading
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from edge.errors import EdgeIpsError
from edge.httpguard import HostAllowList, Tokens
from edge.httpserver import HttpLimits, HttpServer, Request, Response
from tests.support.dashboard import EdgeProcess, call, clean_env, edge_start

GUARD_S = 30.0  # how long a socket may take to see what the test waits for before the test fails
TOKEN = "dashboard-control-token"
PARTIAL_HEAD = b"GET /healthz HTTP/1.1\r\nHost: localhost\r\nX-Slow: "


def connect(port: int, source: str = "127.0.0.1") -> socket.socket:
    return socket.create_connection(("127.0.0.1", port), timeout=GUARD_S, source_address=(source, 0))


def closed_by_server(sock: socket.socket, feed: bytes | None = None, every_s: float = 0.1) -> bool:
    """True once the server closes ``sock`` (within GUARD_S). With ``feed``, one more byte of it is sent each
    ``every_s`` while waiting: a request trickled in as slowloris does."""
    sock.settimeout(every_s if feed else GUARD_S)
    for k in range(int(GUARD_S / every_s) if feed else 1):
        try:
            data = sock.recv(4096)
        except TimeoutError:
            if feed is not None:
                sock.sendall(feed[k % len(feed) : k % len(feed) + 1])
            continue
        except ConnectionResetError:
            return True
        return data == b"" or data.startswith(b"HTTP/1.1 4")
    return False


def read_until(sock: socket.socket, marker: bytes) -> bytes:
    """What ``sock`` receives up to and including ``marker`` (fails on a close or after GUARD_S)."""
    sock.settimeout(GUARD_S)
    got = b""
    while marker not in got:
        data = sock.recv(4096)
        assert data, f"closed before {marker!r}: {got!r}"
        got += data
    return got


def get(port: int, path: str, headers: dict[str, str] | None = None, source: str = "127.0.0.1") -> tuple[int, bytes]:
    return send("GET", port, path, headers, source)


def send(
    method: str,
    port: int,
    path: str,
    headers: dict[str, str] | None = None,
    source: str = "127.0.0.1",
    body: bytes = b"",
) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=GUARD_S, source_address=(source, 0))
    try:
        conn.request(method, path, body=body or None, headers=headers or {})
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


# -- a server in this process ----------------------------------------------------------------------------------------
class Streams:
    """A stream route whose chunks the test releases one at a time."""

    def __init__(self) -> None:
        self.release: asyncio.Event | None = None

    async def handler(self, request: Request) -> Response:
        return Response(200, content_type="text/event-stream", stream=self.chunks())

    async def chunks(self) -> AsyncIterator[bytes]:
        yield b"first\n"
        while True:
            self.release = self.release or asyncio.Event()
            await self.release.wait()
            self.release.clear()
            yield b"more\n"


@pytest.fixture
def server() -> Iterator[HttpServer]:
    async def pong(request: Request) -> Response:
        return Response(200, b"pong")

    def where(request: Request) -> Response:
        return Response(200, threading.current_thread().name.encode())

    def boom(request: Request) -> Response:
        raise RuntimeError("handler bug")

    def echo(request: Request) -> Response:
        return Response(200, str(len(request.body)).encode())

    http_server = HttpServer(
        "127.0.0.1",
        0,
        limits=HttpLimits(max_connections=8, request_timeout_s=0.5, max_streams=2, workers=2),
        hosts=HostAllowList(frozenset({"localhost"})),
        tokens=Tokens(TOKEN),
    )
    streams = Streams()
    http_server.route("/ping", pong)
    http_server.route("/where", where)
    http_server.route("/boom", boom)
    http_server.route("/echo", echo, method="POST", access="control")
    http_server.route("/stream", streams.handler, access="read")
    http_server.streams = streams  # type: ignore[attr-defined]
    http_server.start()
    try:
        yield http_server
    finally:
        http_server.stop()


def test_idle_connections_beyond_the_cap_close_the_oldest_idle_one_and_requests_get_through(
    server: HttpServer,
) -> None:
    idle = [connect(server.port) for _ in range(8)]
    assert get(server.port, "/ping") == (200, b"pong")  # a ninth connection: the oldest idle one made room
    assert closed_by_server(idle[0])
    more = [connect(server.port) for _ in range(30)]
    assert get(server.port, "/ping") == (200, b"pong")
    assert server.open_connections <= 8 and server.stats.evicted >= 30
    for sock in idle + more:
        sock.close()


def test_event_streams_in_progress_are_not_evicted_and_there_are_at_most_max_streams(server: HttpServer) -> None:
    auth = f"Authorization: Bearer {TOKEN}\r\n".encode()
    streams = []
    for _ in range(2):
        sock = connect(server.port)
        sock.sendall(b"GET /stream HTTP/1.1\r\nHost: localhost\r\n" + auth + b"\r\n")
        read_until(sock, b"first")
        streams.append(sock)
    assert get(server.port, "/stream", {"Authorization": f"Bearer {TOKEN}"})[0] == 503  # a third one
    idle = [connect(server.port) for _ in range(20)]
    assert get(server.port, "/ping") == (200, b"pong")
    release = server.streams.release  # type: ignore[attr-defined]
    assert release is not None and server._loop is not None
    server._loop.call_soon_threadsafe(release.set)
    for sock in streams:  # both streams are still open and get the next chunk
        read_until(sock, b"more")
    for sock in streams + idle:
        sock.close()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("sent", "trickle"),
    [
        (b"", None),  # connects and says nothing
        (PARTIAL_HEAD, None),  # half a request, then nothing
        (PARTIAL_HEAD, b"abcdefgh"),  # slowloris: a byte of header every 0.1 s, for ever
        (b"GET /ping HTTP/1.1\r\nHost: localhost\r\n\r\n" + PARTIAL_HEAD, b"abcdefgh"),  # the same, kept alive
    ],
)
def test_a_connection_must_send_a_whole_request_within_the_timeout(
    server: HttpServer, sent: bytes, trickle: bytes | None
) -> None:
    sock = connect(server.port)
    sock.sendall(sent)
    if sent.startswith(b"GET /ping"):
        assert sock.recv(4096).startswith(b"HTTP/1.1 200")
    assert closed_by_server(sock, trickle)
    sock.close()


@pytest.mark.slow
def test_bodies_that_are_too_large_or_never_arrive_are_refused(server: HttpServer) -> None:
    auth = {"Authorization": f"Bearer {TOKEN}"}
    assert call(server.port, "POST", "/echo", b"x" * 1000, {**auth, "Host": "localhost"}).body == b"1000"
    big = call(server.port, "POST", "/echo", b"x" * 70_000, {**auth, "Host": "localhost"})
    assert big.status == 413
    sock = connect(server.port)
    head = f"POST /echo HTTP/1.1\r\nHost: localhost\r\nAuthorization: Bearer {TOKEN}\r\nContent-Length: 10\r\n\r\n"
    sock.sendall(head.encode() + b"12345")
    sock.settimeout(GUARD_S)
    assert sock.recv(4096).startswith(b"HTTP/1.1 408")
    sock.close()


def test_plain_handlers_run_on_worker_threads_and_a_failing_one_is_a_500(
    server: HttpServer, caplog: pytest.LogCaptureFixture
) -> None:
    status, name = get(server.port, "/where")
    assert status == 200 and name.startswith(b"http-worker")
    with caplog.at_level(logging.ERROR, logger="edge.http"):
        assert get(server.port, "/boom")[0] == 500
    assert "http GET /boom failed: RuntimeError: handler bug" in caplog.text
    assert get(server.port, "/nope")[0] == 404 and get(server.port, "/echo")[0] == 405


@pytest.mark.parametrize(
    ("host", "status"),
    [("localhost:1", 200), ("127.0.0.1", 200), ("[::1]", 200), ("rebound.attacker.example", 421), ("", 400)],
)
def test_requests_naming_another_host_are_refused(server: HttpServer, host: str, status: int) -> None:
    sock = connect(server.port)
    sock.sendall(f"GET /ping HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())
    sock.settimeout(GUARD_S)
    assert sock.recv(4096).startswith(f"HTTP/1.1 {status}".encode())
    sock.close()


@pytest.mark.parametrize(
    "request_bytes",
    [
        b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03 TLS on the plain port\r\n\r\n",
        b"GET /ping HTTP/1.1\r\nHost: localhost\r\nX-Long: " + b"a" * 9000 + b"\r\n\r\n",
        b"BREW /ping HTTP/1.1\r\nHost: localhost\r\n\r\n",
        b"GET /ping HTTP/1.1\r\nHost: localhost\r\nContent-Length: -5\r\n\r\n",
    ],
)
def test_malformed_requests_are_a_400_and_no_error_in_the_log(
    server: HttpServer, request_bytes: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    sock = connect(server.port)
    with caplog.at_level(logging.INFO):
        sock.sendall(request_bytes)
        sock.settimeout(GUARD_S)
        assert sock.recv(4096).startswith((b"HTTP/1.0 400", b"HTTP/1.1 400"))
        assert get(server.port, "/ping") == (200, b"pong")  # and the server goes on
    sock.close()
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


@pytest.mark.slow
@pytest.mark.parametrize("path", ["/ping", "/nope", "/where"])
def test_a_client_that_resets_before_its_reply_leaves_no_error_in_the_log(
    server: HttpServer, path: str, caplog: pytest.LogCaptureFixture
) -> None:
    """A request followed at once by a reset (SO_LINGER 0): the reply meets a closing transport. aiohttp logged
    that as an error with a traceback, one per such request: anyone could fill the log."""
    with caplog.at_level(logging.INFO):
        for _ in range(20):
            sock = connect(server.port)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            sock.sendall(f"GET {path} HTTP/1.1\r\nHost: localhost\r\n\r\n".encode())
            sock.close()
        assert get(server.port, "/ping") == (200, b"pong")  # and the server goes on
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_replies_carry_headers_that_keep_the_page_to_itself(server: HttpServer) -> None:
    reply = call(server.port, "GET", "/ping", headers={"Host": "localhost"})
    assert reply.headers["x-frame-options"] == "DENY" and reply.headers["referrer-policy"] == "no-referrer"
    assert reply.headers["cache-control"] == "no-store" and reply.headers["x-content-type-options"] == "nosniff"


def test_a_taken_port_is_one_clear_error(server: HttpServer) -> None:
    with pytest.raises(EdgeIpsError, match=rf"http: port {server.port} on 127.0.0.1 is already in use"):
        HttpServer("127.0.0.1", server.port).start()


# -- a real edge-ips start (its embedded broker on a free port) ------------------------------------------------------
@pytest.fixture(scope="module")
def edge(tmp_path_factory: pytest.TempPathFactory) -> Iterator[EdgeProcess]:
    env = clean_env(
        EDGE_IPS_DASHBOARD__TOKEN=TOKEN,
        EDGE_IPS_HTTP__REQUEST_TIMEOUT_S="2",
        EDGE_IPS_BROKER__EMBEDDED_HOST="127.0.0.1",
        EDGE_IPS_BROKER__EMBEDDED_PORT="0",
    )
    with edge_start(["--source", "sim"], tmp_path_factory.mktemp("edge"), env) as process:
        yield process


def threads_of(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(status.split("Threads:")[1].split()[0])


@pytest.mark.slow
def test_300_idle_and_50_half_open_connections_leave_healthz_answering_and_add_no_threads(edge: EdgeProcess) -> None:
    auth = {"Authorization": f"Bearer {TOKEN}"}
    for path in ("/metrics", "/api/state", "/healthz"):  # every kind of handler has run once
        assert get(edge.http_port, path, auth)[0] == 200
    before = threads_of(edge.proc.pid)
    idle = [connect(edge.http_port) for _ in range(300)]
    half_open = [connect(edge.http_port) for _ in range(50)]
    for sock in half_open:
        sock.sendall(PARTIAL_HEAD)
    status, body = get(edge.http_port, "/healthz")
    assert status == 200 and json.loads(body)["state"] == "online"
    assert threads_of(edge.proc.pid) <= before + HttpLimits().workers  # at most the worker pool: no thread each
    assert all(closed_by_server(sock) for sock in half_open)  # evicted, or timed out after request_timeout_s
    assert get(edge.http_port, "/healthz")[0] == 200
    metrics = get(edge.http_port, "/metrics")[1].decode()
    assert "edge_ips_http_connections_evicted_total" in metrics
    for sock in idle + half_open:
        sock.close()
    assert threads_of(edge.proc.pid) <= before + HttpLimits().workers


@pytest.mark.slow
def test_a_foreign_host_is_refused_by_the_appliance(edge: EdgeProcess) -> None:
    status, body = get(edge.http_port, "/api/state", {"Host": "rebound.attacker.example", "X-Token": TOKEN})
    assert status == 421 and b"http.allowed_hosts" in body
    assert get(edge.http_port, "/healthz", {"Host": f"localhost:{edge.http_port}"})[0] == 200
    assert get(edge.http_port, "/healthz", {"Host": f"{socket.gethostname()}:{edge.http_port}"})[0] == 200
    said = "refused Host 'rebound.attacker.example' from 127.0.0.1"
    assert said in edge.wait_log(said)


@pytest.mark.slow
@pytest.mark.parametrize("path", ["/api/state", "/api/frame.jpg", "/api/events", "/api/errormap.png"])
def test_the_camera_events_and_state_need_the_token(edge: EdgeProcess, path: str) -> None:
    assert get(edge.http_port, path)[0] == 401
    if path != "/api/events":  # a stream does not end: its status is enough, read in the next test
        assert get(edge.http_port, f"{path}?token={TOKEN}")[0] == 200
        assert get(edge.http_port, path, {"Authorization": f"Bearer {TOKEN}"})[0] == 200


@pytest.mark.slow
def test_events_open_with_the_token_in_the_address(edge: EdgeProcess) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", edge.http_port, timeout=GUARD_S)
    try:
        conn.request("GET", f"/api/events?token={TOKEN}")
        resp = conn.getresponse()
        assert resp.status == 200 and resp.readline() == b"retry: 2000\n"  # (through the chunked encoding)
        assert resp.readline() == b"\n" and resp.readline() == b"event: status\n"
    finally:
        conn.close()


@pytest.mark.slow
def test_wrong_tokens_are_logged_with_the_address_and_the_address_is_locked_out(edge: EdgeProcess) -> None:
    guesser = "127.0.0.2"  # its own address: the lockout must not reach the other tests' 127.0.0.1
    statuses = [
        get(edge.http_port, "/api/frame.jpg", {"Authorization": f"Bearer guess-{k}"}, guesser)[0] for k in range(5)
    ]
    assert statuses == [401] * 5
    right = {"Authorization": f"Bearer {TOKEN}"}
    assert get(edge.http_port, "/api/state", right, guesser)[0] == 429  # locked out: not even checked
    assert get(edge.http_port, "/healthz", {}, guesser)[0] == 200  # open routes still answer
    assert get(edge.http_port, "/api/state", right)[0] == 200  # another address is not affected
    locked = f"wrong token from {guesser} (GET /api/frame.jpg): 5 in the last 60 s, locked out for 60 s"
    log = edge.wait_log(locked)  # the last of the five lines
    assert log.count(f"wrong token from {guesser}") == 5
    assert locked in log
    assert "guess-" not in log  # the guesses themselves are not logged


@pytest.mark.slow
def test_a_stop_from_a_locked_out_address_with_the_right_token_is_published(edge: EdgeProcess) -> None:
    """A tab left open with an old token keeps its machine locked out; the operator's STOP from it must work."""
    stale = "127.0.0.3"  # its own address (the other tests use 127.0.0.1 and 127.0.0.2)
    old = {"Authorization": "Bearer the-token-before-it-changed"}
    assert [get(edge.http_port, "/api/frame.jpg", old, stale)[0] for _ in range(5)] == [401] * 5
    right = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
    line = json.dumps({"kind": "line", "ids": ["red", "green", "blue"], "spacing": 60}).encode()
    assert send("POST", edge.http_port, "/api/formation", right, stale, line)[0] == 429  # other commands wait
    status, body = send("POST", edge.http_port, "/api/stop", right, stale, line)  # the route stops, whatever is posted
    assert status == 200, body
    reply = json.loads(body)
    assert reply["formation"]["kind"] == "stop" and reply["formation"]["ids"] == []  # read back from the broker
    assert send("POST", edge.http_port, "/api/stop", old, stale)[0] == 429  # a stale token stops nothing
    said = f"a STOP from {stale}, locked out for wrong tokens, has the right token: honoured"
    assert said in edge.wait_log(said)
