"""The dashboard's token when none is configured: made on the first start, kept in the state directory, reused.

As notebook servers do: a newcomer's first ``edge-ips start`` can press the formation buttons without editing
anything, and the controls are still not open to the network. The token is 32 random characters (URL-safe
base64 of 24 bytes), in ``dashboard-token`` with mode 0600 from the first byte
(:func:`edge.private_files.write_private`); ``start`` prints the page's address with it on its first lines. A
token set in the configuration (``dashboard.token``) is used instead, and this file is not made.
"""

from __future__ import annotations

import secrets
from pathlib import Path

from edge.config import EdgeConfig, state_dir
from edge.config_load import with_overrides
from edge.errors import ConfigError
from edge.private_files import private_dir, write_private

TOKEN_FILE = "dashboard-token"
MIN_LENGTH = 8  # what dashboard.token accepts


def token_path(state_dir: Path) -> Path:
    return state_dir / TOKEN_FILE


def dashboard_token(state_dir: Path) -> tuple[str, bool]:
    """(the state directory's dashboard token, True when it was made now)."""
    path = token_path(state_dir)
    try:
        token = path.read_text(encoding="utf-8").strip()
    except FileNotFoundError:
        token = secrets.token_urlsafe(24)
        private_dir(state_dir)
        write_private(path, token + "\n")
        return token, True
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the dashboard token ({exc})") from None
    if len(token) < MIN_LENGTH or any(c.isspace() for c in token):
        raise ConfigError(f"{path}: not a dashboard token (at least {MIN_LENGTH} characters, no spaces); delete it")
    return token, False


def with_dashboard_token(config: EdgeConfig) -> tuple[EdgeConfig, str]:
    """The configuration with its dashboard token (the configured one, else the state directory's, made now on the
    first start) and the line that gives the page's address with it; ("", unchanged) when there is no page."""
    if not (config.http.enabled and config.dashboard.enabled):
        return config, ""
    host = config.http.host if config.http.host not in ("0.0.0.0", "::", "") else "localhost"
    port = "PORT" if config.http.port == 0 else str(config.http.port)
    if config.dashboard.token is not None:
        return config, f"dashboard: http://{host}:{port}/ (with the configured dashboard.token)"
    directory = state_dir(config)
    token, made = dashboard_token(directory)
    kept = "made now, kept" if made else "kept"
    address = f"dashboard: http://{host}:{port}/?token={token} (the token is {kept} in {token_path(directory)})"
    return with_overrides(config, **{"dashboard.token": token}), address
