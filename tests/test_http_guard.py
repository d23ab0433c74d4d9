"""Who may ask the HTTP server what, without a server: Host names, tokens by access level, and the lockout after
repeated wrong tokens (time passed in, no clock)."""

from __future__ import annotations

import logging
import socket

import pytest

from edge.httpguard import AccessGuard, FailureLimiter, HostAllowList, Tokens, board_names, host_name, presented_token

CONTROL = "control-token-123"
VIEWER = "viewer-token-456"


@pytest.mark.parametrize(
    ("header", "name"),
    [
        ("edge.lab:8080", "edge.lab"),
        ("Edge.Lab.", "edge.lab"),
        ("127.0.0.1:8080", "127.0.0.1"),
        ("[::1]:8080", "::1"),
        ("[fe80::1]", "fe80::1"),
        ("::1", "::1"),
        ("", None),
        ("edge.lab:http", None),
        ("[::1]x", None),
        ("[::1", None),
        (":8080", None),
    ],
)
def test_the_name_in_a_host_header(header: str, name: str | None) -> None:
    assert host_name(header) == name


ALLOW = HostAllowList(frozenset({"localhost", "edge-board", "edge-board.local", "ips.lab.example"}))


@pytest.mark.parametrize(
    ("host", "local", "allowed"),
    [
        ("localhost:8080", "127.0.0.1", True),
        ("edge-board:8080", "192.168.1.20", True),
        ("EDGE-BOARD.local", "192.168.1.20", True),
        ("ips.lab.example", "192.168.1.20", True),
        ("192.168.1.20:8080", "192.168.1.20", True),  # the address the request came in on
        ("127.0.0.1:8080", "127.0.0.1", True),
        ("127.0.0.1", "192.168.1.20", True),  # loopback
        ("[::1]:8080", "::1", True),
        ("[::ffff:192.168.1.20]:8080", "::ffff:192.168.1.20", True),
        ("10.0.0.9:8080", "192.168.1.20", False),  # an address that is not this connection's
        ("attacker.example", "192.168.1.20", False),  # DNS rebinding: the attacker's name on our address
        ("edge-board.attacker.example", "192.168.1.20", False),
        ("localhost.attacker.example", "127.0.0.1", False),
        (None, "127.0.0.1", False),
        ("", "127.0.0.1", False),
    ],
)
def test_only_the_boards_names_and_addresses_are_answered(host: str | None, local: str, allowed: bool) -> None:
    assert ALLOW.allows(host, local) is allowed


def test_the_allow_list_has_this_machines_names_and_the_configured_ones() -> None:
    allow = HostAllowList.for_this_board(["IPS.Lab.Example."])
    hostname = socket.gethostname().lower()
    assert {"localhost", hostname, f"{hostname.split('.')[0]}.local", "ips.lab.example"} <= allow.names
    assert board_names() <= allow.names and not allow.any_host
    assert allow.allows(f"{hostname}:8080", "10.1.2.3") and not allow.allows("other.example", "10.1.2.3")
    anything = HostAllowList.for_this_board(["*"])
    assert anything.any_host and anything.allows("attacker.example", "10.1.2.3")


@pytest.mark.parametrize(
    ("method", "headers", "query", "token"),
    [
        ("GET", {"Authorization": "Bearer abc"}, {}, "abc"),
        ("GET", {"authorization": "bearer  abc "}, {}, "abc"),
        ("GET", {"Authorization": "Basic abc"}, {}, ""),  # a header without a bearer token: not the query's
        ("GET", {}, {"token": ["abc"]}, "abc"),
        ("GET", {}, {"token": ["one", "two"]}, "two"),
        ("POST", {}, {"token": ["abc"]}, None),  # a command's token is a header, never in a URL
        ("GET", {}, {}, None),
    ],
)
def test_the_token_a_request_carries(
    method: str, headers: dict[str, str], query: dict[str, list[str]], token: str | None
) -> None:
    assert presented_token(method, headers, query) == token


def _check(guard: AccessGuard, access: str, headers: dict[str, str], query: dict[str, list[str]] | None = None) -> int:
    method = "POST" if access in ("control", "stop") else "GET"
    refusal = guard.check(
        access,  # type: ignore[arg-type]
        method=method,
        path="/x",
        headers=headers,
        query=query or {},
        client="10.0.0.5",
        now=0.0,
    )
    return 200 if refusal is None else refusal.status


BOTH = Tokens(CONTROL, VIEWER)


@pytest.mark.parametrize(
    ("tokens", "access", "headers", "query", "status"),
    [
        (Tokens(), "open", {}, {}, 200),
        (Tokens(), "read", {}, {}, 200),  # no token configured: the page is open to view
        (Tokens(), "control", {}, {}, 200),  # ... and the route itself says the controls are disabled (403)
        (BOTH, "open", {}, {}, 200),
        (BOTH, "read", {}, {}, 401),
        (BOTH, "read", {"Authorization": f"Bearer {CONTROL}"}, {}, 200),
        (BOTH, "read", {"Authorization": f"Bearer {VIEWER}"}, {}, 200),
        (BOTH, "read", {}, {"token": [VIEWER]}, 200),
        (BOTH, "read", {}, {"token": ["guess"]}, 401),
        (BOTH, "control", {"Authorization": f"Bearer {CONTROL}"}, {}, 200),
        (BOTH, "control", {"Authorization": f"Bearer {VIEWER}"}, {}, 403),  # read-only
        (BOTH, "control", {"Authorization": "Bearer guess"}, {}, 401),
        (BOTH, "control", {}, {"token": [CONTROL]}, 401),
        (BOTH, "stop", {"Authorization": f"Bearer {CONTROL}"}, {}, 200),
        (BOTH, "stop", {"Authorization": f"Bearer {VIEWER}"}, {}, 403),  # read-only
        (BOTH, "stop", {"Authorization": "Bearer guess"}, {}, 401),
        (BOTH, "stop", {}, {}, 401),
        (Tokens(viewer=VIEWER), "read", {"Authorization": f"Bearer {VIEWER}"}, {}, 200),
        (Tokens(viewer=VIEWER), "control", {}, {}, 200),  # no control token: the route answers 403 itself
        (Tokens(control=CONTROL), "read", {"Authorization": f"Bearer {CONTROL}x"}, {}, 401),
    ],
)
def test_access_by_route_level_and_token(
    tokens: Tokens, access: str, headers: dict[str, str], query: dict[str, list[str]], status: int
) -> None:
    assert _check(AccessGuard(tokens), access, headers, query) == status


def test_wrong_tokens_lock_the_address_out_and_it_may_try_again_later() -> None:
    limiter = FailureLimiter(max_failures=3, window_s=60.0, lockout_s=30.0)
    assert [limiter.failed("a", t) for t in (0.0, 10.0)] == [(1, False), (2, False)]
    assert limiter.failed("b", 11.0) == (1, False)  # another address has its own count
    assert limiter.locked_for("a", 12.0) == 0.0
    assert limiter.failed("a", 20.0) == (3, True)
    assert limiter.locked_for("a", 25.0) == pytest.approx(25.0) and limiter.locked_for("b", 25.0) == 0.0
    assert limiter.locked_for("a", 50.0) == 0.0  # the lockout is over
    assert limiter.take_refused("a") == 1 and limiter.take_refused("a") == 0
    assert limiter.failed("a", 51.0) == (1, False)  # a fresh start after the lockout
    assert limiter.failed("c", 0.0) == (1, False) and limiter.failed("c", 61.0) == (1, False)  # the window slides
    assert (limiter.failures, limiter.lockouts, limiter.refused) == (7, 1, 1)


def test_the_limiter_remembers_a_bounded_number_of_addresses() -> None:
    limiter = FailureLimiter(max_failures=2, max_addresses=100)
    for k in range(1000):
        limiter.failed(f"10.0.{k // 256}.{k % 256}", float(k))
    assert len(limiter._addresses) == 100


def test_a_locked_out_address_is_refused_even_with_the_right_token_and_each_failure_is_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    guard = AccessGuard(Tokens(CONTROL), FailureLimiter(max_failures=5, window_s=60.0, lockout_s=60.0))
    statuses = []
    with caplog.at_level(logging.WARNING, logger="edge.http"):
        for k in range(8):
            token = CONTROL if k >= 6 else f"guess-{k}"
            refusal = guard.check(
                "read",
                method="GET",
                path="/api/frame.jpg",
                headers={"Authorization": f"Bearer {token}"},
                query={},
                client="192.168.1.66",
                now=float(k),
            )
            statuses.append(200 if refusal is None else refusal.status)
        right = {"Authorization": f"Bearer {CONTROL}"}
        later = guard.check("read", method="GET", path="/", headers=right, query={}, client="192.168.1.66", now=70.0)
    assert statuses == [401, 401, 401, 401, 401, 429, 429, 429] and later is None
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 5 and all("wrong token from 192.168.1.66 (GET /api/frame.jpg)" in ln for ln in lines)
    assert lines[-1].endswith("5 in the last 60 s, locked out for 60 s")
    refusal = guard.check("read", method="GET", path="/", headers={}, query={}, client="192.168.1.66", now=80.0)
    assert refusal is not None and refusal.status == 401  # a missing token is not a guess: not counted
    assert guard.limiter.failures == 5


def test_wrong_token_log_lines_are_limited_over_all_addresses(caplog: pytest.LogCaptureFixture) -> None:
    guard = AccessGuard(Tokens(CONTROL))
    with caplog.at_level(logging.WARNING, logger="edge.http"):
        for k in range(100):  # 100 addresses, one guess each, within one minute
            headers = {"Authorization": "Bearer guess"}
            guard.check("read", method="GET", path="/", headers=headers, query={}, client=f"10.9.0.{k}", now=k * 0.1)
        guard.check("read", method="GET", path="/", headers=headers, query={}, client="10.9.1.1", now=61.0)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 31 and guard.limiter.failures == 101
    assert lines[-1].endswith("; 70 more wrong tokens (all addresses) not logged")


def test_a_stop_with_the_right_token_goes_through_a_lockout_and_guessing_through_it_stays_slow(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A tab left open with an old token locks its machine out; the operator's STOP from there must still work."""
    guard = AccessGuard(Tokens(CONTROL, VIEWER), FailureLimiter(max_failures=5, window_s=60.0, lockout_s=60.0))
    here = "192.168.1.20"

    def ask(access: str, token: str, now: float) -> int:
        method = "GET" if access == "read" else "POST"
        headers = {"Authorization": f"Bearer {token}"}
        refusal = guard.check(access, method=method, path="/x", headers=headers, query={}, client=here, now=now)  # type: ignore[arg-type]
        return 200 if refusal is None else refusal.status

    with caplog.at_level(logging.WARNING, logger="edge.http"):
        assert [ask("read", "old-token", k * 1.0) for k in range(5)] == [401] * 5  # the stale tab: locked out
        assert ask("control", CONTROL, 5.0) == 429  # other commands wait out the lockout
        assert ask("read", CONTROL, 5.1) == 429
        refused = guard.limiter.refused
        assert ask("stop", CONTROL, 5.2) == 200  # the STOP goes through
        assert guard.limiter.refused == refused  # and is not counted as refused
        assert ask("stop", VIEWER, 5.3) == 403  # a read-only token is said to be one, as outside a lockout ...
        assert ask("stop", CONTROL, 5.5) == 429  # its token is checked at most once a second while locked out
        assert ask("stop", CONTROL, 6.3) == 200  # ... and was no guess: the STOP's checks go on
        failures = guard.limiter.failures
        assert ask("stop", "guess", 7.5) == 429 and guard.limiter.failures == failures + 1  # a guess counts ...
        assert ask("stop", CONTROL, 9.0) == 429  # ... and ends the STOP's checks for this lockout: one guess more
        assert ask("stop", "guess", 10.0) == 429 and guard.limiter.failures == failures + 1  # not even checked
        assert ask("stop", CONTROL, 70.0) == 200  # the lockout is over
    said = [r.getMessage() for r in caplog.records]
    assert sum("a STOP from 192.168.1.20, locked out for wrong tokens, has the right token" in m for m in said) == 2
    assert all(CONTROL not in m and "guess" not in m for m in said)
