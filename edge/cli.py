"""The ``edge-ips`` command line: one click group, thin commands over the library.

Every user mistake the library detects arrives here as an :class:`edge.errors.EdgeIpsError` and leaves as a
one-line message with exit code 2; nothing else in the package talks to the terminal's exit code.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import click

from edge.errors import EdgeIpsError

if TYPE_CHECKING:
    from edge.config import EdgeConfig
    from edge.messages import FormationKind


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


# -- configuration helpers shared by the appliance commands ------------------------------------------------------
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


def _load(config_path: Path | None, **overrides: Any) -> tuple[EdgeConfig, str, tuple[str, ...]]:
    """The validated configuration with command-line overrides, and a description of where it came from."""
    import os

    from edge.config import find_config, load_config, with_overrides

    path = find_config(config_path, os.environ)
    loaded = load_config(path, os.environ)
    config = with_overrides(loaded.config, **overrides)
    where = str(path) if path is not None else "no configuration file (defaults)"
    return config, where, loaded.env_keys


def _setup_logging(level: str) -> None:
    import logging

    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%Y-%m-%dT%H:%M:%S",
    )


# -- start -------------------------------------------------------------------------------------------------------
@main.command()
@config_option
@click.option(
    "--source",
    default=None,
    metavar="SPEC",
    help="Camera index or /dev/videoN, video file, rtsp:// or http:// URL, or sim[:SCENARIO]; overrides camera.source",
)
@broker_option
@click.option(
    "--http-port", type=click.IntRange(0, 65535), default=None, help="Port of /healthz and /metrics (0: any)."
)
@click.option(
    "--record",
    "record_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Record everything published as JSON lines in DIR (rotated by size).",
)
@click.option("--loop/--no-loop", default=None, help="Video files: start again at the end.")
@click.option("--edge-id", default=None, help="Edge id (status topic ips/v1/edge/<id>/status).")
def start(
    config_path: Path | None,
    source: str | None,
    broker_url: str | None,
    http_port: int | None,
    record_dir: Path | None,
    loop: bool | None,
    edge_id: str | None,
) -> None:
    """Run the appliance: capture, track, publish every rover's pose over MQTT until SIGTERM or Ctrl-C.

    With no configuration file and no --source it runs the simulated camera and the embedded MQTT broker, so
    `mosquitto_sub -h localhost -t 'ips/v1/#' -v` in another terminal shows live poses. A configured camera that
    is missing is an error (exit code 2) that suggests --source sim.

    Example:

        edge-ips start --source sim --broker mqtt://localhost:1883
    """
    import logging

    from edge.config import broker_target
    from edge.runtime import prepare_appliance, run_until_signalled

    config, where, env_keys = _load(
        config_path,
        **{
            "camera.source": source,
            "broker.url": broker_url,
            "http.port": http_port,
            "recording.dir": str(record_dir) if record_dir is not None else None,
            "camera.loop": loop,
            "edge.id": edge_id,
        },
    )
    _setup_logging(config.edge.log_level)
    log = logging.getLogger("edge.cli")

    if source:
        why = "from --source"
    elif config_path is None and where.startswith("no configuration"):
        why = "no configuration found, so the simulated camera"
    else:
        why = f"camera.source in {where}"
    log.info(
        "edge-ips start: edge %s, source %s (%s), broker %s, configuration: %s",
        config.edge.id,
        config.camera.source,
        why,
        broker_target(config.broker).display(),
        where,
    )
    if env_keys:
        log.info("environment overrides: %s", ", ".join(env_keys))
    run_until_signalled(prepare_appliance(config, config_where=where))


# -- formation ---------------------------------------------------------------------------------------------------
@main.command()
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
    from edge.config import broker_target
    from edge.messages import dumps
    from edge.publisher import TlsFiles, build_formation, send_formation

    config, _, _ = _load(config_path, **{"broker.url": broker_url})
    shape = cast("FormationKind", kind)
    ids = [r.strip() for r in rovers.split(",") if r.strip()] if rovers else [r.id for r in config.rovers]
    if kind == "line" and spacing is None:
        spacing = 60.0
    if kind == "triangle" and side is None:
        side = 100.0
    build_formation(shape, ids, seq=1, spacing_cm=spacing, side_cm=side, x_cm=x_cm, y_cm=y_cm, theta_rad=theta_rad)
    sent = send_formation(
        broker_target(config.broker),
        lambda seq: build_formation(
            shape, ids, seq=seq, spacing_cm=spacing, side_cm=side, x_cm=x_cm, y_cm=y_cm, theta_rad=theta_rad
        ),
        client_id=f"edge-ips-formation-{config.edge.id}",
        tls=TlsFiles(config.broker.ca_file, config.broker.cert_file, config.broker.key_file),
    )
    click.echo(dumps(sent).decode())


# -- broker-config -----------------------------------------------------------------------------------------------
@main.command("broker-config")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Directory to write mosquitto.conf, passwd, acl and credentials.toml into.",
)
@click.option("--rovers", default=None, help="Comma-separated rover ids (default: configured rovers).")
@click.option("--edge-user", default="edge", show_default=True, help="MQTT user name of the edge.")
@click.option("--port", type=click.IntRange(1, 65535), default=1883, show_default=True, help="Listener port.")
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
    install_dir: Path | None,
    force: bool,
    config_path: Path | None,
) -> None:
    """Write a Mosquitto configuration with users and ACLs for this deployment.

    Anonymous access off; the edge may publish poses, its status and the formation; each rover may read poses
    and the formation and publish only its own status. Random passwords go to credentials.toml (mode 600).

    Example:

        edge-ips broker-config --out /etc/mosquitto/edge-ips --rovers red,green,blue
    """
    from edge.broker import write_mosquitto_config

    config, _, _ = _load(config_path)
    ids = [r.strip() for r in rovers.split(",") if r.strip()] if rovers else [r.id for r in config.rovers]
    files = write_mosquitto_config(
        out_dir,
        rovers=ids,
        edge_id=config.edge.id,
        edge_user=edge_user,
        port=port,
        install_dir=install_dir,
        force=force,
    )
    for path in (files.conf, files.passwd, files.acl, files.credentials):
        click.echo(f"wrote {path}")
    click.echo(f"passwords hashed with {files.hash_method}; clear-text credentials in {files.credentials}")


# -- config ------------------------------------------------------------------------------------------------------
@main.group(cls=EdgeGroup)
def config() -> None:
    """Show or start the TOML configuration.

    Example:

        edge-ips config show
    """


@config.command("show")
@config_option
@click.option("--json", "as_json", is_flag=True, help="JSON instead of TOML.")
def config_show(config_path: Path | None, as_json: bool) -> None:
    """Print the effective configuration (file, environment overrides, defaults) with secrets masked.

    Example:

        EDGE_IPS_BROKER__URL=mqtt://pi:1883 edge-ips config show
    """
    import json

    from edge.config import masked, to_toml

    cfg, where, env_keys = _load(config_path)
    data = masked(cfg)
    if as_json:
        click.echo(json.dumps(data, indent=2))
        return
    overrides = f" + environment ({', '.join(env_keys)})" if env_keys else ""
    click.echo(f"# effective configuration: {where}{overrides}")
    click.echo(to_toml(data), nl=False)


@config.command("init")
@click.argument("path", type=click.Path(dir_okay=False, path_type=Path), default=Path("edge-ips.toml"))
@click.option("--force", is_flag=True, help="Overwrite an existing file.")
def config_init(path: Path, force: bool) -> None:
    """Write a commented starting configuration file.

    Example:

        edge-ips config init /etc/edge-ips/config.toml
    """
    from edge.config import write_starter

    click.echo(f"wrote {write_starter(path, force=force)}")


# -- doctor ------------------------------------------------------------------------------------------------------
@main.command()
@config_option
@click.option("--source", default=None, metavar="SPEC", help="Check this source instead of camera.source.")
@broker_option
@click.pass_context
def doctor(ctx: click.Context, config_path: Path | None, source: str | None, broker_url: str | None) -> None:
    """Check camera, calibration, broker and clock; one line per check with a fix hint. Exit code 1 on failure.

    Example:

        edge-ips doctor --config /etc/edge-ips/config.toml
    """
    from edge.doctor import run_checks
    from edge.runtime import default_sim_factory

    cfg, where, env_keys = _load(config_path, **{"camera.source": source, "broker.url": broker_url})
    failed = False
    for check in run_checks(cfg, where=where, env_keys=env_keys, sim_factory=default_sim_factory(cfg)):
        click.echo(check.line())
        failed = failed or check.level == "fail"
    if failed:
        ctx.exit(1)


if __name__ == "__main__":  # pragma: no cover
    main()
