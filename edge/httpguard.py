"""Who may ask the HTTP server what: the ``Host`` allow-list, the dashboard's tokens, and a limit on wrong tokens.

- **Host**: a page on another site can make a browser resolve its own name to the board's address (DNS
  rebinding) and then read the answers as same-origin. The browser still sends that name in ``Host``, so only the
  board's own names (hostname, ``<hostname>.local``, ``localhost``, ``http.allowed_hosts``) and IP
  literals (the address the request arrived on, loopback) are answered.
- **Tokens**: routes are ``open`` (the page's files, ``/healthz``, ``/metrics``), ``read`` (the camera, events,
  state: any configured token), ``control`` (commands: the control token, in ``Authorization: Bearer``) or
  ``stop`` (the STOP: as ``control``, see below). A GET
  may carry the token as ``?token=`` instead, because a browser's ``EventSource`` and ``<img>`` send no headers.
  With no token configured, ``read`` routes are open and ``control`` routes answer 403 themselves.
- **Wrong tokens**: each one is logged with the client's address; after ``max_failures`` within ``window_s`` the
  address gets 429 on every protected route for ``lockout_s`` (without its token being checked), so guessing runs
  at a few tries a minute. A missing token is not a guess: it is answered 401 and not counted.
- **The STOP is never locked out**: a ``stop`` route's control token is still checked while its address is locked
  out, at most once per ``STOP_CHECK_S``, and the right one goes through. A wrong one counts, is refused as before
  and ends these checks until the lockout is over: one more guess per lockout, so guessing stays as slow.
  Otherwise a dashboard tab left open with an old token, retrying its camera frame every second, keeps its
  machine locked out, and the operator's STOP from that machine, with the right token, would be refused.

Everything here is pure (time is passed in), so it is tested without a server or a clock.
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
import socket
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Literal

from edge.log_budget import LogBudget

log = logging.getLogger("edge.http")

Access = Literal["open", "read", "control", "stop"]

MAX_FAILURES = 5  # wrong tokens from one address within WINDOW_S before it is locked out
WINDOW_S = 60.0
LOCKOUT_S = 60.0
MAX_ADDRESSES = 4096  # addresses remembered (least recently failed forgotten first)
STOP_CHECK_S = 1.0  # while an address is locked out, its STOP's token is checked at most this often
LOG_LINES_PER_MINUTE = 30  # all addresses together; beyond it failures are counted and summarised


# -- Host ----------------------------------------------------------------------------------------------------------
def host_name(header: str) -> str | None:
    """The name or address in a ``Host`` header, lower case, without port, brackets or trailing dot (None if empty
    or malformed)."""
    value = header.strip().lower()
    if value.startswith("["):  # [v6] or [v6]:port
        end = value.find("]")
        rest = value[end + 1 :] if end >= 0 else ""
        if end < 0 or (rest and not (rest.startswith(":") and rest[1:].isdigit())):
            return None
        return value[1:end] or None
    if value.count(":") == 1:  # name:port (a bare IPv6 address has more colons and no port)
        value, _, port = value.partition(":")
        if not port.isdigit():
            return None
    return value.rstrip(".") or None


def board_names() -> set[str]:
    """This machine's names: hostname, ``<hostname>.local`` (mDNS), ``localhost``. (Not the FQDN: finding it asks
    DNS, which on a lab network without one stalls the start for seconds; name it in ``http.allowed_hosts``.)"""
    hostname = socket.gethostname().lower().rstrip(".")
    return {n for n in ("localhost", hostname, f"{hostname.split('.')[0]}.local") if n}


@dataclass(frozen=True)
class HostAllowList:
    """``names``: allowed names (lower case); IP literals are allowed when they are the address the request came
    in on or loopback. ``any_host``: no check (``http.allowed_hosts = ["*"]``, for a reverse proxy)."""

    names: frozenset[str]
    any_host: bool = False

    @classmethod
    def for_this_board(cls, extra: Iterable[str] = ()) -> HostAllowList:
        more = [e.strip().lower().rstrip(".") for e in extra]
        return cls(frozenset(board_names() | {e for e in more if e and e != "*"}), any_host="*" in more)

    def allows(self, header: str | None, local_address: str | None) -> bool:
        if self.any_host:
            return True
        name = host_name(header) if header else None
        if name is None:
            return False
        if name in self.names:
            return True
        try:
            ip = ipaddress.ip_address(name)
        except ValueError:
            return False
        if ip.is_loopback:
            return True
        try:
            return local_address is not None and ipaddress.ip_address(local_address.split("%")[0]) == ip
        except ValueError:
            return False


# -- tokens --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Tokens:
    """``control``: commands and viewing; ``viewer``: viewing only. Either may be unset."""

    control: str | None = None
    viewer: str | None = None

    @property
    def required(self) -> bool:
        return self.control is not None or self.viewer is not None


def _bearer(headers: Mapping[str, str]) -> str | None:
    header = next((v for k, v in headers.items() if k.lower() == "authorization"), None)
    if header is None:
        return None
    scheme, _, given = header.strip().partition(" ")
    return given.strip() if scheme.lower() == "bearer" else ""


def presented_token(method: str, headers: Mapping[str, str], query: Mapping[str, list[str]]) -> str | None:
    """The token a request carries: ``Authorization: Bearer`` (an empty string when the header is there but holds
    no bearer token), else on a GET the ``token`` query parameter; None when there is none."""
    given = _bearer(headers)
    if given is None and method == "GET":
        values = query.get("token") or []
        given = values[-1] if values else None
    return given


def _same(given: str, expected: str | None) -> bool:
    return expected is not None and hmac.compare_digest(given.encode(), expected.encode())


@dataclass(frozen=True)
class Refusal:
    status: int
    error: str
    headers: tuple[tuple[str, str], ...] = ()


@dataclass
class _Address:
    failures: list[float] = field(default_factory=list)
    locked_until: float = 0.0
    refused_while_locked: int = 0
    stop_checked: float = -float("inf")  # when a STOP's token was last checked while locked out
    stop_guessed: bool = False  # a wrong STOP token during this lockout: no more STOP checks until it is over


class FailureLimiter:
    """Wrong tokens per client address; see the module docstring."""

    def __init__(
        self,
        max_failures: int = MAX_FAILURES,
        window_s: float = WINDOW_S,
        lockout_s: float = LOCKOUT_S,
        max_addresses: int = MAX_ADDRESSES,
    ) -> None:
        self.max_failures, self.window_s, self.lockout_s = max_failures, window_s, lockout_s
        self.max_addresses = max_addresses
        self._addresses: OrderedDict[str, _Address] = OrderedDict()
        self.failures = 0
        self.lockouts = 0
        self.refused = 0

    def locked_for(self, address: str, now: float) -> float:
        """Seconds ``address`` stays locked out (0 when it may try); counts the refusal."""
        entry = self._addresses.get(address)
        if entry is None or now >= entry.locked_until:
            return 0.0
        entry.refused_while_locked += 1
        self.refused += 1
        return entry.locked_until - now

    def honoured(self, address: str) -> None:
        """A request :meth:`locked_for` counted as refused went through after all (the STOP): not a refusal."""
        entry = self._addresses.get(address)
        if entry is not None and entry.refused_while_locked > 0:
            entry.refused_while_locked -= 1
            self.refused -= 1

    def may_check_stop(self, address: str, now: float) -> bool:
        """Whether a STOP from ``address``, locked out, may have its token checked now (at most once per
        ``STOP_CHECK_S``: guessing through the STOP stays slow)."""
        entry = self._addresses.get(address)
        if entry is None or entry.stop_guessed or now - entry.stop_checked < STOP_CHECK_S:
            return False
        entry.stop_checked = now
        return True

    def stop_guessed(self, address: str) -> None:
        """A wrong STOP token while ``address`` is locked out: no more STOP checks until the lockout is over."""
        entry = self._addresses.get(address)
        if entry is not None:
            entry.stop_guessed = True

    def failed(self, address: str, now: float) -> tuple[int, bool]:
        """Record one wrong token: (failures from ``address`` in the window, whether it is now locked out)."""
        self.failures += 1
        entry = self._addresses.pop(address, None) or _Address()
        self._addresses[address] = entry  # most recent last: the least recent is forgotten first
        while len(self._addresses) > self.max_addresses:
            self._addresses.popitem(last=False)
        entry.failures = [t for t in entry.failures if now - t < self.window_s] + [now]
        if len(entry.failures) >= self.max_failures:
            entry.locked_until = now + self.lockout_s
            entry.stop_guessed = False
            entry.failures = []
            self.lockouts += 1
            return self.max_failures, True
        return len(entry.failures), False

    def take_refused(self, address: str) -> int:
        """Requests refused while ``address`` was locked out, since last asked."""
        entry = self._addresses.get(address)
        if entry is None:
            return 0
        count, entry.refused_while_locked = entry.refused_while_locked, 0
        return count


class AccessGuard:
    """Checks a request's token for its route's access level, logging and limiting wrong ones."""

    def __init__(self, tokens: Tokens, limiter: FailureLimiter | None = None) -> None:
        self.tokens = tokens
        self.limiter = limiter or FailureLimiter()
        self._log_budget = LogBudget(LOG_LINES_PER_MINUTE)

    def check(
        self,
        access: Access,
        *,
        method: str,
        path: str,
        headers: Mapping[str, str],
        query: Mapping[str, list[str]],
        client: str,
        now: float,
    ) -> Refusal | None:
        """None when the request may go on; else the answer to give."""
        if access == "open":
            return None
        if access == "read" and not self.tokens.required:
            return None
        if access in ("control", "stop") and self.tokens.control is None:
            return None  # the route says itself that its controls are disabled
        given = presented_token(method, headers, query) if access == "read" else _bearer(headers)
        locked = self.limiter.locked_for(client, now)
        if locked > 0:
            if access == "stop" and given and _same(given, self.tokens.viewer):
                return Refusal(403, "this token is read-only: commands need the dashboard's control token")
            if access == "stop" and given and self.limiter.may_check_stop(client, now):
                if _same(given, self.tokens.control):
                    self.limiter.honoured(client)
                    log.warning(
                        "http: a STOP from %s, locked out for wrong tokens, has the right token: honoured", client
                    )
                    return None
                self._failed(client, method, path, now)
                self.limiter.stop_guessed(client)
            wait = str(max(1, round(locked)))
            return Refusal(429, f"too many wrong tokens from {client}: try again in {wait} s", (("Retry-After", wait),))
        if not given:
            how = "Authorization: Bearer <token>" + (" or ?token=<token>" if access == "read" else "")
            return Refusal(401, f"a token is required: {how}", (("WWW-Authenticate", 'Bearer realm="edge-ips"'),))
        if _same(given, self.tokens.control) or (access == "read" and _same(given, self.tokens.viewer)):
            return None
        if access != "read" and _same(given, self.tokens.viewer):
            return Refusal(403, "this token is read-only: commands need the dashboard's control token")
        self._failed(client, method, path, now)
        return Refusal(401, "wrong token", (("WWW-Authenticate", 'Bearer realm="edge-ips", error="invalid_token"'),))

    def _failed(self, client: str, method: str, path: str, now: float) -> None:
        count, locked = self.limiter.failed(client, now)
        if not self._log_budget.take(now):
            return
        skipped = self._log_budget.left_out()
        also = f"; {skipped} more wrong tokens (all addresses) not logged" if skipped else ""
        refused = self.limiter.take_refused(client)
        earlier = f"; {refused} requests refused while it was locked out" if refused else ""
        lockout = f", locked out for {self.limiter.lockout_s:g} s" if locked else ""
        log.warning(
            "http: wrong token from %s (%s %s): %d in the last %g s%s%s%s",
            client,
            method,
            path,
            count,
            self.limiter.window_s,
            lockout,
            earlier,
            also,
        )
