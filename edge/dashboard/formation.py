"""The dashboard's formation controls: who may command (a bearer token), what a command may say, the retained
formation the broker holds now (watched, so commands from ``edge-ips formation`` show on the page too), and what each
rover reports it applies (its retained rover status v2): the page shows the rovers' word, not the edge's memory.

Checks in this order, so nothing about the input leaks to someone without the token: controls disabled (no token
configured: 403), token missing or wrong (401, compared in constant time), input invalid (400). Only then is the
retained formation v1 message published with :func:`edge.commands.send_formation` (its ``seq`` follows the one
the broker holds).
"""

from __future__ import annotations

import hmac
import json
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from edge.commands import FORMATION_QOS, build_formation, send_formation
from edge.config import BrokerTarget
from edge.errors import EdgeIpsError, MessageError, describe_validation
from edge.messages import (
    FORMATION_TOPIC,
    ROVER_STATUS_WILDCARD,
    FormationKind,
    FormationV1,
    RoverStatusV2,
    parse_formation,
    parse_rover_status,
)
from edge.mqttclient import TlsFiles, connect_host, make_client

log = logging.getLogger("edge.dashboard")

MAX_BODY_BYTES = 4096


class FormationRequest(BaseModel):
    """What the page posts to ``/api/formation``. ``spacing`` is used for a line, ``side`` for a triangle."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: FormationKind
    ids: list[str] = Field(max_length=16)
    spacing: float | None = None
    side: float | None = None
    x: float | None = None
    y: float | None = None
    theta: float | None = None


@dataclass(frozen=True)
class Refusal:
    status: int
    error: str


def authorize(token: str | None, headers: Mapping[str, str]) -> Refusal | None:
    """None when ``Authorization: Bearer <token>`` matches the configured token; else why not (403 or 401)."""
    if token is None:
        return Refusal(403, "formation controls are disabled: no dashboard token is configured (dashboard.token)")
    header = next((v for k, v in headers.items() if k.lower() == "authorization"), "")
    scheme, _, given = header.strip().partition(" ")
    if scheme.lower() != "bearer" or not given.strip():
        return Refusal(401, "a token is required: Authorization: Bearer <dashboard token>")
    if not hmac.compare_digest(given.strip().encode(), token.encode()):
        return Refusal(401, "wrong token")
    return None


def parse_request(body: bytes, rover_ids: Sequence[str]) -> Callable[[int], FormationV1]:
    """Validate a posted command; returns ``make(seq)`` for :func:`send_formation`. Raises :class:`MessageError`
    naming the field at fault."""
    if len(body) > MAX_BODY_BYTES:
        raise MessageError(f"formation request: body of {len(body)} bytes exceeds {MAX_BODY_BYTES}")
    try:
        data = json.loads(body)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MessageError(f"formation request: not JSON ({exc})") from None
    try:
        req = FormationRequest.model_validate(data)
    except ValidationError as exc:
        raise MessageError(f"formation request: {describe_validation(exc, top_level='(body)')}") from None

    def make(seq: int) -> FormationV1:
        return build_formation(
            req.kind,
            req.ids,
            seq=seq,
            spacing_cm=req.spacing,
            side_cm=req.side,
            x_cm=req.x,
            y_cm=req.y,
            theta_rad=req.theta,
            known_ids=rover_ids,
        )

    make(1)  # every check (configured ids, each once, spacing in range, ...) before anything is published
    return make


class FormationDesk:
    """Publishes commands and keeps the retained formation (``current``) and the rovers' retained statuses
    (``reports``) up to date from the broker.

    ``on_change(formation dict or None)`` is called (on paho's thread) whenever the retained formation changes,
    ``on_report(rover id, its status or None)`` whenever a configured rover's status changes (None: cleared).
    """

    def __init__(
        self,
        target: BrokerTarget,
        *,
        edge_id: str,
        rover_ids: Sequence[str],
        token: str | None,
        tls: TlsFiles | None = None,
        on_change: Callable[[dict[str, Any] | None], None] | None = None,
        on_report: Callable[[str, RoverStatusV2 | None], None] | None = None,
    ) -> None:
        self.target = target
        self.edge_id = edge_id
        self.rover_ids = tuple(rover_ids)
        self.token = token
        self.tls = tls
        self.on_change = on_change
        self.on_report = on_report
        self._reports: dict[str, RoverStatusV2] = {}
        self.refused_reports = 0
        self._lock = threading.Lock()  # one command at a time: each one's seq follows the last
        self._current: FormationV1 | None = None
        self._state_lock = threading.Lock()
        self._client: mqtt.Client | None = None

    @property
    def enabled(self) -> bool:
        return self.token is not None

    @property
    def current(self) -> dict[str, Any] | None:
        with self._state_lock:
            return None if self._current is None else self._current.model_dump(mode="json")

    @property
    def reports(self) -> dict[str, RoverStatusV2]:
        """Each configured rover's newest status, as the rover published it (absent: none received)."""
        with self._state_lock:
            return dict(self._reports)

    def _report(self, topic: str, payload: bytes) -> None:
        # A status counts only on its own rover's topic and for a configured rover (on an open broker anyone may
        # publish anything); an empty retained payload clears it.
        parts = topic.split("/")  # ips/v2/rovers/<id>/status
        rover_id = parts[3] if len(parts) == 5 else ""
        if rover_id not in self.rover_ids:
            self.refused_reports += 1
            return
        report = None
        if payload:
            try:
                report = parse_rover_status(payload)
            except EdgeIpsError as exc:
                self.refused_reports += 1
                log.warning("dashboard: ignoring a rover status that breaks the contract: %s", exc)
                return
            if report.id != rover_id:
                self.refused_reports += 1
                return
        with self._state_lock:
            if self._reports.get(rover_id) == report:
                return
            if report is None:
                del self._reports[rover_id]
            else:
                self._reports[rover_id] = report
        if self.on_report is not None:
            self.on_report(rover_id, report)

    def _set(self, formation: FormationV1 | None) -> None:
        with self._state_lock:
            if formation == self._current:
                return
            self._current = formation
        if self.on_change is not None:
            self.on_change(None if formation is None else formation.model_dump(mode="json"))

    # -- watching the retained message ------------------------------------------------------------------------
    def start(self) -> FormationDesk:
        """Subscribe to the retained formation and the rovers' statuses in the background (paho reconnects)."""
        client = make_client(self.target, f"edge-ips-{self.edge_id}-dashboard", tls=self.tls)

        def on_connect(c: mqtt.Client, u: Any, flags: Any, reason_code: Any, props: Any) -> None:
            if not reason_code.is_failure:
                c.subscribe([(FORMATION_TOPIC, FORMATION_QOS), (ROVER_STATUS_WILDCARD, 1)])

        def on_message(c: mqtt.Client, u: Any, message: mqtt.MQTTMessage) -> None:
            if message.topic != FORMATION_TOPIC:
                self._report(message.topic, bytes(message.payload))
                return
            if not message.payload:
                self._set(None)  # the retained formation was cleared
                return
            try:
                self._set(parse_formation(bytes(message.payload)))
            except EdgeIpsError as exc:
                log.warning("dashboard: ignoring a formation message that breaks the contract: %s", exc)

        client.on_connect = on_connect
        client.on_message = on_message
        client.connect_async(connect_host(self.target), self.target.port, keepalive=30)
        client.loop_start()
        self._client = client
        return self

    def close(self) -> None:
        if self._client is not None:
            self._client.disconnect()
            self._client.loop_stop()
            self._client = None

    # -- commanding -----------------------------------------------------------------------------------------------
    def command(self, headers: Mapping[str, str], body: bytes) -> tuple[int, dict[str, Any]]:
        """Check and publish one posted command: (HTTP status, JSON body)."""
        refused = authorize(self.token, headers)
        if refused is not None:
            return refused.status, {"error": refused.error}
        try:
            make = parse_request(body, self.rover_ids)
        except MessageError as exc:
            return 400, {"error": str(exc)}
        with self._lock:
            try:
                sent = send_formation(
                    self.target, make, client_id=f"edge-ips-{self.edge_id}-dashboard-cmd", tls=self.tls
                )
            except EdgeIpsError as exc:
                log.error("dashboard: formation not published: %s", exc)
                return 502, {"error": f"not published: {exc}"}
        log.info("dashboard: formation %s %s published (seq %d)", sent.kind, ",".join(sent.ids), sent.seq)
        self._set(sent)
        return 200, {"ok": True, "seq": sent.seq, "formation": sent.model_dump(mode="json")}


def formation_targets(
    formation: Mapping[str, Any] | None, positions: Mapping[str, tuple[float, float]]
) -> list[dict[str, Any]] | None:
    """Where each member of ``formation`` (a formation v1 dict) is headed now, ``[{id, x, y}]`` in world cm, or
    None (no formation, ``stop``, or no member seen).

    Computed by the firmware's own ``formation.offsets`` and ``formation.orient`` (the rovers' example config for
    the rendezvous ring), from the members' current ``positions``: so an unanchored triangle is drawn turned and
    mirrored to fit the rovers, as they will form it, not upright. The shape is placed on the anchor (``x``, ``y``)
    when the formation has one, else on the members' mean, which the consensus keeps.
    """
    from edge.rover_host import firmware_modules

    if formation is None or formation.get("kind") not in ("line", "rendezvous", "triangle"):
        return None
    modules = firmware_modules()
    fm, msg, defaults = modules["formation"], modules["msg"], modules["config"].DEFAULTS["control"]
    ids = list(dict.fromkeys(formation["ids"]))  # the firmware's rule: a repeated id keeps its first place
    n = len(ids)
    if n == 0:
        return None
    kind = msg.KINDS.index(formation["kind"])
    ring = defaults["safety_cm"] + defaults["ring_gap_cm"] * (n - 2 if n > 2 else 1)
    spacing, side = formation.get("spacing"), formation.get("side")
    bx, by = [0.0] * n, [0.0] * n
    fm.offsets(kind, n, spacing if spacing is not None else ring, side if side is not None else ring, ring, bx, by)
    present = [k for k, rid in enumerate(ids) if rid in positions]
    if not present:
        return None
    m = len(present)
    px = [positions[ids[k]][0] for k in present]
    py = [positions[ids[k]][1] for k in present]
    cx, cy = [0.0] * m, [0.0] * m
    fm.orient(kind, formation.get("theta"), px, py, [bx[k] for k in present], [by[k] for k in present], m, cx, cy)
    ax = formation["x"] if formation.get("x") is not None else sum(px) / m
    ay = formation["y"] if formation.get("y") is not None else sum(py) / m
    return [{"id": ids[k], "x": round(ax + cx[j], 2), "y": round(ay + cy[j], 2)} for j, k in enumerate(present)]


def with_targets(event: dict[str, Any], formation: Mapping[str, Any] | None) -> dict[str, Any]:
    """The ``pose`` event with ``targets`` (:func:`formation_targets` for the rovers it places) added."""
    positions = {r["id"]: (r["x"], r["y"]) for r in event["rovers"] if r["x"] is not None and r["y"] is not None}
    return {**event, "targets": formation_targets(formation, positions)}
