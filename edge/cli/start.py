"""``edge-ips start`` and ``edge-ips doctor``: run the appliance, and check that it can run."""

from __future__ import annotations

from pathlib import Path

import click

from edge.cli.common import broker_option, config_option, load, setup_logging


@click.command()
@config_option
@click.option(
    "--source",
    default=None,
    metavar="SPEC",
    help="Camera index or /dev/videoN, video file, rtsp:// or http:// URL, or sim[:SCENARIO]; overrides camera.source",
)
@broker_option
@click.option(
    "--http-port",
    type=click.IntRange(0, 65535),
    default=None,
    help="Port of the dashboard, /healthz and /metrics (0: any).",
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
@click.option("--no-dashboard", is_flag=True, help="Do not serve the live web page (dashboard.enabled = false).")
def start(
    config_path: Path | None,
    source: str | None,
    broker_url: str | None,
    http_port: int | None,
    record_dir: Path | None,
    loop: bool | None,
    edge_id: str | None,
    no_dashboard: bool,
) -> None:
    """Run the appliance: capture, track, publish every rover's pose over MQTT until SIGTERM or Ctrl-C.

    With no configuration file and no --source it runs the simulated camera and the embedded MQTT broker, so
    `mosquitto_sub -h localhost -t 'ips/v1/#' -v` in another terminal shows live poses, and http://localhost:8080/
    the live dashboard (off with --no-dashboard). A configured camera that is missing is an error (exit code 2)
    that suggests --source sim.

    Example:

        edge-ips start --source sim --broker mqtt://localhost:1883
    """
    from edge import appliance

    loaded = load(
        config_path,
        **{
            "camera.source": source,
            "broker.url": broker_url,
            "http.port": http_port,
            "recording.dir": str(record_dir) if record_dir is not None else None,
            "camera.loop": loop,
            "edge.id": edge_id,
            "dashboard.enabled": False if no_dashboard else None,
        },
    )
    setup_logging(loaded.config.edge.log_level)
    appliance.start(loaded, source_given=bool(source))


@click.command()
@config_option
@click.option("--source", default=None, metavar="SPEC", help="Check this source instead of camera.source.")
@broker_option
@click.pass_context
def doctor(ctx: click.Context, config_path: Path | None, source: str | None, broker_url: str | None) -> None:
    """Check camera, calibration, broker and clock; one line per check with a fix hint. Exit code 1 on failure.

    Example:

        edge-ips doctor --config /etc/edge-ips/config.toml
    """
    from edge.appliance import default_sim_factory
    from edge.doctor import run_checks

    loaded = load(config_path, **{"camera.source": source, "broker.url": broker_url})
    cfg = loaded.config
    failed = False
    for check in run_checks(cfg, where=loaded.where, env_keys=loaded.env_keys, sim_factory=default_sim_factory(cfg)):
        click.echo(check.line())
        failed = failed or check.level == "fail"
    if failed:
        ctx.exit(1)
