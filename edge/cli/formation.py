"""``edge-ips formation``: publish the retained formation command."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, cast

import click

from edge.cli.common import broker_option, config_option, id_list, load

if TYPE_CHECKING:
    from edge.messages import FormationKind


@click.command()
@click.argument("kind", type=click.Choice(["line", "rendezvous", "triangle", "stop"]))
@click.option("--spacing", type=float, default=None, help="Line: distance between neighbours, cm (default 60).")
@click.option("--side", type=float, default=None, help="Triangle: side length, cm (default 100).")
@click.option("--rovers", default=None, help="Comma-separated rover ids in formation order (default: configured).")
@click.option("--x", "x_cm", type=float, default=None, help="Anchor x, cm (line: the line's x).")
@click.option("--y", "y_cm", type=float, default=None, help="Anchor y, cm (the formation's centre).")
@click.option("--theta", "theta_rad", type=float, default=None, help="Orientation, rad (line: 0 = along +y).")
@config_option
@broker_option
def formation(
    kind: str,
    spacing: float | None,
    side: float | None,
    rovers: str | None,
    x_cm: float | None,
    y_cm: float | None,
    theta_rad: float | None,
    config_path: Path | None,
    broker_url: str | None,
) -> None:
    """Publish the retained formation command (seq follows the one the broker holds).

    Example:

        edge-ips formation line --spacing 60 --rovers red,green,blue
    """
    from edge.commands import publish_formation
    from edge.messages import dumps

    loaded = load(config_path, **{"broker.url": broker_url})
    sent = publish_formation(
        loaded.config,
        cast("FormationKind", kind),
        id_list(rovers),
        spacing_cm=spacing,
        side_cm=side,
        x_cm=x_cm,
        y_cm=y_cm,
        theta_rad=theta_rad,
    )
    click.echo(dumps(sent).decode())
