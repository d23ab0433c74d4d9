"""An MQTT client that tries what an attacker would, in this process or on "another host".

:class:`Probe` is a paho v2 client (MQTT 3.1.1 unless told; amqtt speaks only 3.1.1) that records its CONNACK, its
disconnections and what it receives, and waits on conditions. :class:`OtherHost` runs ``python -m
tests.support.probe`` with another source address: inside a network namespace joined to this one by a veth pair
(``ip netns``, as root), or, where namespaces are not available, bound to a non-loopback address of this machine.
The password travels in the environment, never on a command line.
"""

from __future__ import annotations

import fcntl
import ipaddress
import json
import os
import random
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt

from tests.conftest import REPO

PASSWORD_ENV = "PROBE_MQTT_PASSWORD"
PROBE_NETWORK = ipaddress.ip_network("10.211.0.0/16")  # the probes' namespaces take /30s of it


class Probe:
    def __init__(
        self,
        host: str,
        port: int,
        *,
        client_id: str = "",
        user: str | None = None,
        password: str | None = None,
        will: tuple[str, bytes] | None = None,
        bind_address: str = "",
        tls: dict[str, Any] | None = None,
        timeout_s: float = 10.0,
    ) -> None:
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True)
        if user is not None:
            self.client.username_pw_set(user, password)
        if will is not None:
            self.client.will_set(will[0], will[1], qos=1, retain=True)
        if tls is not None:
            self.client.tls_set(**tls)
        self._cond = threading.Condition()
        self.connack: Any = None
        self.disconnects = 0
        self.received: list[mqtt.MQTTMessage] = []
        self.error: str = ""
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.client.on_subscribe = self._on_subscribe
        self.granted: list[Any] = []
        try:
            self.client.connect(host, port, keepalive=30, bind_address=bind_address)
        except (OSError, ValueError) as exc:  # a TLS handshake refused, a connection reset
            self.error = f"{type(exc).__name__}: {exc}"
            return
        self.client.loop_start()
        self.wait(lambda: self.connack is not None or self.disconnects > 0, timeout_s)
        if not self.accepted:
            self.client.loop_stop()  # no reconnecting: one attempt is the probe

    def _on_connect(self, c: Any, u: Any, flags: Any, rc: Any, props: Any) -> None:
        with self._cond:
            self.connack = rc
            self._cond.notify_all()

    def _on_disconnect(self, c: Any, u: Any, flags: Any, rc: Any, props: Any) -> None:
        with self._cond:
            self.disconnects += 1
            self._cond.notify_all()

    def _on_message(self, c: Any, u: Any, message: mqtt.MQTTMessage) -> None:
        with self._cond:
            self.received.append(message)
            self._cond.notify_all()

    def _on_subscribe(self, c: Any, u: Any, mid: int, codes: Any, props: Any) -> None:
        with self._cond:
            self.granted.append(codes)
            self._cond.notify_all()

    def wait(self, condition: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        with self._cond:
            return self._cond.wait_for(condition, timeout=timeout_s)

    @property
    def accepted(self) -> bool:
        return self.connack is not None and not self.connack.is_failure

    @property
    def connack_code(self) -> int | None:
        # paho reports MQTT 3.1.1 return codes as v5 reason codes; the 3.1.1 value is what the broker sent.
        if self.connack is None:
            return None
        return {0: 0, 132: 1, 133: 2, 136: 3, 134: 4, 135: 5}.get(self.connack.value, self.connack.value)

    def publish(self, topic: str, payload: bytes, retain: bool = False, qos: int = 1, timeout_s: float = 10.0) -> bool:
        """Publish; with QoS 1, wait for the PUBACK (``timeout_s`` is a failure guard). True once acknowledged."""
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        if qos:
            info.wait_for_publish(timeout_s)
        return info.is_published()

    def subscribe(self, topic_filter: str, qos: int = 1) -> Any:
        before = len(self.granted)
        self.client.subscribe(topic_filter, qos=qos)
        self.wait(lambda: len(self.granted) > before)
        return self.granted[-1][0]

    def payloads(self, topic: str) -> list[bytes]:
        with self._cond:
            return [bytes(m.payload) for m in self.received if m.topic == topic]

    def wait_payload(self, topic: str, payload: bytes, timeout_s: float = 10.0) -> bool:
        return self.wait(lambda: any(m.topic == topic and m.payload == payload for m in self.received), timeout_s)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def __enter__(self) -> Probe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def edge_states_until_marker(publisher: Any, watcher: Probe, edge_id: str) -> list[str]:
    """Have the edge's publisher send a marker status and return every state ``watcher`` saw on the edge's status
    topic up to it: an ``offline`` among them is the edge's last will, published when its session was taken."""
    from edge.messages import edge_status_topic, parse_status
    from edge.publisher import offline_status

    marker = offline_status(edge_id, publisher.rovers, t=1.0).model_copy(update={"state": "online", "camera": "ok"})
    assert publisher.publish_status(marker)
    topic = edge_status_topic(edge_id)
    assert watcher.wait(lambda: any(parse_status(p).t == 1.0 for p in watcher.payloads(topic)))
    return [parse_status(p).state for p in watcher.payloads(topic)]


# -- another host -------------------------------------------------------------------------------------------------
@dataclass
class OtherHost:
    """Where a probe runs from: ``address`` is the address the broker sees; ``host_address`` reaches this machine."""

    address: str
    host_address: str
    namespace: str | None = None

    def probe(self, port: int, **kwargs: Any) -> dict[str, Any]:
        """Run ``python -m tests.support.probe`` from there; returns its JSON report."""
        password = kwargs.pop("password", None)
        cmd = [sys.executable, "-m", "tests.support.probe", "--host", self.host_address, "--port", str(port)]
        if self.namespace is None:
            cmd += ["--bind", self.address]
        else:
            cmd = ["ip", "netns", "exec", self.namespace, *cmd]
        for key, value in kwargs.items():
            cmd += [f"--{key.replace('_', '-')}", str(value)]
        env = {**os.environ, "PYTHONPATH": str(REPO), **({PASSWORD_ENV: password} if password else {})}
        result = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=60)
        assert result.returncode == 0, result.stderr
        report: dict[str, Any] = json.loads(result.stdout.strip().splitlines()[-1])
        return report


def _non_loopback_address() -> str | None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # no packet is sent: this only picks the outgoing interface's address
        except OSError:
            return None
        address: str = s.getsockname()[0]
    return None if address.startswith("127.") else address


def _free_subnet(ip: str | None) -> int:
    """A /30 in 10.211.0.0/16 that no interface of this machine holds (its index: the third byte times 64 plus the
    fourth's quarter): a namespace left behind by a killed run, or one of a run beside this one, on the same subnet
    would take the replies and time the probe out."""
    used: set[int] = set()
    if ip is not None:
        listing = subprocess.run([ip, "-o", "-4", "addr", "show"], capture_output=True, text=True).stdout
        held = (ipaddress.ip_address(a) for a in re.findall(r"inet (\d+\.\d+\.\d+\.\d+)[/ ]", listing))
        used = {(int(a) - int(PROBE_NETWORK.network_address)) // 4 for a in held if a in PROBE_NETWORK}
    free = [n for n in range(1, 250 * 64) if n not in used]
    if not free:
        raise RuntimeError("every /30 of 10.211.0.0/16 is held: namespaces left behind? (`ip netns list`)")
    return random.choice(free)


@contextmanager
def _netns_lock() -> Iterator[None]:
    """Held while a namespace's subnet is chosen and its addresses set, across processes (runs side by side)."""
    with open(os.path.join(tempfile.gettempdir(), "edgeips-netns.lock"), "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@contextmanager
def other_host() -> Iterator[OtherHost]:
    """A network namespace with a veth pair to this one (a free /30 in 10.211.0.0/16), or a non-loopback address
    of this host."""
    name = f"edgeips-{uuid.uuid4().hex[:6]}"
    ip = shutil.which("ip")
    outer, inner = f"vo{name[-6:]}", f"vi{name[-6:]}"
    made = ip is not None and os.geteuid() == 0
    try:
        with _netns_lock():
            subnet = _free_subnet(ip if made else None)
            base = PROBE_NETWORK.network_address + 4 * subnet
            here, there = str(base + 1), str(base + 2)
            steps = [
                ["netns", "add", name],
                ["link", "add", outer, "type", "veth", "peer", "name", inner],
                ["link", "set", inner, "netns", name],
                ["addr", "add", f"{here}/30", "dev", outer],
                ["link", "set", outer, "up"],
                ["netns", "exec", name, "ip", "addr", "add", f"{there}/30", "dev", inner],
                ["netns", "exec", name, "ip", "link", "set", inner, "up"],
                ["netns", "exec", name, "ip", "link", "set", "lo", "up"],
            ]
            for step in steps if made else []:
                if subprocess.run([str(ip), *step], capture_output=True).returncode != 0:
                    made = False
                    break
        if made:
            yield OtherHost(address=there, host_address=here, namespace=name)
        else:
            address = _non_loopback_address()
            assert address is not None, "neither `ip netns` nor a non-loopback address: no other host to probe from"
            yield OtherHost(address=address, host_address=address)
    finally:  # also when a step failed half-way: what was made is removed
        if ip is not None:
            subprocess.run([ip, "link", "del", outer], capture_output=True)
            subprocess.run([ip, "netns", "del", name], capture_output=True)


def main(argv: list[str]) -> None:
    """One probe: connect (login from --user and $PROBE_MQTT_PASSWORD), optionally publish, report as JSON."""
    import argparse

    parser = argparse.ArgumentParser()
    parser.add_argument("--host", required=True)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--bind", default="")
    parser.add_argument("--user", default=None)
    parser.add_argument("--client-id", default="")
    parser.add_argument("--publish", default=None, help="topic: publish --payload (retained, QoS 1) once connected")
    parser.add_argument("--payload", default="")
    parser.add_argument("--payload-bytes", type=int, default=0, help="instead of --payload: this many bytes")
    parser.add_argument("--timeout-s", type=float, default=30.0, help="the most to wait for CONNACK (a failure guard)")
    args = parser.parse_args(argv)
    probe = Probe(
        args.host,
        args.port,
        client_id=args.client_id,
        user=args.user,
        password=os.environ.get(PASSWORD_ENV),
        bind_address=args.bind,
        timeout_s=args.timeout_s,
    )
    report: dict[str, Any] = {"accepted": probe.accepted, "connack": probe.connack_code, "error": probe.error}
    if probe.accepted and args.publish:
        if args.payload_bytes:  # a broker that reads no such packet drops the connection
            probe.client.publish(args.publish, b"x" * args.payload_bytes, qos=1, retain=True)
            report["disconnected"] = probe.wait(lambda: probe.disconnects > 0, 10.0)
        else:
            report["published"] = probe.publish(args.publish, args.payload.encode(), retain=True, timeout_s=30.0)
    if probe.accepted:
        probe.close()
    print(json.dumps(report))


if __name__ == "__main__":
    main(sys.argv[1:])
