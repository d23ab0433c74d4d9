"""``edge-ips doctor --fusion``: is the system of several boards healthy? Read from the central broker's retained
messages: the fusers' statuses (one active, a standby), every board's status and bridge, each board's clock
offset as the active fuser estimates it, and the rovers nobody sees. One line per check, with a fix hint.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import paho.mqtt.client as mqtt

from edge.board_messages import FUSER_STATUS_WILDCARD, FuserStatusV1, parse_fuser_status
from edge.config import BrokerTarget, EdgeConfig
from edge.doctor import Check
from edge.errors import MessageError
from edge.messages import StatusV1, parse_status
from edge.mqttclient import TlsFiles, connect_host, make_client

EDGE_STATUS_WILDCARD = "ips/v1/edge/+/status"
BRIDGE_WILDCARD = "ips/v1/edge/+/bridge"
OFFSET_WARN_MS = 20.0  # beyond this the board's clock is not synchronised (NTP) although the fuser corrects it
STATUS_FRESH_S = 5.0


@dataclass
class Snapshot:
    fusers: dict[str, FuserStatusV1] = field(default_factory=dict)
    boards: dict[str, StatusV1] = field(default_factory=dict)
    bridges: dict[str, bytes] = field(default_factory=dict)


def read_snapshot(target: BrokerTarget, tls: TlsFiles | None = None, settle_s: float = 1.5) -> Snapshot:
    """The retained fuser statuses, board statuses and bridge states (and what arrives within ``settle_s``)."""
    snap = Snapshot()
    subscribed = threading.Event()
    failed: list[str] = []
    client = make_client(target, f"edge-ips-doctor-{int(time.time() * 1000) % 100000}", tls=tls)

    def on_connect(c: mqtt.Client, u: Any, flags: Any, rc: Any, props: Any) -> None:
        if rc.is_failure:
            failed.append(str(rc))
            subscribed.set()
            return
        c.subscribe([(FUSER_STATUS_WILDCARD, 1), (EDGE_STATUS_WILDCARD, 1), (BRIDGE_WILDCARD, 1)])

    def on_message(c: mqtt.Client, u: Any, m: mqtt.MQTTMessage) -> None:
        topic, payload = m.topic, bytes(m.payload)
        try:
            if topic.startswith("ips/v1/fuser/"):
                status = parse_fuser_status(payload)
                snap.fusers[status.fuser] = status
            elif topic.endswith("/bridge"):
                snap.bridges[topic.split("/")[3]] = payload
            else:
                board = parse_status(payload)
                snap.boards[board.edge] = board
        except MessageError:
            pass

    client.on_connect = on_connect
    client.on_subscribe = lambda *a: subscribed.set()
    client.on_message = on_message
    try:
        client.connect(connect_host(target), target.port, keepalive=5)
    except OSError as exc:
        raise MessageError(f"broker {target.display()}: cannot connect ({exc})") from exc
    client.loop_start()
    try:
        if not subscribed.wait(5.0) or failed:
            raise MessageError(f"broker {target.display()}: {failed[0] if failed else 'no answer'}")
        time.sleep(settle_s)  # the retained messages follow the subscription at once; live ones within a second
    finally:
        client.disconnect()
        client.loop_stop()
    return snap


def fusion_checks(snap: Snapshot, now_s: float | None = None) -> list[Check]:
    """One line per check of a system of several boards."""
    now = time.time() if now_s is None else now_s
    checks = []
    live = {f: s for f, s in snap.fusers.items() if s.state != "offline" and now - s.t <= STATUS_FRESH_S}
    active = [s for s in live.values() if s.state == "active"]
    standby = [s for s in live.values() if s.state == "standby"]
    if not active:
        checks.append(
            Check(
                "fusers",
                "fail",
                f"no fuser publishes poses ({_names(snap.fusers)})",
                "start edge-ips fuse --broker URL on the central broker's network",
            )
        )
        return checks
    if len(active) > 1:
        checks.append(Check("fusers", "fail", f"{_names(active)} all say active", "report this: the lease failed"))
    elif not standby:
        checks.append(
            Check(
                "fusers",
                "warn",
                f"{active[0].fuser} active, no standby",
                "run a second edge-ips fuse (another --id) to take over if this one dies",
            )
        )
    else:
        checks.append(Check("fusers", "ok", f"{active[0].fuser} active; standby: {_names(standby)}"))
    fuser = active[0]
    for b in fuser.boards:
        own = snap.boards.get(b.edge)
        bridge = snap.bridges.get(b.edge)
        where = (
            f"clock {b.offset_ms:+.1f} ms (+-{b.offset_sigma_ms:.1f}, {b.offset_source})"
            if b.offset_ms is not None
            else "clock unknown"
        )
        detail = f"{b.state}; {where}; {len(b.rovers)} rovers; {b.stale} stale"
        if bridge is not None:
            detail += f"; bridge {'up' if bridge == b'1' else 'down'}"
        if own is not None:
            detail += f"; camera {own.camera}, {own.fps:.0f} fps"
        if b.state != "ok" or bridge == b"0":
            hint = (
                "its bridge is down: check the network between the central broker and the board"
                if bridge == b"0"
                else (
                    "the board is offline: start edge-ips on it"
                    if b.state == "offline"
                    # Mosquitto before 2.0.15 keeps saying "up" for a link that died silently (no TCP reset)
                    else 'no detections arrive: check edge-ips start on the board, edge.publish = "detections" and'
                    " the network between the central broker and the board"
                )
            )
            checks.append(Check(f"board {b.edge}", "fail", detail, hint))
        elif b.offset_ms is not None and abs(b.offset_ms) > OFFSET_WARN_MS:
            checks.append(Check(f"board {b.edge}", "warn", detail, "its clock is off: enable NTP (timedatectl)"))
        elif b.offset_source == "arrival":
            checks.append(
                Check(
                    f"board {b.edge}",
                    "warn",
                    detail,
                    "no rover seen together with another board yet: its clock rests on arrival times",
                )
            )
        elif own is not None and own.state != "online":
            checks.append(Check(f"board {b.edge}", "warn", detail, "see edge-ips doctor on the board"))
        else:
            checks.append(Check(f"board {b.edge}", "ok", detail))
    if fuser.missing:
        checks.append(
            Check(
                "rovers",
                "warn",
                f"{len(fuser.rovers)} seen; missing: {', '.join(fuser.missing)}",
                "a rover outside every view, switched off, or in the view of a board that is down",
            )
        )
    else:
        checks.append(Check("rovers", "ok", f"{len(fuser.rovers)} seen, none missing"))
    return checks


def central_checks(config: EdgeConfig) -> list[Check]:
    """``doctor --fusion``: the checks, from the central broker the configuration (or ``--broker``) names."""
    from edge.fusion.service import central_broker

    return fusion_checks(read_snapshot(*central_broker(config, "doctor --fusion")))


def _names(items: dict[str, FuserStatusV1] | list[FuserStatusV1]) -> str:
    statuses = items.values() if isinstance(items, dict) else items
    return ", ".join(sorted(s.fuser for s in statuses)) or "none"
