"""What the embedded broker checks before amqtt sees a connection: packet sizes, then the CONNECT.

amqtt 0.12 acts on a CONNECT before it authenticates it: a clean-session CONNECT deletes the subscriptions of the
session with the same client id (``Broker._initialize_client_session``) and a second one takes the session over,
whether or not the login is right; a last will is published without a topic check. So the embedded broker reads
the CONNECT itself (:class:`GateReader` records it), decides with :meth:`BrokerAccess.admit` (login, client id
owned by that login, last will on a topic the login may publish), and only then replays it to amqtt. Every packet,
the CONNECT included, is bounded by :data:`~edge.broker.access.MAX_PACKET_BYTES`, checked on the length field
before the body is read.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from edge.broker.access import (
    MAX_PACKET_BYTES,
    VIEWER_RIGHTS,
    Policy,
    hashed_users,
    payload_limit,
    topic_matches,
    verify_mosquitto_hash,
)
from edge.broker.credentials import Credentials

# CONNACK return codes of MQTT 3.1.1 (section 3.2.2.3)
IDENTIFIER_REJECTED = 0x02
BAD_USERNAME_PASSWORD = 0x04
NOT_AUTHORIZED = 0x05


class PacketTooLarge(Exception):
    """A client announced an MQTT packet larger than the broker reads."""


class PacketLimit:
    """Follows MQTT packet boundaries in a byte stream and refuses a packet whose remaining length is too large.

    Fed every byte read from a client, in any chunking; raises :class:`PacketTooLarge` as soon as the length field
    is complete, before the reader asks for the body.
    """

    def __init__(self, max_bytes: int = MAX_PACKET_BYTES) -> None:
        self.max_bytes = max_bytes
        self._in_length = False
        self._length = 0
        self._shift = 0
        self._body_left = 0

    def feed(self, data: bytes) -> None:
        i, n = 0, len(data)
        while i < n:
            if self._body_left:
                step = min(self._body_left, n - i)
                self._body_left -= step
                i += step
            elif not self._in_length:  # the fixed header's first byte: packet type and flags
                self._in_length, self._length, self._shift = True, 0, 0
                i += 1
            else:
                byte = data[i]
                i += 1
                self._length |= (byte & 0x7F) << self._shift
                self._shift += 7
                if byte & 0x80 and self._shift < 28:
                    continue
                self._in_length = False
                if byte & 0x80 or self._length > self.max_bytes:
                    raise PacketTooLarge(f"a packet of {self._length} bytes (at most {self.max_bytes} are read)")
                self._body_left = self._length


class GateReader:
    """amqtt's ``ReaderAdapter`` over an asyncio stream: bounded packets, and the CONNECT replayed after the gate."""

    def __init__(
        self, reader: object, max_bytes: int = MAX_PACKET_BYTES, on_too_large: Callable[[str], None] | None = None
    ) -> None:
        self._reader = reader
        self._limit = PacketLimit(max_bytes)
        self._on_too_large = on_too_large
        self._recorded: bytearray | None = bytearray()
        self._replay = b""

    async def read(self, n: int = -1) -> bytes:
        if self._replay:
            if n < 0 or n >= len(self._replay):
                head, self._replay = self._replay, b""
                rest = b"" if n < 0 or n == len(head) else await self.read(n - len(head))
                return head + rest
            head, self._replay = self._replay[:n], self._replay[n:]
            return head
        data: bytes = await (self._reader.read(n) if n < 0 else self._reader.readexactly(n))  # type: ignore[attr-defined]
        try:
            self._limit.feed(data)
        except PacketTooLarge as exc:
            if self._on_too_large is not None:
                self._on_too_large(str(exc))
            raise
        if self._recorded is not None:
            self._recorded += data
        return data

    def replay_recorded(self) -> None:
        """Serve what was read so far (the CONNECT) again, then the stream; stop recording."""
        self._replay = bytes(self._recorded or b"")
        self._recorded = None

    def feed_eof(self) -> None:
        self._reader.feed_eof()  # type: ignore[attr-defined]


def is_loopback(address: str | None) -> bool:
    if not address:
        return False
    try:
        ip = ipaddress.ip_address(address.split("%", 1)[0])
    except ValueError:
        return False
    mapped = getattr(ip, "ipv4_mapped", None)
    return bool(ip.is_loopback or (mapped is not None and mapped.is_loopback))


@dataclass(frozen=True)
class Refusal:
    code: int  # the CONNACK return code
    reason: str


@dataclass(frozen=True)
class Connect:
    """What the gate reads from a CONNECT."""

    username: str | None
    password: str | None
    client_id: str
    address: str | None
    will_topic: str | None = None
    will_bytes: int = 0


@dataclass(frozen=True)
class BrokerAccess:
    """The logins (``$7$`` hashes), the :class:`Policy`, and where the clear logins are (for the log and doctor)."""

    policy: Policy
    hashes: Mapping[str, str]
    credentials: Path | None = None

    @classmethod
    def of(cls, credentials: Credentials, edge_id: str, path: Path | None = None) -> BrokerAccess:
        return cls(credentials.policy(edge_id), hashed_users(credentials.passwords()), path)

    def admit(self, connect: Connect) -> Refusal | None:
        """None when the connection may go on; otherwise why not, with the CONNACK code to answer."""
        if connect.username is None:
            if not is_loopback(connect.address):
                return Refusal(NOT_AUTHORIZED, "anonymous, from another machine")
            rights = VIEWER_RIGHTS
        else:
            hashed = self.hashes.get(connect.username)
            if hashed is None or not verify_mosquitto_hash(connect.password or "", hashed):
                return Refusal(BAD_USERNAME_PASSWORD, f"wrong password or unknown user {connect.username!r}")
            rights = self.policy.rights()[connect.username]
        if not self.policy.may_use_client_id(connect.username, connect.client_id):
            return Refusal(IDENTIFIER_REJECTED, f"client id {connect.client_id!r} belongs to another login")
        if connect.will_topic is not None:
            if not any(topic_matches(connect.will_topic, allowed) for allowed in rights.publish):
                return Refusal(NOT_AUTHORIZED, f"a last will on {connect.will_topic}, which it may not publish")
            if connect.will_bytes > payload_limit(connect.will_topic):
                return Refusal(NOT_AUTHORIZED, f"a last will of {connect.will_bytes} bytes on {connect.will_topic}")
        return None

    def describe(self) -> str:
        where = f" ({self.credentials})" if self.credentials is not None else ""
        return f"logins required{where}; anonymous: read-only, from this machine only"


def admit_open(connect: Connect) -> Refusal | None:
    """The broker without logins: anonymous, with every right, but only for clients on this machine."""
    if not is_loopback(connect.address):
        return Refusal(NOT_AUTHORIZED, "the broker has no logins and takes clients from this machine only")
    return None


OPEN_DESCRIPTION = "no logins: anonymous clients from this machine only"
