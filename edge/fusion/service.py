"""``edge-ips fuse --broker URL``: the fusion service on the central broker.

It subscribes to every board's detections (``ips/v1/edge/+/detections``) and statuses, fuses them
(:class:`edge.fusion.core.Fuser`, on the fuser's own wall clock: boards' offsets are estimated against it) and, while
it holds the lease (:mod:`edge.fusion.lease`), publishes the canonical ``ips/v1/rovers/<id>/pose`` (pose v1, QoS 0,
``frame`` counted on the shared clock: ``round(t * fps)``) and its retained status on ``ips/v1/fuser/<id>/status``.
A standby fuses too, so its filters are warm when it takes over.

On every connection, active or standby, it publishes a retained ``stop`` (:class:`edge.commands.StopAtStart`) and
no pose on that connection until the broker took it, as the single-camera edge does: a central broker that crashed
comes back with the formation it last saved, which may be older than the last command, and the rovers that
reconnect apply it (``shared/schema/README.md``, "Commands", rule 4). The stop goes over the fuser's own
connection: the central broker's client id is the login's name, so a second connection would take over its session.

Threads: paho's network thread receives and fuses each detections message and publishes the poses it gives at once
(the shortest path from a board's grab to a rover), the clocks learning from the frames when no other message waits;
the ``lease`` thread sends beats and claims and the status. The fuser's state is shared under one lock.
"""

from __future__ import annotations

import logging
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import paho.mqtt.client as mqtt
from pydantic import ValidationError

from edge.board_messages import DETECTIONS_WILDCARD, BoardStateV1, FuserStatusV1, fuser_status_topic, parse_detections
from edge.commands import StopAtStart, send_formation_on
from edge.config import BrokerTarget, EdgeConfig, broker_target
from edge.errors import BrokerError, MessageError, describe_validation
from edge.fusion.core import FusedPose, Fuser, FusionSettings, FusionStatus
from edge.fusion.detections import from_message
from edge.fusion.fusedmap import map_state
from edge.fusion.lease import LEASE_QOS, LEASE_TOPIC, Lease, LeaseMessage, LeaseSettings
from edge.fusion.offline import pose_line
from edge.messages import FormationV1, dumps, edge_status_topic, parse_status, pose_topic
from edge.mqttclient import TlsFiles, connect_host, make_client

if TYPE_CHECKING:
    from edge.httpserver import HttpServer

log = logging.getLogger("edge.fusion")

STATUS_QOS = 1
MAX_UNLEARNED = 16  # fused frames the clock learning may lag behind while messages keep arriving
EDGE_STATUS_WILDCARD = edge_status_topic("+")


@dataclass
class ServiceStats:
    detections: int = 0
    invalid: int = 0
    poses_sent: int = 0
    poses_withheld: int = 0  # fused while standby (or with the lease lapsed)
    poses_held: int = 0  # fused while holding the lease, before the broker took this connection's stop
    connects: int = 0
    seq: dict[str, int] = field(default_factory=dict)


class FuserConnection:
    """One broker connection of a :class:`FuserService`: no pose goes out on it until :meth:`release` (its stop
    taken). An :class:`edge.commands.HeldConnection`."""

    def __init__(self, service: FuserService, number: int) -> None:
        self._service = service
        self.number = number

    @property
    def current(self) -> bool:
        return self._service._connection == self.number and self._service._connected.is_set()

    def release(self) -> None:
        self._service._release(self.number)


class FuserService:
    """One fuser: connect, subscribe, fuse, publish while holding the lease. :meth:`start` then :meth:`stop`."""

    def __init__(
        self,
        target: BrokerTarget,
        fuser_id: str,
        *,
        settings: FusionSettings | None = None,
        lease: LeaseSettings | None = None,
        tls: TlsFiles | None = None,
        client_id: str | None = None,
        keepalive_s: int = 5,
        status_interval_s: float = 1.0,
        mono: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        on_pose: Callable[[FusedPose, bytes], None] | None = None,
        dashboards: dict[str, str] | None = None,
    ) -> None:
        self.target = target
        self.fuser_id = fuser_id
        self.settings = settings or FusionSettings()
        self.fuser = Fuser(self.settings)
        self.lease = Lease(fuser_id, settings=lease or LeaseSettings())
        self.stats = ServiceStats()
        self.status_interval_s = status_interval_s
        self.keepalive_s = keepalive_s
        self.on_pose = on_pose
        self.dashboards = dashboards or {}  # board -> its dashboard's address (the map shows its camera image)
        self._mono, self._wall = mono, wall
        self._lock = threading.Condition()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._connected = threading.Event()
        self._thread: threading.Thread | None = None
        # connections are numbered; poses go out only on the released one (its stop taken), checked under _lock
        self._connection = 0
        self._released = 0
        self.stop_at_start = StopAtStart(send=self._send_formation, retry=True)
        self._status_topic = fuser_status_topic(fuser_id)
        self._latest: dict[str, FusedPose] = {}  # each rover's newest fused pose, published or not (the map)
        self._client = make_client(target, client_id or f"edge-ips-fuser-{fuser_id}", tls=tls)
        # the lease's release for this session is the connection's last will (not retained: a standby has one too): a
        # killed holder is replaced at once
        self._client.will_set(LEASE_TOPIC, dumps(self.lease.will()), qos=LEASE_QOS, retain=False)
        self._client.on_connect = self._on_connect
        self._client.on_disconnect = self._on_disconnect
        self._client.on_message = self._on_message

    # -- life cycle ---------------------------------------------------------------------------------------------
    def start(self) -> FuserService:
        try:
            self._client.connect_async(connect_host(self.target), self.target.port, keepalive=self.keepalive_s)
        except ValueError as exc:
            raise BrokerError(f"broker {self.target.display()}: {exc}") from exc
        self._client.loop_start()
        self._thread = threading.Thread(target=self._lease_loop, name="lease", daemon=True)
        self._thread.start()
        return self

    def wait_connected(self, timeout_s: float) -> bool:
        return self._connected.wait(timeout_s)

    def stop(self, timeout_s: float = 3.0) -> None:
        """Release the lease if held, publish the offline status, disconnect."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self._connected.is_set():
            with self._lock:
                release = self.lease.release(self._wall())
                offline = self._status("offline")
            infos = []
            if release is not None:
                infos.append(self._client.publish(LEASE_TOPIC, dumps(release), qos=LEASE_QOS, retain=True))
            infos.append(self._client.publish(self._status_topic, dumps(offline), qos=STATUS_QOS, retain=True))
            for info in infos:
                try:
                    info.wait_for_publish(timeout_s)
                except (RuntimeError, ValueError):
                    log.warning("fuser %s: the broker did not acknowledge the stop", self.fuser_id)
        self._client.disconnect()
        self._client.loop_stop()

    # -- paho callbacks (network thread) ------------------------------------------------------------------------
    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason_code: Any, props: Any) -> None:
        if reason_code.is_failure:
            log.error("broker %s refused the fuser: %s", self.target.display(), reason_code)
            return
        with self._lock:
            self.lease.join(self._mono(), self.lease.session)
            self._connection += 1
            hold = FuserConnection(self, self._connection)
        self.stats.connects += 1
        client.subscribe([(LEASE_TOPIC, LEASE_QOS), (DETECTIONS_WILDCARD, 0), (EDGE_STATUS_WILDCARD, 1)])
        self._connected.set()
        self._wake.set()
        log.info(
            "fuser %s connected to %s (standby until it holds the lease; no pose before its retained stop is taken)",
            self.fuser_id,
            self.target.display(),
        )
        self.stop_at_start.on_connected(hold)

    def _send_formation(self, make: Callable[[int], FormationV1]) -> FormationV1:
        return send_formation_on(self._client, self.target, make)

    def _release(self, number: int) -> None:
        with self._lock:
            if number != self._connection:
                return  # replaced since: the newer connection has its own stop coming
            self._released = number
            self._lock.notify_all()
        log.info("fuser %s: its retained stop is taken; poses may go out on this connection", self.fuser_id)

    def wait_poses_released(self, timeout_s: float) -> bool:
        """Wait until connected with this connection's stop taken (poses may go out); False on timeout."""
        with self._lock:
            return self._lock.wait_for(self._poses_released, timeout_s)

    def _poses_released(self) -> bool:
        return self._released == self._connection and self._connected.is_set()

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason_code: Any, props: Any) -> None:
        self._connected.clear()
        with self._lock:
            self.lease.join(self._mono(), self.lease.session)  # a standby until the log says otherwise again
        if not self._stop.is_set():
            log.warning("fuser %s lost the broker (%s); reconnecting", self.fuser_id, reason_code)

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        topic, payload = message.topic, bytes(message.payload)
        try:
            if topic == LEASE_TOPIC:
                entry = LeaseMessage.model_validate_json(payload)
                with self._lock:
                    was = self.lease.is_holder
                    self.lease.apply(entry, self._mono(), retained=bool(message.retain))
                    changed = was != self.lease.is_holder
                if changed:
                    log.info("fuser %s is now %s", self.fuser_id, "active" if self.lease.is_holder else "standby")
                    self._wake.set()
            elif topic.endswith("/detections"):
                self._fuse(payload)
            elif topic.endswith("/status"):
                status = parse_status(payload)
                if status.state == "offline":
                    with self._lock:
                        self.fuser.board_offline(status.edge)
        except (MessageError, ValueError) as exc:  # a ValidationError is a ValueError: said in one line
            self.stats.invalid += 1
            why = describe_validation(exc) if isinstance(exc, ValidationError) else str(exc)
            if self.stats.invalid in (1, 10, 100, 1000):
                log.warning(
                    "fuser %s: refused a message on %s (%d so far): %s", self.fuser_id, topic, self.stats.invalid, why
                )
        self._learn()

    def _fuse(self, payload: bytes) -> None:
        d = from_message(parse_detections(payload))
        with self._lock:
            self.stats.detections += 1
            poses = self.fuser.add(d, now_s=self._wall(), learn=False)
            for pose in poses:
                self._latest[pose.rover_id] = pose
                n = self.stats.seq.get(pose.rover_id, 0)
                line = pose_line(pose, n)
                # asked right before each publish: a fuser that lost the lease (or was paused past it) stays quiet,
                # and none goes out on a connection before the broker took its stop
                if not self.lease.may_publish(self._mono()):
                    self.stats.poses_withheld += 1
                elif self._released != self._connection:
                    self.stats.poses_held += 1
                else:
                    self._client.publish(pose_topic(pose.rover_id), line, qos=0)
                    self.stats.seq[pose.rover_id] = n + 1
                    self.stats.poses_sent += 1
                    if self.on_pose is not None:
                        self.on_pose(pose, line)

    def _learn(self) -> None:
        """The clocks' evidence, after the poses are queued and not while another message waits: four boards'
        frames of one instant arrive together, and the last one's poses would wait for the others' learning (paho
        sends them when the callback returns)."""
        if self.fuser.unlearned and (len(self.fuser.unlearned) >= MAX_UNLEARNED or not self._more_waiting()):
            with self._lock:
                self.fuser.learn_pending()

    def _more_waiting(self) -> bool:
        """Bytes of another message are in the socket (or the TLS layer's buffer) already."""
        sock = self._client.socket()
        if sock is None:
            return False
        pending = getattr(sock, "pending", None)
        if pending is not None and pending() > 0:
            return True
        try:
            return bool(select.select([sock], [], [], 0.0)[0])
        except (OSError, ValueError):  # closed under us: the loop reconnects; learn now
            return False

    # -- the lease and the status (own thread) ------------------------------------------------------------------
    def _lease_loop(self) -> None:
        next_status = 0.0
        beat = self.lease.settings.beat_s
        while not self._stop.is_set():
            now = self._mono()
            if self._connected.is_set():
                with self._lock:
                    entry = self.lease.due(now, self._wall())
                if entry is not None:
                    self._client.publish(LEASE_TOPIC, dumps(entry), qos=LEASE_QOS, retain=True)
                if now >= next_status or self._wake.is_set():
                    self._wake.clear()
                    with self._lock:
                        status = self._status("active" if self.lease.is_holder else "standby")
                    self._client.publish(self._status_topic, dumps(status), qos=STATUS_QOS, retain=True)
                    next_status = now + self.status_interval_s
            self._wake.wait(beat / 5.0)

    def status(self) -> FusionStatus:
        with self._lock:
            return self.fuser.status(now_s=self._wall())

    def map_state(self) -> dict[str, Any]:
        """The fused map's state (:func:`edge.fusion.fusedmap.map_state`): boards, views, rovers and who saw them."""
        with self._lock:
            status = self._status("active" if self.lease.is_holder else "standby")
            poses = dict(self._latest)
        return map_state(status, poses, status.t, self.fuser.settings.timeout_s, self.dashboards)

    def _status(self, state: str) -> FuserStatusV1:
        """The retained status (call with the lock held)."""
        now = self._wall()
        st = self.fuser.status(now_s=now)
        silent = set(st.missing_boards)
        boards = []
        for b in st.boards[:16]:
            est = st.offsets.get(b.edge_id)
            boards.append(
                BoardStateV1(
                    edge=b.edge_id,
                    state="offline" if not b.online else ("silent" if b.edge_id in silent else "ok"),
                    offset_ms=None if est is None else round(1e3 * est.offset_s, 3),
                    offset_sigma_ms=None if est is None else round(min(1e3 * est.sigma_s, 1e7), 3),
                    offset_source=est.source if est is not None else "none",  # type: ignore[arg-type]
                    age_ms=None if b.last_arrival_s is None else round(min(1e3 * (now - b.last_arrival_s), 1e7), 1),
                    stale=min(b.stale, 999_999_999),
                    rovers=sorted(b.rovers)[:64],
                    view=[[round(x, 1), round(y, 1)] for x, y in b.view_cm],
                )
            )
        return FuserStatusV1(
            v=1,
            fuser=self.fuser_id,
            state=state,  # type: ignore[arg-type]
            holder=self.lease.holder,
            boards=boards,
            rovers=list(st.rovers[:64]),
            missing=list(st.missing[:64]),
            t=round(now, 3),
        )


def central_broker(config: EdgeConfig, who: str) -> tuple[BrokerTarget, TlsFiles]:
    """The central Mosquitto of several boards as the configuration's ``[broker]`` names it (credentials, TLS files
    checked); ``who`` (the fuser, ``doctor --fusion``) is named in the error when it is the embedded broker."""
    target = broker_target(config.broker)
    if target.embedded:
        raise BrokerError(f"{who} connects to the central Mosquitto of several boards: give its URL with --broker")
    tls = TlsFiles.of(config.broker)
    if target.tls:
        tls.check()
    return target, tls


def fuser_for(
    config: EdgeConfig, fuser_id: str, settings: FusionSettings, dashboards: dict[str, str] | None = None
) -> FuserService:
    """The fuser ``edge-ips fuse --broker`` runs, on the central broker the configuration's ``[broker]`` names."""
    target, tls = central_broker(config, "the fuser")
    return FuserService(target, fuser_id, settings=settings, tls=tls, dashboards=dashboards)


def run_fuser(service: FuserService, stop: threading.Event, http: HttpServer | None = None) -> None:
    """Run until ``stop`` is set, then stop cleanly; with ``http`` (started), the fused map on it too."""
    if http is not None:
        from edge.fusion.fusedmap import serve_map

        serve_map(http, service.map_state)
    service.start()
    try:
        stop.wait()
    finally:
        service.stop()
        if http is not None:
            http.stop()
