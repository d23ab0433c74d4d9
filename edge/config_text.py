"""The configuration as TOML text: the effective configuration shown with its secrets masked
(``edge-ips config show``), and the commented starting file (``edge-ips config init``)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from edge.config import EdgeConfig
from edge.errors import ConfigError

MASK = "********"


def masked(config: EdgeConfig) -> dict[str, Any]:
    """The configuration as plain data with every secret replaced by ``********``."""
    data = config.model_dump(mode="json")
    if config.broker.password is not None:
        data["broker"]["password"] = MASK
    target = urlsplit(config.broker.url)
    if target.password:
        data["broker"]["url"] = config.broker.url.replace(f":{target.password}@", f":{MASK}@", 1)
    for key in ("token", "viewer_token"):
        if getattr(config.dashboard, key) is not None:
            data["dashboard"][key] = MASK
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
# state_dir = "/var/lib/edge-ips"  # the embedded broker's logins (generated on the first start, mode 600).
                              # Default: $STATE_DIRECTORY (the service), else ~/.local/state/edge-ips; set it
                              # so `edge-ips formation` and `edge-ips flash` find the service's logins

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

[camera.controls]             # a V4L2 camera's controls, set at every (re)open and logged as granted; unset = the
                              # camera's own. Fix focus and white balance under a calibration (docs/deploy.md: C920)
# autofocus = false           # example. Autofocus moves the focal length the calibration measured
# focus = 0                   # example. Camera units (C920: 0-250 in steps of 5); needs autofocus = false
# auto_white_balance = false  # example. Auto white balance moves the marker hues
# white_balance_k = 4000      # example. Needs auto_white_balance = false
# auto_exposure = false       # example. false: manual exposure; true: the camera's (aperture priority)
# exposure = 156              # example. Units of 100 us (156 = 15.6 ms); needs auto_exposure = false
# exposure_dynamic_framerate = false  # example. false: the camera keeps its frame rate in low light
# gain = 64                   # example
# power_line_hz = 50          # example. Mains frequency: 50 or 60 (flicker under lamps), 0 = off
# sharpness = 0               # example. The camera's own sharpening; its least is none (C920: 0 of 0-255)

[calibration]
path = "calibration.json"     # example. From `edge-ips calibrate`; relative paths are relative to this file.
                              # Required for a real camera; the simulator brings its own exact calibration.

# One table per rover: its id (the topic ips/v1/rovers/<id>/pose) and marker colour as the camera sees it (B, G, R).
# Measure them with `edge-ips rovers enroll` (a frame of the rovers and one of the empty floor): the values below
# are examples, not any real marker's.
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
# outline_fit = false         # true: one-colour markers' centre from their fitted edges (less camera-
                              # dependent bias) at about 3.5x the tracking time per frame: only on a board with time
# edge_offsets = "auto"       # centres corrected by full edge fits in the camera's encoded chroma, run in a worker
                              # process (one rover's window every edge_offsets_every = 10 frames): takes most of a
                              # webcam's colour-dependent bias out; uses up to one more core. auto: on for a camera,
                              # a video or a stream, off for the simulator's uncompressed frames; true / false
# line_time_us = 0.0          # the camera's rolling shutter, us between two rows' exposures (0: global shutter;
                              # a webcam at 1280x720 and 30 fps: about 44; `edge-ips calibrate line-time` measures it)

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
embedded_host = "0.0.0.0"     # embedded broker: where rovers connect. Logins required (generated in
embedded_port = 1883          # state_dir); anonymous clients only from this machine, read-only

[recording]
# dir = "/var/lib/edge-ips/recordings"  # JSON lines of everything published; unset = off
max_bytes = 50000000          # a new file beyond this size
max_files = 20                # oldest files deleted beyond this count

[http]
enabled = true                # /healthz, /metrics (Prometheus) and the dashboard
host = "0.0.0.0"
port = 8080
allowed_hosts = []            # more names the board is reached by; its hostname, <hostname>.local, localhost and
                              # its addresses are always allowed. ["*"]: no Host check (behind a reverse proxy)
max_connections = 64          # beyond it the oldest idle connection is closed
request_timeout_s = 10.0      # a client must send its request (and read the reply) within this
max_streams = 16              # open dashboard pages (event streams) at most

[dashboard]
enabled = true                # the live page at http://<board>:8080/ (off: --no-dashboard)
# token = "..."               # needed to view (camera, events, state) and to command formations (at least 8
                              # characters); unset = the page is open to view, formation controls disabled.
                              # Better: EDGE_IPS_DASHBOARD__TOKEN in the service environment
# viewer_token = "..."        # a second token that can view but not command
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
