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


class EdgeCommand(click.Command):
    """A command that turns library errors into one-line messages when run on its own (tools/flash.py)."""

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


# -- flash ---------------------------------------------------------------------------------------------------------
@main.command(cls=EdgeCommand)
@click.option("--port", help="Serial port of the rover's ESP8266, e.g. /dev/ttyUSB0 (not needed with --bundle).")
@click.option(
    "--rover",
    required=True,
    help="Rover id of an example config in firmware/esp8266/configs (red, green, blue) or a config.json path.",
)
@click.option(
    "--firmware",
    type=click.Path(dir_okay=False, path_type=Path),
    help="MicroPython ESP8266_GENERIC .bin to write first (v1.23 or later); without it the board keeps its own.",
)
@click.option("--erase", is_flag=True, help="Erase the whole flash first (needs --firmware).")
@click.option("--baud", default=460800, show_default=True, help="Baud rate for writing the firmware.")
@click.option(
    "--romfs",
    is_flag=True,
    help="Put the .mpy files into the ROMFS partition (ESP8266_GENERIC FLASH_2M_ROMFS firmware, MicroPython 1.25+): "
    "they then run from flash and leave ~20 KB more heap.",
)
@click.option("--dry-run", is_flag=True, help="Print the commands instead of running them.")
@click.option(
    "--bundle",
    "bundle_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Write exactly what would be copied onto the board into this (new or empty) directory, and stop.",
)
def flash(
    port: str | None,
    rover: str,
    firmware: Path | None,
    erase: bool,
    baud: int,
    romfs: bool,
    dry_run: bool,
    bundle_dir: Path | None,
) -> None:
    """Flash and provision one rover: MicroPython, the firmware (.mpy), main.py and its config.json.

    Wi-Fi and broker secrets come from EDGE_IPS_WIFI_SSID, EDGE_IPS_WIFI_PASSWORD and EDGE_IPS_MQTT_PASSWORD, or
    are asked for; EDGE_IPS_BROKER_HOST (host or host:port) overrides the config's broker. Nothing secret is
    written anywhere but the board (and --bundle).

    Example:

        python tools/flash.py --port /dev/ttyUSB0 --rover red --firmware ESP8266_GENERIC-v1.24.1.bin --erase
    """
    import os
    import sys
    import tempfile

    from edge import flashing

    flashing.check_inputs(port, firmware, erase, need_port=bundle_dir is None and not dry_run)
    if dry_run:
        bundle = Path("BUNDLE")
        click.echo(f"# BUNDLE: a temporary directory with {', '.join(flashing.bundle_files(romfs))}")
        for cmd in flashing.commands(port or "PORT", bundle, firmware, erase, baud, romfs):
            click.echo(" ".join(_quote(a) for a in cmd))
        return

    def ask(secret: flashing.Secret) -> str:
        return str(click.prompt(secret.prompt, hide_input=secret.hidden, default="", show_default=False))

    prompt = ask if sys.stdin.isatty() else None
    config = flashing.provisioned_config(rover, os.environ, prompt)
    if bundle_dir is not None:
        for path in flashing.write_bundle(bundle_dir, config, romfs):
            click.echo(f"wrote {path}")
        return
    assert port is not None  # check_inputs insists on it
    with tempfile.TemporaryDirectory(prefix=f"edge-ips-{config['id']}-") as tmp:
        bundle = Path(tmp) / "bundle"
        flashing.write_bundle(bundle, config, romfs)
        flashing.flash(port, bundle, firmware, erase, baud, romfs, echo=click.echo)


def _quote(arg: str) -> str:
    import shlex

    return shlex.quote(arg)


if __name__ == "__main__":  # pragma: no cover
    main()
