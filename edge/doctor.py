"""``edge-ips doctor``: is this board ready to run ``edge-ips start``? One line per check, with a fix hint.

Checks the configuration, the camera (opens, resolution, fps), its controls (granted as configured; autofocus, auto
white balance and the camera's sharpening off under a calibration), the calibration (loads, matches the
resolution; points clicked by hand are named, printed targets take their error down), the broker (connects, may
publish) and the clock (synchronised: poses carry the board's wall-clock time).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Literal

from edge.config import BrokerTarget, EdgeConfig, broker_target
from edge.errors import EdgeIpsError
from edge.messages import edge_status_topic, parse_status

if TYPE_CHECKING:
    from edge.source_spec import SimFactory

Level = Literal["ok", "warn", "fail"]


@dataclass(frozen=True)
class Check:
    name: str
    level: Level
    detail: str
    hint: str = ""

    def line(self) -> str:
        text = f"{self.level.upper():4}  {self.name:<12} {self.detail}"
        return f"{text}  -> {self.hint}" if self.hint and self.level != "ok" else text


def check_config(where: str, env_keys: tuple[str, ...]) -> Check:
    env = f"; environment overrides: {', '.join(env_keys)}" if env_keys else ""
    return Check("config", "ok", f"{where}{env}")


def check_camera(config: EdgeConfig, sim_factory: SimFactory | None = None) -> tuple[Check, Any, Any]:
    """Open the source and read one frame. Returns the check, the (closed) source and what it granted."""
    from edge.source_spec import camera_source, parse_source

    cam = config.camera
    try:
        source = camera_source(cam, sim_factory, realtime=False)
        info = source.open()
    except EdgeIpsError as exc:
        hint = "plug the camera in and check `ls /dev/video*`, or try --source sim"
        return Check("camera", "fail", str(exc), hint), None, None
    try:
        frame = source.read()
    except EdgeIpsError as exc:
        source.close()
        return Check("camera", "fail", f"{info.description}: opened but {exc}", "check the cable and power"), None, None
    if frame is None:
        source.close()
        return Check("camera", "fail", f"{info.description}: no frame", "check the source"), None, None
    h, w = frame.image.shape[:2]
    asked = (cam.width, cam.height)
    detail = f"{info.description}; first frame {w}x{h}"
    level: Level = "ok"
    hint = ""
    if parse_source(cam.source).kind == "camera" and ((w, h) != asked or info.fps + 0.5 < cam.fps):
        level = "warn"
        hint = f"the camera did not grant {cam.width}x{cam.height}@{cam.fps:g}; check `v4l2-ctl --list-formats-ext`"
    check = Check("camera", level, detail, hint)
    return check, source, info


def check_controls(config: EdgeConfig, source: Any) -> Check | None:
    """A V4L2 camera's controls: what was not granted, and automatic modes that move a calibration or the hues."""
    from edge.sources import CameraSource

    if not isinstance(source, CameraSource):
        return None
    report = source.controls_report
    try:
        modes = source.automatic_modes()
        sharpening = source.sharpening()
    except EdgeIpsError as exc:
        return Check("controls", "warn", f"cannot read the camera's controls: {exc}", "check the camera's driver")
    if modes and config.calibration.path is not None:
        on = " and ".join(modes)
        return Check(
            "controls",
            "warn",
            f"{on} on: {'they move' if len(modes) > 1 else 'it moves'} the focal length or the marker colours "
            "under a calibration",
            "set [camera.controls] autofocus = false, focus = N, auto_white_balance = false, white_balance_k = K "
            "(docs/deploy.md gives the C920's)",
        )
    if sharpening and config.calibration.path is not None:
        return Check(
            "controls",
            "warn",
            f"the camera sharpens its frames ({sharpening}): the halos move marker centres",
            "set [camera.controls] sharpness to the camera's least (docs/deploy.md gives the C920's)",
        )
    if not report.ok:
        return Check("controls", "warn", f"not all granted: {report.line()}", "see docs/deploy.md, camera controls")
    return Check("controls", "ok", report.line() if report.granted else "the camera's own settings")


def check_calibration(config: EdgeConfig, source: Any, info: Any, where: str) -> Check:
    from edge.appliance import load_calibration_for

    if source is None:
        return Check("calibration", "warn", "not checked: no camera", "fix the camera first")
    try:
        load_calibration_for(config, source, info, where)
    except EdgeIpsError as exc:
        return Check("calibration", "fail", str(exc), "run `edge-ips calibrate` and set calibration.path")
    finally:
        source.close()
    from edge.source_spec import parse_source

    if parse_source(config.camera.source).kind == "sim":
        return Check("calibration", "ok", "simulated camera: its exact calibration")
    loaded = f"{config.calibration.path} loaded for {info.width_px}x{info.height_px}"
    from edge.appliance import calibration_path
    from edge.calibration.files import read_calibration_file
    from edge.calibration.refine import clicked_by_hand, clicked_note

    path = calibration_path(config, where)
    clicked = None if path is None else clicked_by_hand(read_calibration_file(path))
    if clicked is not None:
        return Check(
            "calibration",
            "warn",
            f"{loaded}; {clicked_note(clicked)}",
            "printed targets on the points and `edge-ips calibrate points --refine-on PHOTO` "
            '(docs/calibration.md, "Printed targets on the points")',
        )
    return Check("calibration", "ok", loaded)


def _port_free(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _probe_broker(target: BrokerTarget, config: EdgeConfig, timeout_s: float) -> Check:
    """Connect with MQTT v5 (the broker then says when an ACL refuses a publish) and prove the edge may publish."""
    import paho.mqtt.client as mqtt
    from paho.mqtt.properties import Properties
    from paho.mqtt.reasoncodes import ReasonCode

    from edge.messages import dumps
    from edge.mqttclient import TlsFiles, connect_host
    from edge.publisher import offline_status

    client = mqtt.Client(
        mqtt.CallbackAPIVersion.VERSION2,
        client_id=f"edge-ips-doctor-{config.edge.id}",
        protocol=mqtt.MQTTv311 if target.embedded else mqtt.MQTTv5,  # amqtt speaks MQTT 3.1.1 only
    )
    if target.username is not None:
        client.username_pw_set(target.username, target.password)
    if target.tls:
        files = TlsFiles.of(config.broker)
        files.check()
        client.tls_set(
            ca_certs=str(files.ca_file) if files.ca_file else None,
            certfile=str(files.cert_file) if files.cert_file else None,
            keyfile=str(files.key_file) if files.key_file else None,
        )
    connected = threading.Event()
    outcome: dict[str, Any] = {}
    retained = threading.Event()
    acked = threading.Event()

    def on_connect(c: Any, u: Any, flags: Any, rc: ReasonCode, props: Properties | None) -> None:
        outcome["connect"] = rc
        connected.set()

    def on_message(c: Any, u: Any, msg: Any) -> None:
        outcome["status"] = msg.payload
        retained.set()

    def on_publish(c: Any, u: Any, mid: int, rc: ReasonCode, props: Properties | None) -> None:
        outcome["publish"] = rc
        acked.set()

    client.on_connect, client.on_message, client.on_publish = on_connect, on_message, on_publish
    shown = target.display()
    try:
        client.connect(connect_host(target), target.port, keepalive=10)
    except OSError as exc:
        hint = "is the broker running? check broker.url (or `systemctl status mosquitto`)"
        return Check("broker", "fail", f"cannot reach {shown}: {exc}", hint)
    client.loop_start()
    try:
        if not connected.wait(timeout_s):
            return Check("broker", "fail", f"{shown} did not answer within {timeout_s:g} s", "check host and port")
        rc = outcome["connect"]
        if rc.is_failure:
            return Check("broker", "fail", f"{shown} refused: {rc}", "check broker.username and broker.password")
        topic = edge_status_topic(config.edge.id)
        client.subscribe(topic, qos=1)
        retained.wait(0.5)
        if "status" in outcome:
            try:
                current = parse_status(outcome["status"])
                if current.state != "offline" and time.time() - current.t < 3 * config.edge.status_interval_s + 5:
                    return Check("broker", "ok", f"{shown}: edge {config.edge.id} is running ({current.state})")
            except EdgeIpsError:
                pass
        # Re-publish "offline", retained: true whenever the edge is not running, so nothing changes for rovers.
        info = client.publish(topic, dumps(offline_status(config.edge.id, [r.id for r in config.rovers])), 1, True)
        if not acked.wait(timeout_s) or info.rc != mqtt.MQTT_ERR_SUCCESS:
            return Check("broker", "fail", f"{shown}: publish not acknowledged", "check the broker's log")
        if outcome["publish"].is_failure:
            hint = "the ACL must let the edge user write its status and poses (edge-ips broker-config)"
            return Check("broker", "fail", f"{shown}: may not publish to {topic}: {outcome['publish']}", hint)
        return Check("broker", "ok", f"{shown}: connected and may publish")
    finally:
        client.disconnect()
        client.loop_stop()


def _embedded_logins(config: EdgeConfig) -> tuple[str, BrokerTarget | None, str]:
    """How the embedded broker's logins look (for the line), the edge's target with its login if readable, and a
    problem with the file ("" if none)."""
    import stat

    from edge.broker.clients import embedded_credentials, select_broker

    path = embedded_credentials(config)
    if not path.exists():
        return f"logins generated on the first start in {path}", None, ""
    mode = stat.S_IMODE(path.stat().st_mode)
    try:
        target = select_broker(config).target
    except EdgeIpsError as exc:
        return f"logins in {path}", None, str(exc)
    if mode & 0o077:
        return f"logins in {path}", target, f"{path} is mode {mode:o}: others may read the passwords (chmod 600)"
    return f"logins in {path} (mode 600)", target, ""


def check_broker(config: EdgeConfig, timeout_s: float = 5.0) -> Check:
    target = broker_target(config.broker)
    if target.embedded:
        logins, edge, problem = _embedded_logins(config)
        where = f"embedded: amqtt on {target.host}:{target.port}, {logins}; anonymous: read-only, this machine only"
        if problem:
            return Check("broker", "warn" if edge is not None else "fail", f"{where}: {problem}", "fix the file")
        if _port_free(target.host, target.port):
            return Check("broker", "ok", f"{where}; port {target.port} is free")
        try:
            probe = _probe_broker(edge or target, config, timeout_s)
        except Exception as exc:
            probe = Check("broker", "fail", str(exc))
        if probe.level == "ok" and "is running" in probe.detail:
            return Check("broker", "ok", f"{where}; {probe.detail}")
        hint = "stop the other broker, set broker.embedded_port, or use it: broker.url = mqtt://localhost:PORT"
        return Check("broker", "fail", f"embedded: port {target.port} on {target.host} is in use", hint)
    probe = _probe_broker(target, config, timeout_s)
    login = f"login {target.username}" if target.username else "anonymous"
    return replace(probe, detail=f"{probe.detail} ({'TLS' if target.tls else 'no TLS'}, {login})")


def check_clock() -> Check:
    now = time.time()
    if now < 1_735_689_600:  # 2025-01-01: a board without a real-time clock that never synchronised
        shown = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(now))
        return Check("clock", "fail", f"{shown} UTC: never synchronised", "sudo timedatectl set-ntp true")
    tool = shutil.which("timedatectl")
    if tool is None:
        return Check("clock", "warn", "cannot tell whether the clock is synchronised (no timedatectl)", "use NTP")
    try:
        result = subprocess.run(
            [tool, "show", "-p", "NTPSynchronized", "--value"], capture_output=True, text=True, timeout=5
        )
    except (OSError, subprocess.TimeoutExpired):
        return Check("clock", "warn", "timedatectl did not answer", "check systemd-timesyncd")
    if result.returncode != 0:
        return Check("clock", "warn", "timedatectl cannot tell (no systemd here?)", "use NTP (systemd-timesyncd)")
    if result.stdout.strip() == "yes":
        return Check("clock", "ok", "synchronised (NTP)")
    return Check("clock", "warn", "not synchronised: pose times will drift", "sudo timedatectl set-ntp true")


def run_checks(
    config: EdgeConfig,
    *,
    where: str,
    env_keys: tuple[str, ...] = (),
    sim_factory: SimFactory | None = None,
) -> Iterator[Check]:
    """Every check, in order, as it completes."""
    yield check_config(where, env_keys)
    camera, source, info = check_camera(config, sim_factory)
    yield camera
    controls = check_controls(config, source)
    if controls is not None:
        yield controls
    yield check_calibration(config, source, info, where)
    try:
        yield check_broker(config)
    except EdgeIpsError as exc:
        yield Check("broker", "fail", str(exc))
    yield check_clock()
