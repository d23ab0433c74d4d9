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
@click.option(
    "--after-kill", type=float, default=None, hidden=True, help="Wait this long first (restart after a kill)."
)
def start(
    config_path: Path | None,
    source: str | None,
    broker_url: str | None,
    http_port: int | None,
    record_dir: Path | None,
    loop: bool | None,
    edge_id: str | None,
    no_dashboard: bool,
    after_kill: float | None,
) -> None:
    """Run the appliance: capture, track, publish every rover's pose over MQTT until SIGTERM or Ctrl-C.

    With no configuration file and no --source it runs the live twin (sim:twin: a simulated lab whose rovers run
    their real firmware and obey the dashboard) and the embedded MQTT broker, so `mosquitto_sub -h localhost -t
    'ips/v1/#' -v` in another terminal shows live poses, and the dashboard's address, printed first with its token,
    the live page (off with --no-dashboard). A configured camera that is missing is an error (exit code 2) that
    suggests --source sim.

    Example:

        edge-ips start --source sim:twin --broker mqtt://localhost:1883
    """
    from edge import appliance
    from edge.cli.twin import first_start, restart_argv

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
    appliance.check_calibration(loaded.config, loaded.where)  # a bad file stops start before it makes any state
    loaded = first_start(loaded, after_kill, source_given=bool(source))
    appliance.start(loaded, source_given=bool(source), restart_argv=restart_argv())


@click.command()
@config_option
@click.option("--source", default=None, metavar="SPEC", help="Check this source instead of camera.source.")
@broker_option
@click.option(
    "--fusion",
    is_flag=True,
    help="Several boards: check the fusers, every board (status, bridge, clock offset) and the rovers nobody sees.",
)
@click.pass_context
def doctor(
    ctx: click.Context, config_path: Path | None, source: str | None, broker_url: str | None, fusion: bool
) -> None:
    """Check camera, calibration, broker and clock; one line per check with a fix hint. Exit code 1 on failure.

    With --fusion (on the central broker of several boards), check instead that one fuser publishes and one
    stands by, every board's detections arrive (its bridge, its clock offset as the fuser estimates it) and which
    rovers nobody sees.

    Example:

    \b
        edge-ips doctor --config /etc/edge-ips/config.toml
        edge-ips doctor --fusion --broker mqtt://edge:PASSWORD@localhost:1884
    """
    from collections.abc import Iterable

    from edge.appliance import default_sim_factory
    from edge.doctor import Check, run_checks

    loaded = load(config_path, **{"camera.source": source, "broker.url": broker_url})
    cfg = loaded.config
    checks: Iterable[Check]
    if fusion:
        from edge.fusion.doctor import central_checks

        checks = central_checks(cfg)
    else:
        checks = run_checks(cfg, where=loaded.where, env_keys=loaded.env_keys, sim_factory=default_sim_factory(cfg))
    failed = False
    for check in checks:
        click.echo(check.line())
        failed = failed or check.level == "fail"
    if failed:
        ctx.exit(1)
