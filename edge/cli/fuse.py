"""``edge-ips fuse``: several boards' detections into the canonical poses, offline (files) or live (a broker)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from edge.cli.common import UserError, broker_option, config_option, load, setup_logging

if TYPE_CHECKING:
    from edge.fusion.core import FusionSettings


@click.command()
@click.argument("detections", nargs=-1, type=click.Path(path_type=Path))
@click.option("--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), default=None, help="Poses file.")
@click.option("--fps", type=click.FloatRange(min=1.0, max=240.0), default=30.0, show_default=True, help="Shared clock.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON object.")
@broker_option
@config_option
@click.option("--id", "fuser_id", default="fuser-1", show_default=True, help="Live: this fuser's id (one per fuser).")
@click.option(
    "--max-age",
    "max_age_s",
    type=click.FloatRange(min=0.01, max=10.0),
    default=0.25,
    show_default=True,
    help="Live: detections older than this (s, capture to arrival on the fuser's clock) are stale and dropped.",
)
@click.option(
    "--http-port",
    type=click.IntRange(0, 65535),
    default=None,
    help="Live: serve the fused map (every board's view, the rovers, which boards saw each) on this port (0: any).",
)
@click.option(
    "--board-dashboard",
    "board_dashboards",
    multiple=True,
    metavar="EDGE=URL",
    help="Live, with --http-port: the fused map shows this board's camera image from its dashboard (repeat per "
    "board; the map's viewer token is passed on, so give the boards the same one).",
)
def fuse(
    detections: tuple[Path, ...],
    out_path: Path | None,
    fps: float,
    as_json: bool,
    broker_url: str | None,
    config_path: Path | None,
    fuser_id: str,
    max_age_s: float,
    http_port: int | None,
    board_dashboards: tuple[str, ...],
) -> None:
    """Fuse several boards' detections into one pose v1 line per rover per frame of the shared clock.

    Offline, each DETECTIONS file is one board's `edge-ips track --detections` output (or a recording of its
    topic); the first file's clock is the reference and the other boards' clock offsets are estimated from rovers
    seen by two boards. Live (--broker), it subscribes to every board's detections on the central broker and
    publishes the canonical poses and its own status while it holds the lease: run two (with different --id) and
    the other takes over when one dies. Credentials and TLS files come from the configuration's [broker] section.

    Example:

    \b
        edge-ips fuse cam1.jsonl cam2.jsonl cam3.jsonl cam4.jsonl --out poses.jsonl
        edge-ips fuse --broker mqtt://fuser:PASSWORD@central.lab:1883 --id fuser-a --http-port 8090 \\
            --board-dashboard cam1=http://cam1.lab:8080 --board-dashboard cam2=http://cam2.lab:8080
    """
    import json
    import re

    from edge.fusion.core import FusionSettings
    from edge.messages import ID_PATTERN

    settings = FusionSettings(fps=fps, max_age_s=max_age_s)
    if broker_url is not None:
        if detections or out_path is not None:
            raise UserError("--broker fuses live: give no detections files and no --out")
        if not re.match(ID_PATTERN, fuser_id):
            raise UserError(f"--id {fuser_id!r}: use 1-16 characters of a-z, 0-9, _ and -")
        if board_dashboards and http_port is None:
            raise UserError("--board-dashboard puts a board's camera on the fused map: give --http-port too")
        _fuse_live(config_path, broker_url, fuser_id, settings, http_port, _dashboards(board_dashboards))
        return
    from edge.fusion.offline import fuse_files

    if http_port is not None or board_dashboards:
        raise UserError("--http-port and --board-dashboard serve the live fused map: use them with --broker")
    if not detections:
        raise UserError("give the detections files to fuse (one per board), or --broker URL to fuse live")
    if out_path is None:
        raise UserError("--out is required: the file to write the poses to")
    summary = fuse_files(list(detections), out_path, settings)
    if as_json:
        click.echo(json.dumps(summary.as_dict()))
        return
    click.echo(f"{summary.frames} detections messages from {len(detections)} boards, {summary.poses} poses")
    for edge_id, est in summary.offsets.items():
        click.echo(f"  {edge_id}: clock offset {1e3 * est.offset_s:+.2f} ms (+-{1e3 * est.sigma_s:.2f}, {est.source})")
    for rover_id, count in sorted(summary.per_rover.items()):
        click.echo(f"  {rover_id}: {count} poses")
    click.echo(f"wrote {out_path}")


def _dashboards(given: tuple[str, ...]) -> dict[str, str]:
    """``EDGE=URL`` options as {edge id: the dashboard's address without a trailing slash}."""
    import re
    from urllib.parse import urlsplit

    from edge.messages import ID_PATTERN

    out = {}
    for item in given:
        edge_id, _, url = item.partition("=")
        parts = urlsplit(url)
        if not re.match(ID_PATTERN, edge_id) or parts.scheme not in ("http", "https") or not parts.hostname:
            raise UserError(f"--board-dashboard {item!r}: give EDGE=URL, e.g. cam1=http://cam1.lab:8080")
        out[edge_id] = url.rstrip("/")
    return out


def _fuse_live(
    config_path: Path | None,
    broker_url: str,
    fuser_id: str,
    settings: FusionSettings,
    http_port: int | None,
    dashboards: dict[str, str],
) -> None:
    import signal
    import threading

    from edge.fusion.service import fuser_for, run_fuser
    from edge.httpserver import HttpServer

    loaded = load(config_path, **{"broker.url": broker_url, "http.port": http_port})
    setup_logging(loaded.config.edge.log_level)
    service = fuser_for(loaded.config, fuser_id, settings, dashboards)
    http = None
    if http_port is not None:
        http = HttpServer.from_config(loaded.config.http, loaded.config.dashboard).start()
        click.echo(f"fused map on http://{loaded.config.http.host}:{http.port}/")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
    signal.signal(signal.SIGINT, lambda signum, frame: stop.set())
    click.echo(f"fuser {fuser_id}: fusing the detections on {service.target.display()} (configuration: {loaded.where})")
    run_fuser(service, stop, http)
