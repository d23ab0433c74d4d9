"""The live twin's commands: ``edge-ips sim twin`` (the lab), ``sim scatter`` and ``sim fault``, and what
``edge-ips start`` does first for it (:func:`first_start`). Thin, as the rest of the command line: each parses its
options and calls the library (:mod:`edge.sim.twin`); :mod:`edge.cli` adds them to its ``sim`` group."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from edge.cli.common import config_option, load

if TYPE_CHECKING:
    from edge.config import EdgeConfig
    from edge.config_load import LoadedConfig

_socket_option = click.option(
    "--socket",
    "socket_file",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="The lab's Unix socket [twin.sock in the state directory].",
)


def _config(config_path: Path | None) -> EdgeConfig:
    return load(config_path).config


def _lab_socket(config_path: Path | None, socket_file: Path | None) -> Path:
    from edge.config import state_dir
    from edge.sim.twin.wire import socket_path

    return socket_file if socket_file is not None else socket_path(state_dir(_config(config_path)))


@click.command("twin")
@click.option("--rovers", type=click.IntRange(1, 12), default=3, show_default=True, help="Rovers on the floor.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed: layouts, motors, camera noise.")
@click.option(
    "--cameras",
    type=click.IntRange(1, 4),
    default=1,
    show_default=True,
    help="1: the paper's lab; 2-4: camera boards over the 8 x 5.5 m wide arena, one edge each "
    "(edge-ips start --source sim:twin:camK).",
)
@click.option(
    "--broker",
    "broker_url",
    default=None,
    metavar="URL",
    help="mqtt://host:port the rovers connect to [this machine's embedded broker, with the state directory's logins].",
)
@click.option(
    "--credentials",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="[rovers.<id>] logins (broker-config's credentials.toml) [the embedded broker's, in the state directory].",
)
@click.option(
    "--config-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Per-rover configs with their logins: <id>/config.json (edge-ips flash --bundle DIR/<id>) or <id>.json.",
)
@click.option("--wait-for-logins", is_flag=True, help="Switch the rovers on once --credentials holds their logins.")
@click.option(
    "--link",
    default="wire",
    show_default=True,
    metavar="SETTINGS",
    help="Each rover's Wi-Fi, as in sim formation: a preset (wire, good, typical, poor) and/or key=value items, "
    "e.g. typical,loss=3% or latency=10ms,jitter=10ms,tail=150ms,loss=2%,outages=1/min.",
)
@click.option(
    "--heading",
    type=click.Choice(["two_tone", "plain"]),
    default="two_tone",
    show_default=True,
    help="Markers: front 30% near-white (heading even standing) or one colour.",
)
@click.option(
    "--camera-latency-ms",
    type=float,
    default=40.0,
    show_default=True,
    help="Exposure to hand-over of each frame (a USB webcam's readout, transfer, decoding).",
)
@click.option(
    "--exit-unwatched",
    type=float,
    default=None,
    metavar="SECONDS",
    help="End when no edge has watched the camera for this long [run until Ctrl-C].",
)
@_socket_option
@config_option
def sim_twin(
    rovers: int,
    seed: int,
    cameras: int,
    broker_url: str | None,
    credentials: Path | None,
    config_dir: Path | None,
    wait_for_logins: bool,
    link: str,
    heading: str,
    camera_latency_ms: float,
    exit_unwatched: float | None,
    socket_file: Path | None,
    config_path: Path | None,
) -> None:
    """Run the twin's lab: a floor, a camera above it, and each rover's real firmware, until Ctrl-C.

    Each rover is its own MQTT client with its own login, driving a simulated body (the drive model of the
    closed-loop experiments; bodies cannot pass through each other) by its motor duties; the camera renders the
    floor as it moves and serves the frames on a local socket, where `edge-ips start --source sim:twin` reads them
    as from a webcam. Each rover's MQTT connection crosses a modelled Wi-Fi link (--link: latency, jitter, loss,
    outages). `start` runs one itself (3 rovers, a perfect link, this machine's embedded broker) when none is
    running; run it yourself for more rovers, a poorer link, or an external broker with its logins. Prints what the
    rovers do.

    With --cameras 2 to 4 the floor is the wide arena, seen by that many cameras with overlapping views: run one
    `edge-ips start --source sim:twin:camK` per camera (edge.publish = "detections", each its own --edge-id and
    --http-port) and `edge-ips fuse --broker URL`, all on one external broker.

    Example:

    \b
        edge-ips sim twin --rovers 6 --link poor & edge-ips start --source sim:twin
        edge-ips sim twin --broker mqtt://localhost:1883 --credentials broker/credentials.toml
        edge-ips sim twin --cameras 2 --broker mqtt://localhost:1883 --credentials broker/credentials.toml
    """
    import signal
    import threading
    from typing import cast

    from edge.broker.credentials import credentials_path
    from edge.config import broker_target, state_dir
    from edge.sim.link import LinkSettings
    from edge.sim.twin.lab import LabSettings
    from edge.sim.twin.service import LabPlan, run_lab
    from edge.sim.twin.wire import socket_path

    config = _config(config_path)
    if broker_url is None:
        target = broker_target(config.broker)
        if target.embedded:
            broker_url = f"mqtt://127.0.0.1:{config.broker.embedded_port}"
            if credentials is None and config_dir is None:
                credentials, wait_for_logins = credentials_path(state_dir(config)), True
        else:
            broker_url = f"mqtt://{target.host}:{target.port}"
    plan = LabPlan(
        LabSettings(
            rovers=rovers,
            seed=seed,
            cameras=cameras,
            heading=cast("Any", heading),
            camera_latency_ms=camera_latency_ms,
            link=LinkSettings.parse(link),
        ),
        broker_url,
        socket_file if socket_file is not None else socket_path(state_dir(config)),
        credentials=credentials,
        config_dir=config_dir,
        wait_for_logins=wait_for_logins,
        exit_unwatched_s=exit_unwatched,
    )
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *args: stop.set())
    run_lab(plan, stop, lambda line: click.echo(line))


@click.command("scatter")
@_socket_option
@config_option
def sim_scatter(socket_file: Path | None, config_path: Path | None) -> None:
    """Pick every rover of the twin's lab up and put it down at a random free spot (to try a formation again).

    Example:

        edge-ips sim scatter
    """
    from edge.sim.twin.source import LabClient

    placed = LabClient(_lab_socket(config_path, socket_file)).scatter()
    for rover_id, (x, y) in placed.items():
        click.echo(f"{rover_id}: ({x:g}, {y:g}) cm")


@click.command("fault")
@click.argument("kind", type=click.Choice(["wifi", "camera", "broker", "edge"]))
@click.option("--rover", default=None, help="wifi: the rover whose Wi-Fi goes.")
@click.option("--camera", default=None, help="camera: the one that hangs, of a lab of several (cam1 ...) [the first].")
@click.option(
    "--for", "seconds", type=click.FloatRange(0.1, 300.0), default=5.0, show_default=True, help="How long, s."
)
@click.option(
    "--url", default=None, help="The edge's dashboard (broker and edge faults) [http://127.0.0.1:<http.port>/]."
)
@_socket_option
@config_option
def sim_fault(
    kind: str,
    rover: str | None,
    camera: str | None,
    seconds: float,
    url: str | None,
    socket_file: Path | None,
    config_path: Path | None,
) -> None:
    """Cause a fault in the twin and watch on the dashboard what the rovers do (they stop, and come back).

    wifi: one rover's access point gone (the firmware sees Wi-Fi lost); camera: the camera hangs (no frames, the
    stream open; --camera camK for one of a lab of several); broker: the embedded broker stopped and started
    again; edge: the appliance killed (no clean-up) and started again, as a service manager would. wifi and camera
    go to the lab; broker and edge to the edge's dashboard, with its token (dashboard.token, or the one start made
    in the state directory).

    Example:

    \b
        edge-ips sim fault wifi --rover green --for 5
        edge-ips sim fault edge --for 3
        edge-ips sim fault camera --camera cam2 --for 5
    """
    if kind in ("wifi", "camera"):
        from edge.sim.twin.source import LabClient

        click.echo(LabClient(_lab_socket(config_path, socket_file)).fault(kind, seconds, rover, camera))
        return
    from edge.sim.twin.remote import post_fault

    config = _config(config_path)
    click.echo(post_fault(config, url, {"kind": kind, "seconds": seconds}))


# -- what `edge-ips start` does before it starts -------------------------------------------------------------------
def first_start(loaded: LoadedConfig, after_kill: float | None, *, source_given: bool) -> LoadedConfig:
    """``start``'s first steps: wait out a simulated kill's restart delay; with nothing configured, the live twin as
    the source; the dashboard's token (the state directory's, made on the first start, unless one is configured),
    and the page's address with it printed first."""
    import logging
    import sys
    import threading
    from dataclasses import replace

    from edge.config_load import with_overrides
    from edge.dashboard.first_token import with_dashboard_token

    if after_kill is not None:
        logging.getLogger("edge.cli").warning(
            "starting again %g s after a kill, as a service manager would", after_kill
        )
        threading.Event().wait(after_kill)
    config = loaded.config
    nothing_configured = loaded.path is None and "EDGE_IPS_CAMERA__SOURCE" not in loaded.env_keys
    if not source_given and nothing_configured and config.camera.source == "sim":
        config = with_overrides(config, **{"camera.source": "sim:twin"})
    config, address = with_dashboard_token(config)
    if address:
        click.echo(address)
        sys.stdout.flush()
    return replace(loaded, config=config)


def restart_argv() -> list[str] | None:
    """How to start this process again after the twin's "edge killed" fault: the interpreter's arguments when this
    is the ``edge-ips`` command (its script, or ``python -m edge.cli``); None when start runs inside another program
    (a test runner), which a restart must not replace."""
    import sys

    script = Path(sys.argv[0])
    ours = script.name == "edge-ips" or (script.name == "__main__.py" and script.parent.name == "cli")
    return list(sys.orig_argv[1:]) if ours else None
