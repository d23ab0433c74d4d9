"""The MQTT client every edge connection is made from (paho v2, MQTT 3.1.1, clean session): credentials, TLS,
reconnect backoff, no Nagle delay; and the address this process reaches the broker at."""

from __future__ import annotations

import contextlib
import socket
import ssl
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

from edge.config import BrokerSection, BrokerTarget
from edge.errors import BrokerError, ConfigError


@dataclass(frozen=True)
class TlsFiles:
    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None

    @classmethod
    def of(cls, section: BrokerSection) -> TlsFiles:
        """The files ``[broker]`` names (used when its URL is ``mqtts://``)."""
        return cls(section.ca_file, section.cert_file, section.key_file)

    def check(self) -> None:
        for key, path in (("ca_file", self.ca_file), ("cert_file", self.cert_file), ("key_file", self.key_file)):
            if path is not None and not path.is_file():
                raise ConfigError(f"broker.{key}: {path} not found")
        if (self.cert_file is None) != (self.key_file is None):
            raise ConfigError("broker.cert_file and broker.key_file go together: give both or neither")


def make_client(
    target: BrokerTarget,
    client_id: str,
    *,
    tls: TlsFiles | None = None,
    reconnect_min_s: float = 0.25,
    reconnect_max_s: float = 2.0,
) -> mqtt.Client:
    """A paho v2 client (MQTT 3.1.1, clean session) set up for ``target``, not yet connected."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True)
    if target.username is not None:
        client.username_pw_set(target.username, target.password)
    if target.tls:
        files = tls or TlsFiles()
        files.check()
        client.tls_set(
            ca_certs=str(files.ca_file) if files.ca_file else None,
            certfile=str(files.cert_file) if files.cert_file else None,
            keyfile=str(files.key_file) if files.key_file else None,
            cert_reqs=ssl.CERT_REQUIRED,
        )
    client.reconnect_delay_set(min_delay=reconnect_min_s, max_delay=reconnect_max_s)  # type: ignore[arg-type]
    client.on_socket_open = _no_delay
    return client


def _no_delay(client: mqtt.Client, userdata: Any, sock: Any) -> None:
    # paho leaves Nagle's algorithm on: the 2nd and 3rd pose of a frame would wait for the broker's delayed ACK
    # (up to 40 ms on Linux). Poses are small and latency-bound, so send each segment at once.
    with contextlib.suppress(OSError, AttributeError):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def connect_host(target: BrokerTarget) -> str:
    # The embedded broker listens on every interface; this process reaches it over loopback.
    return "127.0.0.1" if target.embedded and target.host in ("0.0.0.0", "::", "") else target.host


def connect_blocking(client: mqtt.Client, target: BrokerTarget, timeout_s: float) -> None:
    """Connect ``client`` and start its network thread; :class:`BrokerError` when unreachable, silent or refusing."""
    done = threading.Event()
    result: list[str] = []

    def on_connect(c: mqtt.Client, u: Any, flags: Any, reason_code: Any, props: Any) -> None:
        result.append("" if not reason_code.is_failure else str(reason_code))
        done.set()

    client.on_connect = on_connect
    try:
        client.connect(connect_host(target), target.port, keepalive=10)
    except (OSError, ssl.SSLError) as exc:
        raise BrokerError(f"cannot reach broker {target.display()}: {exc}") from exc
    client.loop_start()
    if not done.wait(timeout_s):
        client.loop_stop()
        raise BrokerError(f"broker {target.display()} did not answer within {timeout_s:g} s")
    if result[0]:
        client.loop_stop()
        raise BrokerError(f"broker {target.display()} refused the connection: {result[0]}")
