"""``edge-ips flash`` (and ``tools/flash.py``): flash and provision one rover."""

from __future__ import annotations

from pathlib import Path

import click

from edge.cli.common import EdgeCommand


@click.command(cls=EdgeCommand)
@click.option("--port", help="Serial port of the rover's ESP8266, e.g. /dev/ttyUSB0 (not needed with --bundle).")
@click.option(
    "--rover",
    required=True,
    help="Rover id of an example config in firmware/esp8266/configs (red, green, blue) or a config.json path.",
)
@click.option(
    "--firmware",
    type=click.Path(dir_okay=False, path_type=Path),
    help="MicroPython to write first: v1.28.0 ESP8266_GENERIC FLASH_2M_ROMFS (checked; anything else is refused). "
    "Without it the board must already run it.",
)
@click.option("--erase", is_flag=True, help="Erase the whole flash first (needs --firmware).")
@click.option("--baud", default=460800, show_default=True, help="Baud rate for writing the firmware.")
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
    dry_run: bool,
    bundle_dir: Path | None,
) -> None:
    """Flash and provision one rover: MicroPython, the firmware (ROMFS image), boot.py, main.py and its config.json.

    A running rover is stopped first. Wi-Fi and broker secrets come from EDGE_IPS_WIFI_SSID, EDGE_IPS_WIFI_PASSWORD
    and EDGE_IPS_MQTT_PASSWORD, or are asked for; EDGE_IPS_BROKER_HOST (host or host:port) overrides the config's
    broker. Nothing secret is written anywhere but the board (and --bundle).

    Example:

    \b
        python tools/flash.py --port /dev/ttyUSB0 --rover red --erase \\
            --firmware ESP8266_GENERIC-FLASH_2M_ROMFS-20260406-v1.28.0.bin
    """
    import os
    import shlex
    import sys
    import tempfile

    from edge import flashing

    checked = flashing.checked_config_file(rover)  # a bad config is said first, before the board or any password
    for text in flashing.config_warnings(checked):
        click.echo(f"warning: {text}", err=True)
    flashing.check_inputs(port, firmware, erase, need_port=bundle_dir is None, need_board=not dry_run)
    if dry_run:
        assert port is not None  # check_inputs insists on it
        bundle = Path("BUNDLE")
        click.echo(f"# BUNDLE: a temporary directory with {', '.join(flashing.BUNDLE)}")
        click.echo(f"# rom.img: {', '.join(flashing.COMPILED)} compiled with mpy-cross -march=xtensa, as ROMFS")
        if firmware is not None:
            click.echo(f"# {firmware} checked first: {flashing.IMAGE.variant} v{flashing.IMAGE.version}")
        for cmd in flashing.commands(port, bundle, firmware, erase, baud):
            click.echo(shlex.join(cmd))
        return

    def ask(secret: flashing.Secret) -> str:
        return str(click.prompt(secret.prompt, hide_input=secret.hidden, default="", show_default=False))

    prompt = ask if sys.stdin.isatty() else None
    config = flashing.provisioned_config(rover, os.environ, prompt, flashing.state_logins(os.environ))
    if (named := flashing.host_warning(config)) is not None:
        click.echo(f"warning: {named}", err=True)
    if bundle_dir is not None:
        for path in flashing.write_bundle(bundle_dir, config):
            click.echo(f"wrote {path}")
        return
    assert port is not None  # check_inputs insists on it
    with tempfile.TemporaryDirectory(prefix=f"edge-ips-{config['id']}-") as tmp:
        bundle = Path(tmp) / "bundle"
        flashing.write_bundle(bundle, config)
        flashing.flash(port, bundle, firmware, erase, baud, echo=click.echo)
