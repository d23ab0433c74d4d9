"""Who may do what on the broker: one table of rights, enforced by the embedded broker and written for Mosquitto.

Users: the edge (its publisher, dashboard, ``edge-ips formation`` and ``doctor`` share one login), one per rover
(its id), and an optional read-only viewer (a laptop watching the topics). The rules:

* the edge publishes every pose, its own status and the formation, and reads everything under ``ips/v1/`` and
  the rovers' statuses (``ips/v2/rovers/+/status``);
* a rover reads poses, the formation and the edge's status, and publishes only its own status;
* the viewer reads what the edge reads and publishes nothing; an anonymous client (embedded broker, from
  this machine only) has the viewer's rights.

Client ids belong to users too (the embedded broker enforces it; Mosquitto gets ``use_username_as_clientid`` on
the network listener instead): ``rover-<id>`` is the rover's (what its firmware uses), ``edge-ips-...`` the edge's,
so no login can take another's session. Payload limits per topic are the contract's ``x-max-bytes``.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from edge.errors import BrokerError
from edge.messages import (
    FORMATION_MAX_BYTES,
    FORMATION_TOPIC,
    ID_PATTERN,
    POSE_MAX_BYTES,
    POSE_WILDCARD,
    ROVER_STATUS_MAX_BYTES,
    ROVER_STATUS_WILDCARD,
    STATUS_MAX_BYTES,
    TOPIC_PREFIX,
    edge_status_topic,
    repeated_ids,
    rover_status_topic,
)

EDGE_USER = "edge"
VIEWER_USER = "viewer"
ANONYMOUS = "anonymous"  # amqtt's name for a client without a user name (its ACL plugin keys on it)
RESERVED_USERS = frozenset({VIEWER_USER, ANONYMOUS})

ROVER_CLIENT_PREFIX = "rover-"  # firmware/esp8266/link.py connects as rover-<id>
EDGE_CLIENT_PREFIX = "edge-ips-"  # the publisher, the dashboard, `edge-ips formation` and `doctor`

ALL_TOPICS = f"{TOPIC_PREFIX}/#"
EDGE_STATUS_WILDCARD = edge_status_topic("+")

MAX_PAYLOAD_BYTES = max(POSE_MAX_BYTES, FORMATION_MAX_BYTES, STATUS_MAX_BYTES, ROVER_STATUS_MAX_BYTES)
# Largest MQTT packet either broker reads: the biggest contract message with its topic and headers, or the edge's
# CONNECT (64-byte client id, last will of one status, user name, password), with room to spare. A 2 MiB retained
# message is refused here, before it is read into memory.
MAX_PACKET_BYTES = 2048


@dataclass(frozen=True)
class Rights:
    """Topic filters a user may publish to and subscribe to (MQTT wildcards allowed)."""

    publish: tuple[str, ...]
    read: tuple[str, ...]


def edge_rights(edge_id: str) -> Rights:
    return Rights(
        publish=(POSE_WILDCARD, edge_status_topic(edge_id), FORMATION_TOPIC), read=(ALL_TOPICS, ROVER_STATUS_WILDCARD)
    )


def rover_rights(rover: str) -> Rights:
    return Rights(publish=(rover_status_topic(rover),), read=(POSE_WILDCARD, FORMATION_TOPIC, EDGE_STATUS_WILDCARD))


VIEWER_RIGHTS = Rights(publish=(), read=(ALL_TOPICS, ROVER_STATUS_WILDCARD))


def topic_matches(topic: str, topic_filter: str) -> bool:
    """MQTT matching of a topic name against a filter with ``+`` and ``#``."""
    names, filters = topic.split("/"), topic_filter.split("/")
    for i, level in enumerate(filters):
        if level == "#":
            return True
        if i >= len(names) or (level != "+" and level != names[i]):
            return False
    return len(names) == len(filters)


def payload_limit(topic: str) -> int:
    """The contract's ``x-max-bytes`` for the message on ``topic`` (the largest of them for any other topic)."""
    if topic == FORMATION_TOPIC:
        return FORMATION_MAX_BYTES
    if topic_matches(topic, POSE_WILDCARD):
        return POSE_MAX_BYTES
    if topic_matches(topic, ROVER_STATUS_WILDCARD):
        return ROVER_STATUS_MAX_BYTES
    if topic_matches(topic, EDGE_STATUS_WILDCARD):
        return STATUS_MAX_BYTES
    return MAX_PAYLOAD_BYTES


def check_names(edge_user: str, rovers: Sequence[str]) -> None:
    """User names must be topic-safe ids, unique, and none of the reserved ones."""
    for name in [edge_user, *rovers]:
        if not re.match(ID_PATTERN, name):
            raise BrokerError(f"user name {name!r}: use 1-16 characters of a-z, 0-9, _ and -")
        if name in RESERVED_USERS:
            raise BrokerError(f"user name {name!r} is reserved (the read-only viewer, or anonymous clients)")
    if edge_user in rovers:
        raise BrokerError(f"the edge user {edge_user!r} must differ from every rover id")
    twice = repeated_ids(rovers)
    if twice:
        raise BrokerError(f"rover {', '.join(twice)} named more than once")


@dataclass(frozen=True)
class Policy:
    """The users of one deployment and what each may do."""

    edge_id: str
    rovers: tuple[str, ...]
    edge_user: str = EDGE_USER
    viewer: bool = True

    def __post_init__(self) -> None:
        check_names(self.edge_user, self.rovers)

    def rights(self) -> dict[str, Rights]:
        """User name -> rights, in the order the ACL lists them."""
        table = {self.edge_user: edge_rights(self.edge_id)}
        table.update({rover: rover_rights(rover) for rover in self.rovers})
        if self.viewer:
            table[VIEWER_USER] = VIEWER_RIGHTS
        return table

    def may_use_client_id(self, user: str | None, client_id: str) -> bool:
        """A rover only as ``rover-<its id>``; ``edge-ips-...`` only the edge; any other id the edge or a viewer."""
        if client_id.startswith(ROVER_CLIENT_PREFIX):
            return user == client_id.removeprefix(ROVER_CLIENT_PREFIX) and user in self.rovers
        if client_id.startswith(EDGE_CLIENT_PREFIX):
            return user == self.edge_user
        return user not in self.rovers

    def acl_text(self) -> str:
        """The same rights as a Mosquitto ``acl_file``."""
        return rights_acl_text(self.rights())


def rights_acl_text(table: Mapping[str, Rights]) -> str:
    """A Mosquitto ``acl_file`` giving each user (name -> :class:`Rights`) exactly its rights."""
    lines = [
        "# edge-ips ACL, written by `edge-ips broker-config`.",
        "# Anonymous access is off; a user not listed here can do nothing.",
        "",
    ]
    for user, rights in table.items():
        lines.append(f"user {user}")
        for topic in rights.publish:
            lines.append(f"topic {'readwrite' if topic in rights.read else 'write'} {topic}")
        lines += [f"topic read {topic}" for topic in rights.read if topic not in rights.publish]
        lines.append("")
    return "\n".join(lines)


def acl_text(edge_user: str, edge_id: str, rovers: Sequence[str], viewer: bool = False) -> str:
    """The Mosquitto ACL of :class:`Policy` (kept as a function for the callers that only need the text)."""
    return Policy(edge_id=edge_id, rovers=tuple(rovers), edge_user=edge_user, viewer=viewer).acl_text()


# -- Mosquitto's password hash, computed here -------------------------------------------------------------------
PBKDF2_ITERATIONS = 101  # what mosquitto_passwd 2.0 writes (PW_DEFAULT_ITERATIONS)
PBKDF2_SALT_BYTES = 12  # SALT_LEN in mosquitto's password_mosq.h
_HASH = re.compile(r"^\$7\$(\d+)\$([A-Za-z0-9+/=]+)\$([A-Za-z0-9+/=]+)$")


def mosquitto_hash(password: str, salt: bytes | None = None, iterations: int = PBKDF2_ITERATIONS) -> str:
    """Mosquitto 2.0's password hash: ``$7$<iterations>$<base64 salt>$<base64 PBKDF2-HMAC-SHA512>``.

    Type 7 is PBKDF2 with SHA-512 over the UTF-8 password and a 12-byte random salt, 64 bytes of output, both in
    standard base64 with padding (``mosquitto_passwd``'s ``output_new_password``). Computed here so a password is
    never put on a command line (``mosquitto_passwd -b`` shows it in ``ps``). The iteration count is Mosquitto's
    default: the passwords edge-ips generates are 144-bit random, so a slower hash would add nothing against
    guessing; the hash only keeps a leaked password file from being a list of passwords.
    """
    salt = salt if salt is not None else os.urandom(PBKDF2_SALT_BYTES)
    digest = hashlib.pbkdf2_hmac("sha512", password.encode("utf-8"), salt, iterations)
    return f"$7${iterations}${base64.b64encode(salt).decode()}${base64.b64encode(digest).decode()}"


def verify_mosquitto_hash(password: str | bytes, hashed: str) -> bool:
    """True when ``password`` matches a ``$7$`` hash (constant-time comparison)."""
    secret = password if isinstance(password, bytes) else password.encode("utf-8")
    match = _HASH.match(hashed)
    if match is None:
        return False
    iterations, salt, digest = int(match[1]), base64.b64decode(match[2]), base64.b64decode(match[3])
    if not 1 <= iterations <= 1_000_000:
        return False
    candidate = hashlib.pbkdf2_hmac("sha512", secret, salt, iterations)
    return hmac.compare_digest(candidate, digest)


def hashed_users(passwords: Mapping[str, str]) -> dict[str, str]:
    """User -> ``$7$`` hash for every clear password."""
    return {user: mosquitto_hash(password) for user, password in passwords.items()}
