"""A central Mosquitto that crashes brings back an older retained formation: the fusers halt the fleet before they
publish a pose again (``shared/schema/README.md``, "Commands", rule 4).

Real parts: Mosquitto with persistence, the central broker's logins and ACL as ``broker-config --bridge`` writes them
(``central_rights``; client id = user name, so the fuser's stop must go over its own connection), a camera board
without a camera (``tests.support.synthetic_board``, its own process), two fusers (``FuserService``, the lease
between them) and an observer that records the order in which the broker delivers formations and poses. The broker
is killed with SIGKILL while a rendezvous is commanded; its database holds the line it saved at its last clean exit.
Every wait is on a message, a connection or a counter, bounded by a generous failure timeout.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest

from edge.broker.access import rights_acl_text
from edge.broker.bridge import central_rights
from edge.broker.mosquitto import write_password_file
from edge.commands import build_formation, send_formation
from edge.config import BrokerTarget
from edge.fusion.service import FuserService
from edge.messages import FORMATION_TOPIC, POSE_WILDCARD
from tests.conftest import REPO
from tests.support.mosquitto import Mosquitto
from tests.support.proxy import Proxy
from tests.support.runtime import MqttRecorder, Received, stop_process

pytestmark = pytest.mark.realtime

TIMEOUT_S = 60.0  # failure guard only
FUSERS = ["fuser-a", "fuser-b"]
PASSWORDS = {"edge": "edge-pw", "viewer": "viewer-pw", "board": "board-pw", **{f: f"{f}-pw" for f in FUSERS}}
OLD_LINE = build_formation("line", ["r1", "r2", "r3"], seq=41, spacing_cm=60.0)
BOARD_ACL = "user board\ntopic write ips/v1/edge/a/#\n"  # at the central broker a board's messages come by bridge


def central_acl(fusers_publish_formation: bool = True) -> str:
    rights = central_rights(FUSERS, [])
    if not fusers_publish_formation:  # the fusers' rights before they published a stop
        rights = {
            user: replace(r, publish=tuple(t for t in r.publish if t != FORMATION_TOPIC)) if user in FUSERS else r
            for user, r in rights.items()
        }
    return rights_acl_text(rights) + "\n" + BOARD_ACL


@dataclass
class Central:
    broker: Mosquitto
    acl: Path

    def login(self, user: str, port: int | None = None) -> BrokerTarget:
        return BrokerTarget(
            embedded=False,
            host=self.broker.host,
            port=self.broker.port if port is None else port,
            username=user,
            password=PASSWORDS[user],
        )

    def set_acl(self, text: str) -> None:
        self.acl.write_text(text)
        assert self.broker.proc is not None
        self.broker.proc.send_signal(signal.SIGHUP)  # Mosquitto reloads its ACL


@contextmanager
def central(tmp_path: Path, acl: str) -> Iterator[Central]:
    """The central Mosquitto (persistence on, as Debian runs it), whose database already holds ``OLD_LINE``, as one
    that ran the fleet on a line before would."""
    (tmp_path / "db").mkdir()
    passwd = write_password_file(tmp_path / "passwd", PASSWORDS)
    acl_path = tmp_path / "acl"
    acl_path.write_text(acl)
    conf = tmp_path / "central.conf"
    conf.write_text(
        "listener 1883\nuse_username_as_clientid true\nallow_anonymous false\n"
        f"password_file {passwd}\nacl_file {acl_path}\npersistence true\npersistence_location {tmp_path}/db/\n"
    )
    broker = Mosquitto(tmp_path / "run", conf_path=conf)
    c = Central(broker, acl_path)
    with broker:
        send_formation(c.login("edge"), lambda seq: OLD_LINE)  # saved at the clean exit
    broker.start()
    try:
        yield c
    finally:
        broker.stop()


class Observer(MqttRecorder):
    """Everything delivered on formations and poses, and where each of its connections began."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.starts: list[int] = []  # index in messages of each connection's first message

    def _on_connect(self, c: Any, u: Any, flags: Any, rc: Any, props: Any) -> None:
        with self._cond:
            self.starts.append(len(self.messages))
        super()._on_connect(c, u, flags, rc, props)

    def __enter__(self) -> Observer:
        self.start()
        return self

    def session(self) -> list[str]:
        """The latest connection's messages: ``pose``, or the formation's kind and seq (``stop 42``)."""
        with self._cond:
            got = self.messages[self.starts[-1] :] if self.starts else []
        return [kind(m) for m in got]


def kind(m: Received) -> str:
    if m.topic.endswith("/pose"):
        return "pose"
    f = json.loads(m.payload)
    return f"{f['kind']} {f['seq']}"


def observer(c: Central) -> Observer:
    return Observer(c.broker.host, c.broker.port, (FORMATION_TOPIC, POSE_WILDCARD), "viewer", PASSWORDS["viewer"])


@contextmanager
def board(c: Central, cwd: Path) -> Iterator[subprocess.Popen[str]]:
    """A board's detections of three rovers at 30 frames/s, straight to the central broker (reconnecting on its
    own, as paho's network thread does)."""
    url = f"mqtt://board:{PASSWORDS['board']}@{c.broker.host}:{c.broker.port}"
    args = [sys.executable, "-m", "tests.support.synthetic_board", url, "a", "0,0,800,550", "0"]
    proc = subprocess.Popen(args, cwd=cwd, env={"PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        yield proc
    finally:
        stop_process(proc)


@contextmanager
def fuser_started(service: FuserService) -> Iterator[FuserService]:
    service.start()
    try:
        yield service
    finally:
        service.stop()


def fuser(target: BrokerTarget, fuser_id: str) -> FuserService:
    return FuserService(target, fuser_id, client_id=fuser_id)


class Fused:
    """A condition notified after every detections message a fuser handled, to wait on its counters."""

    def __init__(self, service: FuserService) -> None:
        self.changed = threading.Condition()
        fuse = service._fuse

        def counted(payload: bytes) -> None:
            fuse(payload)
            with self.changed:
                self.changed.notify_all()

        service._fuse = counted  # type: ignore[method-assign]

    def wait(self, condition: Callable[[], bool]) -> bool:
        with self.changed:
            return self.changed.wait_for(condition, TIMEOUT_S)


def before_first_pose(session: list[str]) -> list[str]:
    return session[: session.index("pose")] if "pose" in session else session


@pytest.mark.slow
def test_after_the_central_broker_crashed_the_fusers_stop_the_fleet_before_any_pose(
    tmp_path: Path, record_property: Callable[[str, object], None]
) -> None:
    with ExitStack() as stack:
        c = stack.enter_context(central(tmp_path, central_acl()))
        watch = stack.enter_context(observer(c))
        assert watch.wait_subscribed(TIMEOUT_S)
        # each fuser reaches the broker through a link the test holds down after the crash, until the observer has
        # the replayed line: the window this test is about, whatever the reconnection backoffs do
        links = {f: Proxy(c.broker.port).start() for f in FUSERS}
        for link in links.values():
            stack.callback(link.stop)
        fusers = [stack.enter_context(fuser_started(fuser(c.login(f, links[f].port), f))) for f in FUSERS]
        stack.enter_context(board(c, tmp_path))
        for f in fusers:
            assert f.wait_poses_released(TIMEOUT_S)
        assert watch.wait_for(lambda m: "pose" in watch.session(), TIMEOUT_S)
        first = before_first_pose(watch.session())
        assert first[0] == "line 41" and set(first[1:]) <= {"stop 42", "stop 43"} and len(first) >= 2, first

        rendezvous = send_formation(c.login("edge"), lambda seq: build_formation("rendezvous", ["r1"], seq=seq))
        assert watch.wait_for(lambda m: f"rendezvous {rendezvous.seq}" in watch.session(), TIMEOUT_S)

        assert c.broker.proc is not None
        for link in links.values():
            link.down()
        c.broker.proc.kill()  # the stops and the rendezvous were never saved
        c.broker.proc.wait()
        c.broker.start()
        assert watch.wait_for(lambda m: len(watch.starts) == 2 and watch.session()[:1] == ["line 41"], TIMEOUT_S)
        for link in links.values():
            link.up()

        for f in fusers:  # each on its second connection, its stop taken there
            assert f.wait_poses_released(TIMEOUT_S) and f.stats.connects == 2
        assert watch.wait_for(lambda m: "pose" in watch.session(), TIMEOUT_S)
        session = watch.session()
        for f in fusers:
            record_property(f"{f.fuser_id} poses_held", f.stats.poses_held)
    # the replayed line, then the fusers' stops (the same command twice, or one after the other), then poses
    replayed = before_first_pose(session)
    assert replayed[0] == "line 41" and len(replayed) >= 2, session
    assert set(replayed[1:]) <= {"stop 42", "stop 43"}, session
    assert [k for k in session if k != "pose"][1:] in (["stop 42", "stop 42"], ["stop 42", "stop 43"]), session


@pytest.mark.slow
def test_a_fuser_whose_stop_the_broker_refuses_holds_its_poses_until_it_takes_one(tmp_path: Path) -> None:
    """The central's ACL drops the fuser's stop (Mosquitto acknowledges it all the same): the fuser takes the lease
    and fuses, and publishes no pose; once the ACL lets the stop through (reloaded), the stop comes first."""
    with ExitStack() as stack:
        c = stack.enter_context(central(tmp_path, central_acl(fusers_publish_formation=False)))
        watch = stack.enter_context(observer(c))
        assert watch.wait_subscribed(TIMEOUT_S)
        service = fuser(c.login("fuser-a"), "fuser-a")
        fused = Fused(service)
        stack.enter_context(fuser_started(service))
        stack.enter_context(board(c, tmp_path))
        assert fused.wait(lambda: service.lease.is_holder and service.stats.poses_held >= 30)
        assert not service.wait_poses_released(0.0) and service.stats.poses_sent == 0
        assert service.stop_at_start.attempts >= 1 and not service.stop_at_start.done.is_set()

        c.set_acl(central_acl())
        assert service.wait_poses_released(TIMEOUT_S)
        assert watch.wait_for(lambda m: "pose" in watch.session(), TIMEOUT_S)
        held = service.stats.poses_held
    assert service.stop_at_start.attempts >= 2  # tried again while the poses stayed held
    assert before_first_pose(watch.session()) == ["line 41", "stop 42"]
    assert held >= 30
