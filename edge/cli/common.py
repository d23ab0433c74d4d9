"""What the command modules share: the one-line user error, the group that turns library errors into it, the
options every appliance command takes, and reading the configuration with the command line's overrides."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import click

from edge.config_load import LoadedConfig
from edge.errors import EdgeIpsError


class UserError(click.ClickException):
    """A one-line error for the user, exit code 2."""

    exit_code = 2


class EdgeGroup(click.Group):
    """A click group that turns library errors into one-line messages."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except EdgeIpsError as exc:
            raise UserError(str(exc)) from exc


class EdgeCommand(click.Command):
    """A command that turns library errors into one-line messages when run on its own (tools/flash.py)."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except EdgeIpsError as exc:
            raise UserError(str(exc)) from exc


config_option = click.option(
    "--config",
    "config_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="TOML configuration. Default: $EDGE_IPS_CONFIG, ./edge-ips.toml, then /etc/edge-ips/config.toml.",
)
broker_option = click.option(
    "--broker",
    "broker_url",
    default=None,
    metavar="URL",
    help="mqtt://[user:pass@]host:port, mqtts://... (TLS) or embedded; overrides broker.url.",
)


def load(config_path: Path | None, **overrides: Any) -> LoadedConfig:
    """The validated configuration (file, environment, defaults) with the command line's dotted overrides (None:
    not given)."""
    import os

    from edge.config_load import effective_config

    return effective_config(config_path, os.environ, **overrides)


def setup_logging(level: str) -> None:
    import logging

    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%Y-%m-%dT%H:%M:%S",
    )


def quiet() -> io.StringIO:
    """Somewhere to send a progress bar that must not show (``--json``: stdout is for the machine)."""
    return io.StringIO()


def id_list(text: str | None) -> list[str] | None:
    """``--rovers a,b,c``: the ids without surrounding spaces, empty items left out (None: not given or empty, so
    the configured rovers)."""
    return [i.strip() for i in text.split(",") if i.strip()] if text else None
