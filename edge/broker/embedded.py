"""The embedded MQTT broker: amqtt (MQTT 3.1.1) on its own thread with its own asyncio event loop.

Closed by default. With a :class:`~edge.broker.gate.BrokerAccess` (what ``edge-ips start`` gives it) every client
logs in, except anonymous ones from this machine, which may only read; each login has the rights of
:mod:`edge.broker.access`, enforced by amqtt's auth and topic-check plugins (:class:`LoginPlugin`,
:class:`TopicRightsPlugin`) after the gate of :mod:`edge.broker.gate` has checked the CONNECT. Without one
(tests, the simulator's closed loop) it takes anonymous clients from this machine only.

Payloads above the contract's ``x-max-bytes`` for their topic are dropped, last wills included; packets above
:data:`~edge.broker.access.MAX_PACKET_BYTES` disconnect their sender.

Nothing is persisted: a restarted broker starts with no retained messages (docs/deploy.md, "Security model", says
why that is the safe choice: a stale formation must never come back before the edge's retained ``stop``).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from amqtt.contexts import Action
from amqtt.plugins.base import BaseAuthPlugin
from amqtt.plugins.topic_checking import TopicAccessControlListPlugin

from edge.broker.access import ANONYMOUS, VIEWER_RIGHTS, Policy, payload_limit
from edge.broker.gate import OPEN_DESCRIPTION, BrokerAccess, Connect, GateReader, admit_open, is_loopback
from edge.errors import BrokerError
from edge.log_budget import LogBudget

log = logging.getLogger("edge.broker")

CONNECT_TIMEOUT_S = 10.0  # a client that opens a socket and says nothing is dropped after this
MAX_PENDING_CONNECTS = 64  # sockets at once that have not finished their CONNECT (other hosts; this machine apart)
MAX_PENDING_PER_ADDRESS = 8  # of them from any one other host
SHUTDOWN_TIMEOUT_S = 4.0  # amqtt's own shutdown, then what it left


AMQTT_LINES_PER_MINUTE = 20  # what amqtt logs itself (one ERROR per protocol violation a client sends), at most


class _AmqttLines(logging.Filter):
    """What amqtt logs, less what this module says better (its traceback when it cannot listen: start() raises a
    BrokerError; the QoS 0 messages dropped on shutdown, by design; a packet the gate refused, logged here), and
    at most ``AMQTT_LINES_PER_MINUTE`` lines a minute: amqtt logs an ERROR per protocol violation (fifty CONNECTs
    in a session, fifty lines), so a script on the network could fill the journal."""

    budget = LogBudget(AMQTT_LINES_PER_MINUTE)

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if text == "Broker startup failed" or "messages not broadcasted" in text or "PacketTooLarge" in text:
            return False
        if not self.budget.take(record.created):
            return False
        if left := self.budget.left_out():
            record.msg, record.args = f"%s ({left} earlier amqtt lines left out)", (text,)
        return True


_amqtt_lines = _AmqttLines()
# amqtt's loggers that a client's packets can make write (a filter works on the logger a record starts at only)
AMQTT_LOGGERS = (
    "amqtt.broker",
    "amqtt.mqtt.protocol.handler",
    "amqtt.adapters",
    "amqtt.session",
    "amqtt.broker.plugins",
)


REFUSAL_LINES_PER_MINUTE = 20
_refusals = [0]
_refusal_lines = LogBudget(REFUSAL_LINES_PER_MINUTE)


def refused(what: str) -> None:
    """Log a refusal: at most ``REFUSAL_LINES_PER_MINUTE`` lines a minute (a client retrying a refused login every
    second must not flood the journal), the next line written saying how many were left out."""
    _refusals[0] += 1
    if _refusal_lines.take(time.monotonic()):
        left = _refusal_lines.left_out()
        more = f"; {left} not logged" if left else ""
        log.warning("embedded broker refused %s (%d refusals so far%s)", what, _refusals[0], more)


# -- amqtt's plugins ---------------------------------------------------------------------------------------------
class LoginPlugin(BaseAuthPlugin):
    """amqtt's authentication step: the same decision as the gate (:meth:`BrokerAccess.admit`)."""

    @dataclass
    class Config:
        hashes: dict[str, str] = field(default_factory=dict)  # empty: no logins, this machine only
        edge_id: str = ""
        edge_user: str = ""
        rovers: list[str] = field(default_factory=list)
        viewer: bool = False

    def __init__(self, context: Any) -> None:
        super().__init__(context)
        cfg = self.context.config
        self.access = (
            BrokerAccess(Policy(cfg.edge_id, tuple(cfg.rovers), cfg.edge_user, cfg.viewer), cfg.hashes)
            if cfg.hashes
            else None
        )

    async def authenticate(self, *, session: Any) -> bool | None:
        connect = Connect(
            username=session.username,
            password=session.password,
            client_id=session.client_id or "",
            address=session.remote_address,
        )
        refusal = self.access.admit(connect) if self.access is not None else admit_open(connect)
        return refusal is None


class TopicRightsPlugin(TopicAccessControlListPlugin):
    """amqtt's topic ACL, configured with both lists (its own Config only declares the deprecated ``acl``)."""

    @dataclass
    class Config:
        publish_acl: dict[str, list[str]] = field(default_factory=dict)
        subscribe_acl: dict[str, list[str]] = field(default_factory=dict)

    async def topic_filtering(self, *, session: Any = None, topic: str | None = None, action: Any = None) -> bool:
        allowed = bool(await super().topic_filtering(session=session, topic=topic, action=action))
        if not allowed and action in (Action.PUBLISH, Action.SUBSCRIBE):
            who = getattr(session, "username", None) or ANONYMOUS
            what = "a publish on" if action == Action.PUBLISH else "a subscription to"
            refused(f"{what} {topic} from {who!r}: not in its rights")
        return allowed


def plugins_config(access: BrokerAccess | None) -> dict[str, Any]:
    """amqtt's ``plugins`` section for ``access`` (None: only the login plugin, in its open mode)."""
    plugins: dict[str, Any] = {}
    if access is None:
        plugins[f"{__name__}.LoginPlugin"] = {}
        return plugins
    policy = access.policy
    plugins[f"{__name__}.LoginPlugin"] = {
        "hashes": dict(access.hashes),
        "edge_id": policy.edge_id,
        "edge_user": policy.edge_user,
        "rovers": list(policy.rovers),
        "viewer": policy.viewer,
    }
    rights = {**policy.rights(), ANONYMOUS: VIEWER_RIGHTS}
    plugins[f"{__name__}.TopicRightsPlugin"] = {
        "publish_acl": {user: list(r.publish) for user, r in rights.items() if r.publish},
        "subscribe_acl": {user: list(r.read) for user, r in rights.items()},
    }
    return plugins


# -- the broker --------------------------------------------------------------------------------------------------
class PendingConnects:
    """Sockets that have not finished their CONNECT, counted so that sockets held open in silence keep nobody out:
    neither this machine (the edge's publisher, its dashboard's STOP and ``edge-ips formation`` connect from here,
    each command on a new connection) nor the other hosts (the rovers). At most :data:`MAX_PENDING_PER_ADDRESS`
    from any one other host (more are refused); when :data:`MAX_PENDING_CONNECTS` of a group (other hosts together,
    or this machine) are waiting, a new one closes the group's oldest, as nginx does: a client that sends its
    CONNECT at once is never the oldest, so whoever holds silent sockets (many hosts, or a process on the board)
    delays no STOP and no rover's reconnection."""

    def __init__(self) -> None:
        self._counts: Counter[str] = Counter()  # per other host
        self._waiting: dict[str, OrderedDict[int, tuple[str | None, Callable[[], None]]]] = {}
        self._tickets = 0
        self.evicted = 0

    @staticmethod
    def _keys(address: str | None) -> tuple[str, str | None]:
        return ("this machine", None) if is_loopback(address) else ("other hosts", address)

    def refusal(self, address: str | None) -> str | None:
        """Why a new socket from ``address`` is refused now (None: it may send its CONNECT)."""
        _, one = self._keys(address)
        if one is not None and self._counts[one] >= MAX_PENDING_PER_ADDRESS:
            return f"{MAX_PENDING_PER_ADDRESS} others from that address have not logged in yet"
        return None

    def enter(self, address: str | None, close: Callable[[], None]) -> tuple[int, str | None]:
        """Count a new socket from ``address`` (``close`` closes it); returns its ticket for :meth:`leave` and,
        when its group was full, the address of the oldest socket closed to make room (else None)."""
        group, one = self._keys(address)
        waiting = self._waiting.setdefault(group, OrderedDict())
        evicted = None
        if len(waiting) >= MAX_PENDING_CONNECTS:
            _, (oldest, close_oldest) = waiting.popitem(last=False)
            close_oldest()
            self.evicted += 1
            evicted = oldest or "an unknown address"
        self._tickets += 1
        waiting[self._tickets] = (address, close)
        if one is not None:
            self._counts[one] += 1
        return self._tickets, evicted

    def leave(self, address: str | None, ticket: int) -> None:
        group, one = self._keys(address)
        self._waiting.get(group, OrderedDict()).pop(ticket, None)
        if one is not None:
            self._counts[one] -= 1
            if self._counts[one] <= 0:
                del self._counts[one]  # remember no address that has nothing pending

    def waiting(self, group: str) -> int:
        """Sockets of ``group`` (``this machine`` or ``other hosts``) waiting for their CONNECT."""
        return len(self._waiting.get(group, ()))


async def _close(out: Any) -> None:
    """Close a client's stream; a client that reset the connection first makes the shutdown fail (ENOTCONN), which
    is no error of ours: without this, asyncio logs a traceback per such client."""
    with contextlib.suppress(OSError):
        await out.close()


def _make_broker(config: dict[str, Any], access: BrokerAccess | None) -> Any:
    """An amqtt broker behind the gate, with per-topic payload limits and retained messages only for subscribers.

    amqtt 0.12.1 (``Broker._handle_client_session``) pushes, to every client that connects, the retained messages
    matching *any* client's subscriptions: a rover would receive topics it never subscribed to. The override
    skips subscriptions the session does not hold (pinned: amqtt >=0.12,<0.13; a test pins the behaviour).
    """
    from amqtt.adapters import StreamWriterAdapter
    from amqtt.broker import Broker
    from amqtt.mqtt.connack import ConnackPacket
    from amqtt.mqtt.connect import ConnectPacket
    from amqtt.mqtt.packet import CONNECT, MQTTFixedHeader

    pending = PendingConnects()

    class _Broker(Broker):
        async def stream_connected(self, reader: Any, writer: Any, listener_name: str) -> None:
            peer = writer.get_extra_info("peername")
            address = peer[0] if peer else None
            out = StreamWriterAdapter(writer)
            full = pending.refusal(address)
            if full is not None:
                refused(f"a connection from {address}: {full}")
                await _close(out)
                return
            gate = GateReader(reader, on_too_large=lambda why: refused(f"{why} from {address}; disconnected"))
            ticket, evicted = pending.enter(address, writer.close)
            if evicted is not None:
                refused(f"a connection from {evicted}: no CONNECT yet, closed to make room for one from {address}")
            try:
                header = await asyncio.wait_for(MQTTFixedHeader.from_stream(gate), CONNECT_TIMEOUT_S)
                if header is None or header.packet_type != CONNECT:
                    raise ValueError("the first packet is not a CONNECT")
                packet = await asyncio.wait_for(ConnectPacket.from_stream(gate, header), CONNECT_TIMEOUT_S)
            except Exception as exc:  # too large, not MQTT, silent, or gone: nothing reached amqtt
                refused(f"a connection from {address}: {exc or type(exc).__name__}")
                await _close(out)
                return
            finally:
                pending.leave(address, ticket)
            will = packet.will_flag and packet.will_topic is not None
            connect = Connect(
                username=packet.username if packet.username_flag else None,
                password=packet.password if packet.password_flag else None,
                client_id=packet.client_id or "",
                address=address,
                will_topic=packet.will_topic if will else None,
                will_bytes=len(packet.will_message or b"") if will else 0,
            )
            refusal = access.admit(connect) if access is not None else admit_open(connect)
            if refusal is not None:
                refused(f"{connect.username or ANONYMOUS!r} from {address}: {refusal.reason}")
                with contextlib.suppress(OSError):  # the client may have gone already
                    await ConnackPacket.build(0, refusal.code).to_stream(out)
                await _close(out)
                return
            gate.replay_recorded()
            try:
                await self._client_connected(listener_name, gate, out)
            except OSError as exc:  # the client reset the connection while amqtt closed it: nothing to undo
                log.debug("embedded broker: a client from %s went while its session ended (%r)", address, exc)

        async def _broadcast_message(
            self, session: Any, topic: str | None, data: Any, force_qos: int | None = None
        ) -> None:
            if topic is not None and data is not None and len(data) > payload_limit(topic):
                who = getattr(session, "username", None) or ANONYMOUS
                limit = payload_limit(topic)
                refused(f"a payload of {len(data)} bytes on {topic} from {who!r} (the contract allows {limit})")
                return
            await super()._broadcast_message(session, topic, data, force_qos)

        async def retain_message(
            self, source_session: Any, topic_name: str | None, data: Any, qos: int | None = None
        ) -> None:
            if topic_name is not None and data is not None and len(data) > payload_limit(topic_name):
                return  # refused (and logged) by _broadcast_message, which amqtt calls first
            await super().retain_message(source_session, topic_name, data, qos)

        async def _publish_retained_messages_for_subscription(
            self, subscription: tuple[str, int], session: Any
        ) -> None:
            holders = self._subscriptions.get(subscription[0], [])
            if any(s.client_id == session.client_id for s, _ in holders):
                await super()._publish_retained_messages_for_subscription(subscription, session)

    return _Broker(config, loop=asyncio.get_running_loop())


class EmbeddedBroker:
    """An amqtt broker on ``host:port`` (port 0 = any free port; see :attr:`port` after :meth:`start`).

    ``access``: the logins and their rights; None = no logins, clients from this machine only.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 1883, access: BrokerAccess | None = None) -> None:
        self.host, self._port = host, port
        self.access = access
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._broker: Any = None
        self._started: Future[int] = Future()

    @property
    def port(self) -> int:
        return self._port

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def describe(self) -> str:
        """Where it listens and who may connect, for the log and ``doctor``."""
        who = self.access.describe() if self.access is not None else OPEN_DESCRIPTION
        return f"amqtt on {self.host}:{self._port}, {who}"

    def _port_in_use_message(self) -> str:
        return (
            f"embedded broker: port {self._port} on {self.host} is already in use (another MQTT broker, such as a "
            "Mosquitto service?). Choose another with broker.embedded_port in the configuration or "
            "EDGE_IPS_BROKER__EMBEDDED_PORT, or publish to the running broker with --broker mqtt://localhost:"
            f"{self._port}"
        )

    async def _serve(self) -> None:
        config = {
            "listeners": {"default": {"type": "tcp", "bind": f"{self.host}:{self._port}"}},
            "plugins": plugins_config(self.access),  # no $SYS topics, no packet logging
        }
        try:
            broker = _make_broker(config, self.access)
            await broker.start()
        except Exception as exc:
            self._started.set_exception(exc)
            return
        self._broker = broker
        server = broker._servers["default"].instance  # the bound port when 0 was asked for
        port = int(server.sockets[0].getsockname()[1])
        self._started.set_result(port)
        self._stop_requested = asyncio.Event()
        await self._stop_requested.wait()
        server.close()  # no new connections first: a client reconnecting while the sessions close kept it busy
        try:
            await asyncio.wait_for(broker.shutdown(), SHUTDOWN_TIMEOUT_S)
        except Exception as exc:  # amqtt's shutdown can trip over its own broadcast loop with clients connected
            log.warning("embedded broker: shutdown incomplete (%s); dropping its connections", repr(exc))
        others = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for task in others:  # what shutdown left (client handlers): cancelled, so their sockets close
            task.cancel()
        if others:
            await asyncio.wait(others, timeout=SHUTDOWN_TIMEOUT_S)

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        finally:
            loop.close()

    def start(self, timeout_s: float = 10.0) -> EmbeddedBroker:
        """Start listening; raises :class:`BrokerError` (port taken, bad address) before returning."""
        if self.running:
            raise BrokerError(f"embedded broker on {self.host}:{self._port} is already running")
        self._started = Future()  # a broker stopped earlier starts again (the port it had, the same logins)
        for name in ("amqtt", "transitions"):
            if logging.getLogger(name).level == logging.NOTSET:
                logging.getLogger(name).setLevel(logging.WARNING)  # amqtt logs every connection at INFO
        _AmqttLines.budget.reset()  # a broker started anew counts anew
        _refusal_lines.reset()
        for name in AMQTT_LOGGERS:
            if _amqtt_lines not in logging.getLogger(name).filters:
                logging.getLogger(name).addFilter(_amqtt_lines)
        self._thread = threading.Thread(target=self._run, name="embedded-broker", daemon=True)
        self._thread.start()
        try:
            self._port = self._started.result(timeout=timeout_s)
        except TimeoutError:
            raise BrokerError(f"embedded broker did not start within {timeout_s:g} s") from None
        except Exception as exc:
            self._thread.join(timeout=5)
            cause: BaseException | None = exc
            while cause is not None:
                if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
                    raise BrokerError(self._port_in_use_message()) from exc
                if isinstance(cause, OSError) and cause.errno == errno.EACCES:
                    raise BrokerError(
                        f"embedded broker: no permission to listen on port {self._port} (below 1024 needs root)"
                    ) from exc
                cause = cause.__cause__ or cause.__context__
            raise BrokerError(f"embedded broker on {self.host}:{self._port} cannot start: {exc}") from exc
        log.info("embedded MQTT broker: %s", self.describe())
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        event = getattr(self, "_stop_requested", None)
        if event is not None:
            loop.call_soon_threadsafe(event.set)
        thread.join(timeout=timeout_s)
        self._thread = None
        log.info("embedded MQTT broker stopped")

    def __enter__(self) -> EmbeddedBroker:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
