"""Reading the configuration: which file (``--config``, ``$EDGE_IPS_CONFIG``, ``./edge-ips.toml``,
``/etc/edge-ips/config.toml``), the environment's ``EDGE_IPS_<SECTION>__<KEY>`` overrides and the command line's,
validated once into :class:`edge.config.EdgeConfig` with errors that name the file (or the variable) and the key.

Nothing here reads the process environment by itself: the caller passes the mapping in (STYLE point 7).
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from edge.config import EdgeConfig, default_state_dir
from edge.errors import ConfigError, describe_validation

ENV_PREFIX = "EDGE_IPS_"
ENV_CONFIG_PATH = "EDGE_IPS_CONFIG"
DEFAULT_PATHS = (Path("edge-ips.toml"), Path("/etc/edge-ips/config.toml"))


@dataclass(frozen=True)
class LoadedConfig:
    """A validated configuration and where it came from (``path`` is None when only defaults applied)."""

    config: EdgeConfig
    path: Path | None
    env_keys: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        """Where the configuration came from, for messages: the file, or that there is none."""
        return str(self.path) if self.path is not None else "no configuration file (defaults)"


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
            "edge": config.edge.model_copy(update={"state_dir": fix(config.edge.state_dir)}),
            "calibration": config.calibration.model_copy(update={"path": fix(config.calibration.path)}),
            "recording": config.recording.model_copy(update={"dir": fix(config.recording.dir)}),
            "dashboard": config.dashboard.model_copy(update={"rovers_file": fix(config.dashboard.rovers_file)}),
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
    loc = tuple(str(p) for p in exc.errors()[0]["loc"])
    origin = where_file
    for path, var in env_paths.items():
        n = min(len(path), len(loc))
        if loc[:n] == path[:n]:
            origin = f"environment variable {var}"
            break
    return f"{origin}: {describe_validation(exc)}"


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
    if config.edge.state_dir is None:
        config = config.model_copy(
            update={"edge": config.edge.model_copy(update={"state_dir": default_state_dir(env)})}
        )
    return LoadedConfig(config=config, path=path, env_keys=tuple(sorted(env_paths.values())))


def effective_config(explicit: Path | None, env: Mapping[str, str], **dotted: Any) -> LoadedConfig:
    """The configuration a command runs with: the file found (:func:`find_config`), the environment's overrides,
    then the command line's (dotted keys, None: not given)."""
    loaded = load_config(find_config(explicit, env), env)
    return replace(loaded, config=with_overrides(loaded.config, **dotted))


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
