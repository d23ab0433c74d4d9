"""The ``edge-ips`` command line: one click group, thin commands over the library.

Every user mistake the library detects arrives here as an :class:`edge.errors.EdgeIpsError` and leaves as a
one-line message with exit code 2; nothing else in the package talks to the terminal's exit code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

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


@click.group(cls=EdgeGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="edge-ips")
def main() -> None:
    """edge-ips: optical indoor positioning for small robot fleets.

    One static camera tracks coloured markers on rovers and publishes each rover's world pose over MQTT.
    """


# -- schema ------------------------------------------------------------------------------------------------------
@main.command()
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("shared/schema"),
    show_default=True,
    help="Directory to write the JSON Schema files into.",
)
def schema(out_dir: Path) -> None:
    """Write the JSON Schemas of the message contract (pose, formation, status v1).

    Example:

        edge-ips schema --out shared/schema
    """
    from edge.messages import write_schemas

    for path in write_schemas(out_dir):
        click.echo(f"wrote {path}")


if __name__ == "__main__":  # pragma: no cover
    main()
