"""``edge-ips broker-config``: the files of a Mosquitto deployment (users, ACLs, TLS)."""

from __future__ import annotations

from pathlib import Path

import click

from edge.cli.common import config_option, id_list, load


@click.command("broker-config")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Directory to write mosquitto.conf, passwd, acl and credentials.toml into.",
)
@click.option("--rovers", default=None, help="Comma-separated rover ids (default: configured rovers).")
@click.option("--edge-user", default="edge", show_default=True, help="MQTT user name of the edge.")
@click.option("--port", type=click.IntRange(1, 65535), default=1883, show_default=True, help="Network listener.")
@click.option(
    "--local-port",
    type=click.IntRange(1, 65535),
    default=1884,
    show_default=True,
    help="Listener on 127.0.0.1 for the edge's own clients on the broker's machine.",
)
@click.option("--tls", is_flag=True, help="Add a TLS listener (client certificate required) and its files.")
@click.option("--tls-port", type=click.IntRange(1, 65535), default=8883, show_default=True, help="TLS listener.")
@click.option(
    "--tls-name",
    "tls_names",
    multiple=True,
    help="Name or address the clients use to reach the broker (repeat; default: this host's name and localhost).",
)
@click.option(
    "--install-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Where the files will live on the broker machine (default: --out).",
)
@click.option("--force", is_flag=True, help="Overwrite existing files.")
@config_option
def broker_config(
    out_dir: Path,
    rovers: str | None,
    edge_user: str,
    port: int,
    local_port: int,
    tls: bool,
    tls_port: int,
    tls_names: tuple[str, ...],
    install_dir: Path | None,
    force: bool,
    config_path: Path | None,
) -> None:
    """Write a Mosquitto configuration with users, ACLs and (--tls) a TLS listener for this deployment.

    Anonymous access off; the edge may publish poses, its status and the formation; each rover may read poses
    and the formation and publish only its own status; the viewer only reads. On the network listener a client's
    id is its user name, so no login can take another client's session. Random passwords go to
    credentials.toml; passwords and private keys are written with mode 600.

    Example:

        edge-ips broker-config --out /etc/mosquitto/edge-ips --rovers red,green,blue --tls --tls-name pi.lab
    """
    import socket

    from edge.broker import write_mosquitto_config

    config = load(config_path).config
    ids = id_list(rovers)
    files = write_mosquitto_config(
        out_dir,
        rovers=ids if ids is not None else [r.id for r in config.rovers],
        edge_id=config.edge.id,
        edge_user=edge_user,
        port=port,
        local_port=local_port,
        tls_port=tls_port if tls else None,
        tls_names=list(tls_names) or [socket.gethostname(), "localhost", "127.0.0.1"],
        install_dir=install_dir,
        force=force,
    )
    for path in files.all():
        click.echo(f"wrote {path}")
    click.echo(f"passwords hashed as PBKDF2-SHA512 ($7$); clear-text logins in {files.credentials}")
    click.echo(f"the edge on the broker's machine: broker.url = mqtt://{edge_user}@localhost:{local_port}")
