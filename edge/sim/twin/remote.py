"""Edge-side faults from the command line: a request to the edge's dashboard (``POST /api/sim/fault``) with its
control token (``dashboard.token``, or the one ``start`` made in the state directory)."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from typing import TYPE_CHECKING, Any

from edge.errors import ConfigError, SimulationError

if TYPE_CHECKING:
    from edge.config import EdgeConfig


def control_token(config: EdgeConfig) -> str:
    """The dashboard's control token: configured, else the state directory's (made by ``start``)."""
    from edge.config import state_dir
    from edge.dashboard.first_token import token_path

    if config.dashboard.token is not None:
        return config.dashboard.token.get_secret_value()
    path = token_path(state_dir(config))
    try:
        return path.read_text(encoding="utf-8").strip()
    except OSError:
        raise ConfigError(f"{path}: no dashboard token (start the appliance first, or set dashboard.token)") from None


def post_fault(config: EdgeConfig, url: str | None, fault: dict[str, Any], timeout_s: float = 10.0) -> str:
    """Ask the edge at ``url`` (default: this machine's, on ``http.port``) for an edge-side fault; what it did."""
    base = url or f"http://127.0.0.1:{config.http.port}/"
    request = urllib.request.Request(
        base.rstrip("/") + "/api/sim/fault",
        data=json.dumps(fault).encode(),
        headers={"Content-Type": "application/json", "Authorization": f"Bearer {control_token(config)}"},
        method="POST",
    )
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as reply:
            return str(json.loads(reply.read())["done"])
    except urllib.error.HTTPError as exc:
        try:
            why = json.loads(exc.read()).get("error", exc.reason)
        except ValueError:
            why = exc.reason
        raise SimulationError(f"{base}: {exc.code} {why}") from None
    except (urllib.error.URLError, OSError) as exc:
        raise SimulationError(f"{base}: no edge answers ({getattr(exc, 'reason', exc)})") from None
