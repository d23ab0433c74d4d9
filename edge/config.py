"""The appliance's configuration: one TOML file, validated once, with ``EDGE_IPS_...`` environment overrides.

Lookup when no ``--config`` is given: ``$EDGE_IPS_CONFIG``, then ``./edge-ips.toml``, then
``/etc/edge-ips/config.toml``; with none of them the defaults apply (simulated camera, embedded broker).
An environment variable ``EDGE_IPS_<SECTION>__<KEY>`` overrides one key (``EDGE_IPS_BROKER__URL=mqtt://pi:1883``);
``EDGE_IPS_ROVERS`` takes a JSON list; other ``EDGE_IPS_`` names (the flasher's ``EDGE_IPS_WIFI_SSID``) are not
ours. Every error names the file (or the variable) and the key at fault.

Nothing here reads the process environment by itself: the caller passes the mapping in (STYLE point 7).
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal
from urllib.parse import unquote, urlsplit

from pydantic import BaseModel, ConfigDict, Field, SecretStr, ValidationError, field_validator

from edge.errors import ConfigError
from edge.messages import ID_PATTERN
from edge.tracker_config import DEFAULT_ROVERS, RoverConfig, TrackerSettings, require_unique_ids

ENV_PREFIX = "EDGE_IPS_"
ENV_CONFIG_PATH = "EDGE_IPS_CONFIG"
DEFAULT_PATHS = (Path("edge-ips.toml"), Path("/etc/edge-ips/config.toml"))
MASK = "********"

_SECTION = ConfigDict(extra="forbid", validate_default=True)


class EdgeSection(BaseModel):
    """Who this appliance is and how often it says so."""

    model_config = _SECTION

    id: str = Field(default="edge-1", pattern=ID_PATTERN, description="Edge id: the status topic segment.")
    status_interval_s: float = Field(default=2.0, gt=0.0, le=60.0, description="Seconds between status refreshes.")
    log_level: Literal["debug", "info", "warning", "error"] = "info"


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
    stall_timeout_s: float = Field(default=2.0, gt=0.0, le=60.0, description="No frame for this long = stalled.")
    reopen_min_s: float = Field(default=0.5, gt=0.0, le=60.0, description="First wait before reopening a source.")
    reopen_max_s: float = Field(default=8.0, gt=0.0, le=600.0, description="Longest wait between reopen attempts.")


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
    reconnect_min_s: float = Field(default=0.25, gt=0.0, le=60.0)
    reconnect_max_s: float = Field(default=2.0, gt=0.0, le=600.0)
    embedded_host: str = Field(default="0.0.0.0", description="Embedded broker: address to listen on.")
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
    max_bytes: int = Field(default=50_000_000, ge=10_000, description="Start a new file beyond this size.")
    max_files: int = Field(default=20, ge=1, description="Keep at most this many files (oldest deleted).")


class HttpSection(BaseModel):
    """The small HTTP server: /healthz, /metrics and the dashboard."""

    model_config = _SECTION

    enabled: bool = True
    host: str = "0.0.0.0"
    port: int = Field(default=8080, ge=0, le=65535, description="0 picks a free port (logged).")


class DashboardSection(BaseModel):
    """The live web page on the HTTP server (``/``): camera view, map, rover status, formation controls."""

    model_config = _SECTION

    enabled: bool = Field(default=True, description="Serve the dashboard at / on the HTTP server.")
    token: SecretStr | None = Field(
        default=None,
        min_length=8,
        description="Bearer token the formation controls require; unset = controls disabled.",
    )
    frame_fps: float = Field(default=10.0, gt=0.0, le=30.0, description="Most camera frames per second sent.")
    jpeg_quality: int = Field(default=70, ge=10, le=95, description="JPEG quality of the camera view.")
    max_width_px: int = Field(default=960, ge=160, le=4096, description="Camera view downscaled to this width.")
    pose_hz: float = Field(default=15.0, gt=0.0, le=60.0, description="Most pose events per second per viewer.")


class EdgeConfig(BaseModel):
    """The whole configuration file."""

    model_config = _SECTION

    edge: EdgeSection = Field(default_factory=EdgeSection)
    camera: CameraSection = Field(default_factory=CameraSection)
    calibration: CalibrationSection = Field(default_factory=CalibrationSection)
    rovers: list[RoverConfig] = Field(default_factory=lambda: list(DEFAULT_ROVERS), min_length=1, max_length=32)
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


@dataclass(frozen=True)
class LoadedConfig:
    """A validated configuration and where it came from (``path`` is None when only defaults applied)."""

    config: EdgeConfig
    path: Path | None
    env_keys: tuple[str, ...] = ()


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


# -- loading -----------------------------------------------------------------------------------------------------
def find_config(explicit: Path | None, env: Mapping[str, str], cwd: Path | None = None) -> Path | None:
    """The file to read: ``explicit`` (must exist), ``$EDGE_IPS_CONFIG`` (must exist), else the default lookup."""
    if explicit is not None:
        if not explicit.is_file():
            raise ConfigError(f"{explicit}: configuration file not found")
        return explicit
    if env.get(ENV_CONFIG_PATH):
        named = Path(env[ENV_CONFIG_PATH])
        if not named.is_file():
            raise ConfigError(f"{named}: configuration file not found (named by {ENV_CONFIG_PATH})")
        return named
    base = cwd or Path.cwd()
    for candidate in DEFAULT_PATHS:
        path = candidate if candidate.is_absolute() else base / candidate
        if path.is_file():
            return path
    return None


def _env_value(text: str) -> Any:
    # JSON for lists and tables (EDGE_IPS_ROVERS='[...]'); scalars stay strings, pydantic converts them.
    stripped = text.strip()
    if stripped[:1] in ("[", "{"):
        try:
            return json.loads(stripped)
        except json.JSONDecodeError:
            return text
    return text


def env_overrides(env: Mapping[str, str]) -> dict[tuple[str, ...], tuple[str, Any]]:
    """``{key path: (variable name, value)}`` for the overriding ``EDGE_IPS_...`` variables.

    An override is ``EDGE_IPS_<SECTION>__<KEY>`` or names a top-level key (``EDGE_IPS_ROVERS``). Other
    ``EDGE_IPS_`` variables belong to other tools (the firmware flasher's ``EDGE_IPS_WIFI_SSID``...) and
    ``EDGE_IPS_CONFIG`` names the file: they are left alone.
    """
    found: dict[tuple[str, ...], tuple[str, Any]] = {}
    top_level = {name.upper() for name in EdgeConfig.model_fields}
    for name, value in sorted(env.items()):
        if not name.startswith(ENV_PREFIX) or name == ENV_CONFIG_PATH:
            continue
        rest = name[len(ENV_PREFIX) :]
        if "__" not in rest and rest not in top_level:
            continue
        path = tuple(part.lower() for part in rest.split("__"))
        if not all(path):
            raise ConfigError(f"environment variable {name}: expected EDGE_IPS_<SECTION>__<KEY>")
        found[path] = (name, _env_value(value))
    return found


def _merge(data: dict[str, Any], path: tuple[str, ...], value: Any, origin: str) -> None:
    node = data
    for part in path[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"{origin}: {'.'.join(path[:-1])} is not a table")
        node = child
    node[path[-1]] = value


def _resolve_paths(config: EdgeConfig, base: Path) -> EdgeConfig:
    """Relative file paths in the file are relative to the file, not to the working directory."""

    def fix(p: Path | None) -> Path | None:
        return p if p is None or p.is_absolute() else base / p

    return config.model_copy(
        update={
            "calibration": config.calibration.model_copy(update={"path": fix(config.calibration.path)}),
            "recording": config.recording.model_copy(update={"dir": fix(config.recording.dir)}),
            "broker": config.broker.model_copy(
                update={
                    "ca_file": fix(config.broker.ca_file),
                    "cert_file": fix(config.broker.cert_file),
                    "key_file": fix(config.broker.key_file),
                }
            ),
        }
    )


def _describe(exc: ValidationError, where_file: str, env_paths: Mapping[tuple[str, ...], str]) -> str:
    errors = exc.errors()
    first = errors[0]
    loc = tuple(str(p) for p in first["loc"])
    key = ".".join(loc) or "(top level)"
    origin = where_file
    for path, var in env_paths.items():
        n = min(len(path), len(loc))
        if loc[:n] == path[:n]:
            origin = f"environment variable {var}"
            break
    message = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        message = "unknown key"
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"{origin}: {key}: {message}{more}"


def load_config(path: Path | None, env: Mapping[str, str] | None = None) -> LoadedConfig:
    """Read and validate ``path`` (None = defaults only) with the environment overrides applied.

    Raises :class:`ConfigError` naming the file or variable and the key.
    """
    env = env or {}
    data: dict[str, Any] = {}
    where_file = str(path) if path is not None else "defaults"
    if path is not None:
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read configuration ({exc.strerror})") from exc
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{path}: configuration is not UTF-8 text") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: invalid TOML: {exc}") from exc
    overrides = env_overrides(env)
    env_paths = {p: var for p, (var, _) in overrides.items()}
    for key_path, (var, value) in overrides.items():
        _merge(data, key_path, value, f"environment variable {var}")
    try:
        config = EdgeConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_describe(exc, where_file, env_paths)) from exc
    if path is not None:
        config = _resolve_paths(config, path.resolve().parent)
    return LoadedConfig(config=config, path=path, env_keys=tuple(sorted(env_paths.values())))


def with_overrides(config: EdgeConfig, **dotted: Any) -> EdgeConfig:
    """A copy with command-line overrides (dotted keys: ``**{"camera.source": "sim"}``), validated again."""
    data = config.model_dump()
    for key, value in dotted.items():
        if value is not None:
            _merge(data, tuple(key.split(".")), value, "command line")
    try:
        return EdgeConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_describe(exc, "command line", {})) from exc


# -- showing -----------------------------------------------------------------------------------------------------
def masked(config: EdgeConfig) -> dict[str, Any]:
    """The configuration as plain data with every secret replaced by ``********``."""
    data = config.model_dump(mode="json")
    if config.broker.password is not None:
        data["broker"]["password"] = MASK
    target = urlsplit(config.broker.url)
    if target.password:
        data["broker"]["url"] = config.broker.url.replace(f":{target.password}@", f":{MASK}@", 1)
    if config.dashboard.token is not None:
        data["dashboard"]["token"] = MASK
    return data


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else "inf")
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def to_toml(data: Mapping[str, Any]) -> str:
    """TOML text of a configuration dict (tables, arrays of tables, scalars); ``None`` is written as a comment."""
    out: list[str] = []

    def table(prefix: str, body: Mapping[str, Any], header: str) -> None:
        scalars = {k: v for k, v in body.items() if not isinstance(v, dict) and not _is_table_list(v)}
        out.append(header)
        for key, value in scalars.items():
            out.append(f"# {key} = (unset)" if value is None else f"{key} = {_toml_value(value)}")
        out.append("")
        for key, value in body.items():
            if isinstance(value, dict):
                table(f"{prefix}{key}.", value, f"[{prefix}{key}]")
            elif _is_table_list(value):
                for item in value:
                    table(f"{prefix}{key}.", item, f"[[{prefix}{key}]]")

    top_scalars = {k: v for k, v in data.items() if not isinstance(v, dict) and not _is_table_list(v)}
    for key, value in top_scalars.items():
        out.append(f"# {key} = (unset)" if value is None else f"{key} = {_toml_value(value)}")
    for key, value in data.items():
        if isinstance(value, dict):
            table(f"{key}.", value, f"[{key}]")
        elif _is_table_list(value):
            for item in value:
                table(f"{key}.", item, f"[[{key}]]")
    return "\n".join(out).rstrip() + "\n"


def _is_table_list(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


# -- a starting file ---------------------------------------------------------------------------------------------
STARTER = """\
# edge-ips configuration. Every key is optional: the value shown is the default unless marked "example".
# Environment variables override single keys: EDGE_IPS_<SECTION>__<KEY>, e.g. EDGE_IPS_BROKER__URL=mqtt://pi:1883.
# `edge-ips config show` prints the effective configuration (secrets masked).

[edge]
id = "edge-1"                 # the status topic is ips/v1/edge/<id>/status
status_interval_s = 2.0       # retained status refreshed this often
log_level = "info"            # debug, info, warning, error

[camera]
source = "/dev/video0"        # example. A V4L2 index (0) or /dev/videoN, a video file, rtsp://..., http://...,
                              # or sim[:SCENARIO] for the simulator (the default when nothing is configured)
width = 1280                  # what to ask the camera for; the log says what it granted
height = 720
fps = 30.0
fourcc = "MJPG"
loop = false                  # video files: start again at the end
realtime = true               # video files and the simulator: deliver at the source's frame rate
stall_timeout_s = 2.0         # no frame for this long: camera "stalled", status "degraded", source reopened
reopen_min_s = 0.5            # backoff between reopen attempts, doubling up to reopen_max_s
reopen_max_s = 8.0

[calibration]
path = "calibration.json"     # example. From `edge-ips calibrate`; relative paths are relative to this file.
                              # Required for a real camera; the simulator brings its own exact calibration.

# One table per rover: its id (the topic ips/v1/rovers/<id>/pose) and marker colour as the camera sees it (B, G, R).
[[rovers]]
id = "red"
color_bgr = [40, 40, 200]

[[rovers]]
id = "green"
color_bgr = [60, 170, 40]

[[rovers]]
id = "blue"
color_bgr = [190, 90, 30]

[tracker]                     # tracking pipeline settings (see docs for the keys); empty = defaults

[broker]
url = "embedded"              # embedded (amqtt in this process), mqtt://[user:pass@]host:port or mqtts://host:port
# client_id = "edge-ips-edge-1"
# username = "edge"           # from `edge-ips broker-config` (credentials.toml)
# password = "..."            # better: EDGE_IPS_BROKER__PASSWORD in the service environment
# ca_file = "/etc/edge-ips/ca.crt"      # TLS (mqtts://): CA that signed the broker's certificate
# cert_file = "/etc/edge-ips/edge.crt"  # TLS client certificate (optional)
# key_file = "/etc/edge-ips/edge.key"
keepalive_s = 10
reconnect_min_s = 0.25        # reconnect backoff, doubling up to reconnect_max_s
reconnect_max_s = 2.0
embedded_host = "0.0.0.0"     # embedded broker: where rovers connect
embedded_port = 1883

[recording]
# dir = "/var/lib/edge-ips/recordings"  # JSON lines of everything published; unset = off
max_bytes = 50000000          # a new file beyond this size
max_files = 20                # oldest files deleted beyond this count

[http]
enabled = true                # /healthz, /metrics (Prometheus) and the dashboard
host = "0.0.0.0"
port = 8080

[dashboard]
enabled = true                # the live page at http://<board>:8080/ (off: --no-dashboard)
# token = "..."               # formation controls need it (at least 8 characters); unset = controls disabled.
                              # Better: EDGE_IPS_DASHBOARD__TOKEN in the service environment
frame_fps = 10.0              # camera view: at most this many JPEG frames per second, encoded once for all viewers
jpeg_quality = 70
max_width_px = 960            # camera view downscaled to this width (overlays are drawn by the browser)
pose_hz = 15.0                # pose events per second sent to each page
"""


def write_starter(path: Path, *, force: bool = False) -> Path:
    """Write the commented starting file; refuses to overwrite unless ``force``."""
    if path.exists() and not force:
        raise ConfigError(f"{path}: already exists (use --force to overwrite)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(STARTER, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write ({exc.strerror})") from exc
    return path
