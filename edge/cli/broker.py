"""``edge-ips broker-config``: the files of a Mosquitto deployment (users, ACLs, TLS)."""

from __future__ import annotations

from pathlib import Path

import click

from edge.cli.common import UserError, config_option, id_list, load


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
@click.option(
    "--tls-port",
    type=click.IntRange(1, 65535),
    default=8883,
    show_default=True,
    help="TLS listener (the edge's; the viewer's is the next port).",
)
@click.option(
    "--tls-name",
    "tls_names",
    multiple=True,
    help="Name or address the clients use to reach the broker (repeat; default: this host's name and localhost). "
    "With --bridge: the central broker's; each board's certificate names the HOST of its --board.",
)
@click.option(
    "--install-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Where the files will live on the broker machine (default: --out).",
)
@click.option("--force", is_flag=True, help="Overwrite existing files.")
@click.option(
    "--bridge",
    is_flag=True,
    help="Several boards: a central broker (OUT/central) and one bridged broker per board (OUT/<board>).",
)
@click.option(
    "--board",
    "board_specs",
    multiple=True,
    metavar="ID=HOST[:PORT]",
    help="--bridge: a board's id (its edge.id) and how the central broker reaches the board's broker (repeat; "
    "PORT defaults to --port, or --tls-port with --tls).",
)
@click.option(
    "--fusers", default="fuser-a,fuser-b", show_default=True, help="--bridge: the fusers' logins at the central."
)
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
    bridge: bool,
    board_specs: tuple[str, ...],
    fusers: str,
    config_path: Path | None,
) -> None:
    """Write a Mosquitto configuration with users, ACLs and (--tls) a TLS listener for this deployment.

    Anonymous access off; the edge may publish poses, its status and the formation; each rover may read poses
    and the formation and publish only its own status; the viewer only reads. On the network listener a client's
    id is its user name, so no login can take another client's session. Random passwords go to
    credentials.toml; passwords and private keys are written with mode 600.

    With --bridge (several boards), OUT/central is the central broker (the fusers and the rovers connect there)
    and OUT/<board> each board's own Mosquitto. The central broker opens a bridge to each board (so the boards'
    detections leave on sockets the boards accepted, sent at once): detections and statuses from the boards,
    poses, the fusers' statuses and the formation to them; over TLS with --tls (each board gets a TLS listener).

    Example:

    \b
        edge-ips broker-config --out /etc/mosquitto/edge-ips --rovers red,green,blue --tls --tls-name pi.lab
        edge-ips broker-config --bridge --board cam1=cam1.lab --board cam2=cam2.lab --tls --out brokers
    """
    import socket

    from edge.broker import write_mosquitto_config

    config = load(config_path).config
    ids = id_list(rovers)
    if board_specs and not bridge:
        raise UserError("--board goes with --bridge (several boards)")
    if bridge:
        from edge.broker.bridge import parse_board, write_bridge_configs

        boards = dict(parse_board(spec) for spec in board_specs)
        if len(boards) != len(board_specs):
            raise UserError("--board: each board id once")
        written = write_bridge_configs(
            out_dir,
            boards=boards,
            rovers=ids if ids is not None else [r.id for r in config.rovers],
            fusers=id_list(fusers) or [],
            port=port,
            local_port=local_port,
            tls_port=tls_port if tls else None,
            tls_names=list(tls_names) or [socket.gethostname(), "localhost", "127.0.0.1"],
            install_dir=install_dir,
            force=force,
        )
        for path in written.all():
            click.echo(f"wrote {path}")
        click.echo(f"central broker: {written.central}, with a bridge to each board's broker: {', '.join(boards)}")
        return
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
