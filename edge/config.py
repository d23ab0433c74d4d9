"""The appliance's configuration as typed sections (``[edge]``, ``[camera]``, ``[calibration]``, ``[[rovers]]``,
``[tracker]``, ``[broker]``, ``[recording]``, ``[http]``, ``[dashboard]``), validated once into :class:`EdgeConfig`;
the broker URL it names, and the appliance's state directory.

Reading it (which file, ``EDGE_IPS_...`` environment overrides, the command line's) is :mod:`edge.config_load`;
showing it and the starting file are :mod:`edge.config_text`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal
from urllib.parse import unquote, urlsplit

from pydantic import BaseModel, ConfigDict, Field, SecretStr, field_validator, model_validator

from edge.camera_controls import CameraControls
from edge.messages import ID_PATTERN
from edge.tracker_config import DEFAULT_ROVERS, RoverConfig, TrackerSettings, require_unique_ids

_SECTION = ConfigDict(extra="forbid", validate_default=True, allow_inf_nan=False)


class EdgeSection(BaseModel):
    """Who this appliance is and how often it says so."""

    model_config = _SECTION

    id: str = Field(default="edge-1", pattern=ID_PATTERN, description="Edge id: the status topic segment.")
    status_interval_s: float = Field(default=2.0, ge=0.05, le=60.0, description="Seconds between status refreshes.")
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    state_dir: Path | None = Field(
        default=None,
        description="The appliance's state (the embedded broker's logins). Default: $STATE_DIRECTORY (systemd), "
        "else $XDG_STATE_HOME/edge-ips, else ~/.local/state/edge-ips.",
    )
    publish: Literal["poses", "detections"] = Field(
        default="poses",
        description="poses: the only camera, publish each rover's pose; detections: one board of several, publish "
        "what it measured on ips/v1/edge/<id>/detections for edge-ips fuse (which publishes the poses).",
    )


class CameraSection(BaseModel):
    """Where frames come from and what to ask the camera for."""

    model_config = _SECTION

    source: str = Field(
        default="sim",
        min_length=1,
        description="V4L2 index or /dev/videoN, a video file, rtsp:// or http(s):// stream, or sim[:SCENARIO].",
    )
    width: int = Field(default=1280, gt=0, le=8192)
    height: int = Field(default=720, gt=0, le=8192)
    fps: float = Field(default=30.0, gt=0.0, le=240.0)
    fourcc: str = Field(default="MJPG", min_length=4, max_length=4, description="Pixel format asked of a camera.")
    loop: bool = Field(default=False, description="Video files: start again at the end.")
    realtime: bool = Field(default=True, description="Video files and the simulator: deliver at the source's fps.")
    stall_timeout_s: float = Field(default=2.0, ge=0.05, le=60.0, description="No frame for this long = stalled.")
    reopen_min_s: float = Field(default=0.5, ge=0.005, le=60.0, description="First wait before reopening a source.")
    reopen_max_s: float = Field(default=8.0, ge=0.005, le=600.0, description="Longest wait between reopen attempts.")
    controls: CameraControls = Field(
        default_factory=CameraControls, description="V4L2 cameras: focus, white balance, exposure... set at every open."
    )


class CalibrationSection(BaseModel):
    model_config = _SECTION

    path: Path | None = Field(default=None, description="calibration file (edge-ips calibrate); relative to config.")


class BrokerSection(BaseModel):
    """Which MQTT broker to publish to: ``embedded`` (amqtt in-process) or an external one."""

    model_config = _SECTION

    url: str = Field(default="embedded", description="embedded, mqtt://[user:pass@]host[:port] or mqtts://...")
    client_id: str | None = Field(default=None, max_length=64, description="Default: edge-ips-<edge id>.")
    username: str | None = None
    password: SecretStr | None = None
    ca_file: Path | None = Field(default=None, description="TLS: CA certificate (PEM) that signed the broker's.")
    cert_file: Path | None = Field(default=None, description="TLS: client certificate (PEM), optional.")
    key_file: Path | None = Field(default=None, description="TLS: client key (PEM), with cert_file.")
    keepalive_s: int = Field(default=10, ge=2, le=3600)
    reconnect_min_s: float = Field(default=0.25, ge=0.01, le=60.0)
    reconnect_max_s: float = Field(default=2.0, ge=0.01, le=600.0)
    embedded_host: str = Field(
        default="0.0.0.0", description="Embedded broker: address to listen on (logins required but from loopback)."
    )
    embedded_port: int = Field(default=1883, ge=0, le=65535, description="Embedded broker: TCP port (0: any free).")

    @field_validator("url")
    @classmethod
    def _url_is_a_broker(cls, value: str) -> str:
        parse_broker_url(value)
        return value


class RecordingSection(BaseModel):
    """JSON lines of everything published, rotated by size."""

    model_config = _SECTION

    dir: Path | None = Field(default=None, description="Directory for the recording; unset = no recording.")
    max_bytes: int = Field(default=50_000_000, ge=10_000, le=2**40, description="Start a new file beyond this size.")
    max_files: int = Field(default=20, ge=1, le=100_000, description="Keep at most this many files (oldest deleted).")


class HttpSection(BaseModel):
    """The small HTTP server: /healthz, /metrics and the dashboard."""

    model_config = _SECTION

    enabled: bool = True
    host: str = "0.0.0.0"
    port: int = Field(default=8080, ge=0, le=65535, description="0 picks a free port (logged).")
    allowed_hosts: list[str] = Field(
        default_factory=list,
        max_length=64,
        description="More names the board is reached by (its hostname, <hostname>.local, localhost and its "
        'addresses are always allowed); ["*"] turns the Host check off (behind a reverse proxy).',
    )
    max_connections: int = Field(default=64, ge=4, le=4096, description="Open connections at most.")
    request_timeout_s: float = Field(
        default=10.0, ge=0.2, le=300.0, description="Seconds a client has to send a request (and to read a reply)."
    )
    max_streams: int = Field(default=16, ge=1, le=1024, description="Event streams (open dashboard pages) at most.")

    @field_validator("allowed_hosts")
    @classmethod
    def _host_names(cls, hosts: list[str]) -> list[str]:
        for host in hosts:
            if not host.strip() or any(c in host for c in " /@?#"):
                raise ValueError(f"{host!r} is not a host name or address (no scheme, port or path)")
        return hosts


class DashboardSection(BaseModel):
    """The live web page on the HTTP server (``/``): camera view, map, rover status, formation controls."""

    model_config = _SECTION

    enabled: bool = Field(default=True, description="Serve the dashboard at / on the HTTP server.")
    token: SecretStr | None = Field(
        default=None,
        min_length=8,
        description="Bearer token for the formation controls and for viewing; unset = controls disabled.",
    )
    viewer_token: SecretStr | None = Field(
        default=None,
        min_length=8,
        description="A second token that can only view (camera, events, state), not command.",
    )
    frame_fps: float = Field(default=10.0, gt=0.0, le=30.0, description="Most camera frames per second sent.")
    jpeg_quality: int = Field(default=70, ge=10, le=95, description="JPEG quality of the camera view.")
    max_width_px: int = Field(default=960, ge=160, le=4096, description="Camera view downscaled to this width.")
    pose_hz: float = Field(default=15.0, gt=0.0, le=60.0, description="Most pose events per second per viewer.")
    rovers_file: Path | None = Field(
        default=None,
        description="Where the page's enrolment saves the [[rovers]] it measured (relative to this file); "
        "unset = download only. Never a configuration with other sections.",
    )


class EdgeConfig(BaseModel):
    """The whole configuration file."""

    model_config = _SECTION

    edge: EdgeSection = Field(default_factory=EdgeSection)
    camera: CameraSection = Field(default_factory=CameraSection)
    calibration: CalibrationSection = Field(default_factory=CalibrationSection)
    rovers: list[RoverConfig] = Field(default_factory=lambda: list(DEFAULT_ROVERS), min_length=1, max_length=64)
    tracker: TrackerSettings = Field(default_factory=TrackerSettings, description="Tracking pipeline settings.")
    broker: BrokerSection = Field(default_factory=BrokerSection)
    recording: RecordingSection = Field(default_factory=RecordingSection)
    http: HttpSection = Field(default_factory=HttpSection)
    dashboard: DashboardSection = Field(default_factory=DashboardSection)

    @field_validator("tracker", mode="before")
    @classmethod
    def _no_rovers_in_tracker(cls, value: Any) -> Any:
        if isinstance(value, Mapping) and "rovers" in value:
            raise ValueError("the rovers are configured in [[rovers]] tables, not in [tracker]")
        return value

    @field_validator("rovers")
    @classmethod
    def _unique_ids(cls, rovers: list[RoverConfig]) -> list[RoverConfig]:
        return require_unique_ids(rovers)

    @model_validator(mode="after")
    def _one_board_tracks_at_most_32(self) -> EdgeConfig:
        # a board publishing poses lists every rover in its status (32 at most); more rovers take several boards
        if self.edge.publish == "poses" and len(self.rovers) > 32:
            raise ValueError(
                f"{len(self.rovers)} rovers: one board publishing poses tracks at most 32 (with more, "
                'set edge.publish = "detections" on each board and run edge-ips fuse)'
            )
        return self


# -- broker URLs -------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BrokerTarget:
    """Where to connect, parsed from ``broker.url`` (credentials in the URL win over the config's)."""

    embedded: bool
    host: str
    port: int
    tls: bool = False
    username: str | None = None
    password: str | None = None

    def display(self) -> str:
        """The URL without its password, for logs."""
        if self.embedded:
            return f"embedded (amqtt on {self.host}:{self.port})"
        user = f"{self.username}@" if self.username else ""
        return f"{'mqtts' if self.tls else 'mqtt'}://{user}{self.host}:{self.port}"


def parse_broker_url(url: str) -> BrokerTarget:
    """``embedded``, ``mqtt://[user:pass@]host[:port]`` (1883) or ``mqtts://...`` (8883)."""
    if url == "embedded":
        return BrokerTarget(embedded=True, host="0.0.0.0", port=1883)
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
        raise ValueError(f"{url!r} is not a broker URL: use embedded, mqtt://host:port or mqtts://host:port")
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"{url!r}: the port is not a number in 1-65535") from None
    if parts.path not in ("", "/"):
        raise ValueError(f"{url!r}: a broker URL has no path")
    tls = parts.scheme == "mqtts"
    return BrokerTarget(
        embedded=False,
        host=parts.hostname,
        port=port or (8883 if tls else 1883),
        tls=tls,
        username=unquote(parts.username) if parts.username else None,
        password=unquote(parts.password) if parts.password else None,
    )


def broker_target(section: BrokerSection) -> BrokerTarget:
    """The broker to use: URL, then the section's credentials where the URL has none."""
    target = parse_broker_url(section.url)
    if target.embedded:
        return BrokerTarget(embedded=True, host=section.embedded_host, port=section.embedded_port)
    password = target.password
    if password is None and section.password is not None:
        password = section.password.get_secret_value()
    return BrokerTarget(
        embedded=False,
        host=target.host,
        port=target.port,
        tls=target.tls,
        username=target.username or section.username,
        password=password,
    )


# -- the state directory -----------------------------------------------------------------------------------------
def default_state_dir(env: Mapping[str, str]) -> Path:
    """``$STATE_DIRECTORY`` (set by systemd's StateDirectory=), else ``$XDG_STATE_HOME/edge-ips``, else
    ``~/.local/state/edge-ips``."""
    if env.get("STATE_DIRECTORY"):
        return Path(env["STATE_DIRECTORY"].split(":")[0])
    if env.get("XDG_STATE_HOME"):
        return Path(env["XDG_STATE_HOME"]) / "edge-ips"
    home = Path(env["HOME"]) if env.get("HOME") else Path.home()
    return home / ".local" / "state" / "edge-ips"


def state_dir(config: EdgeConfig) -> Path:
    """Where the appliance keeps its state: ``edge.state_dir`` (:func:`load_config` fills it in from the
    environment when the file does not set it)."""
    return config.edge.state_dir if config.edge.state_dir is not None else default_state_dir({})
