"""``edge-ips sim``: the camera-scene simulator, the closed-loop experiments, the rovers' firmware on a broker."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import click

from edge.cli.common import UserError


@click.group()
def sim() -> None:
    """The camera-scene simulator: the paper's lab rendered with ground truth.

    Example:

        edge-ips sim scenarios
    """


@sim.command("render")
@click.argument("scenario")
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Directory for video.mp4, truth.csv, visibility.csv, points.csv, background.png, camera.json.",
)
@click.option("--frames", type=click.IntRange(min=1), default=None, help="Frames to render [scenario's default].")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed: trajectories, lighting phases, noise.")
@click.option(
    "--rovers",
    type=click.IntRange(min=1, max=64),
    default=None,
    help="Number of rovers (48 at most, wide 64) [scenario's].",
)
@click.option(
    "--heading",
    type=click.Choice(["plain", "two_tone", "aruco"]),
    default="plain",
    show_default=True,
    help="Markers that show heading: front 30% near-white (two_tone) or an ArUco tag (aruco).",
)
@click.option(
    "--kit",
    is_flag=True,
    help="Also write check.csv, floor.png + markers.csv (ArUco) and, for a distorting lens, checkerboard boards/.",
)
@click.option(
    "--cameras",
    type=click.IntRange(min=2, max=4),
    default=None,
    help="wide: the number of camera boards (2, 3 or 4)  [default: 4].",
)
def sim_render(
    scenario: str,
    out_dir: Path,
    frames: int | None,
    seed: int,
    rovers: int | None,
    heading: str,
    kit: bool,
    cameras: int | None,
) -> None:
    """Render SCENARIO to a 30 fps video with per-frame ground truth.

    truth.csv has one row per rover per frame: frame,id,x,y,theta,vx,vy (marker centre in world cm at marker
    height, heading in radians, velocity in cm/s).

    SCENARIO wide is an 8 x 5.5 m arena seen by --cameras boards with overlapping views: truth.csv for the whole
    arena and one directory per camera (cam1 ... camN) with its video, survey points in the shared floor frame,
    check points, background, camera and rovers.toml.

    Example:

    \b
        edge-ips sim render lab --out runs/lab --frames 300 --seed 1
        edge-ips sim render lens --out runs/lens --kit   # + a calibration session
        edge-ips sim render wide --cameras 4 --rovers 20 --out runs/wide
    """
    if scenario == "wide":
        _render_wide(out_dir, cameras or 4, frames, seed, rovers)
        return
    if cameras is not None:
        raise UserError(f"--cameras is for the wide scenario, not {scenario}")
    if rovers is not None and rovers > 48:
        raise UserError(f"--rovers {rovers}: at most 48 in scenario {scenario} (64 in wide)")
    from edge.sim.export import ensure_directory, render_to_directory
    from edge.sim.scenarios import build
    from edge.sim.scene import Heading

    look = cast("Heading", heading)
    total = build(scenario, seed=seed, rovers=rovers, frames=frames, heading=look).frames  # check before starting
    ensure_directory(out_dir)
    with click.progressbar(length=total, label=f"rendering {scenario}") as bar:
        summary = render_to_directory(
            scenario,
            out_dir,
            frames=frames,
            seed=seed,
            rovers=rovers,
            heading=look,
            kit=kit,
            progress=lambda n: bar.update(n),
        )
    click.echo(f"wrote {summary.frames} frames of {scenario} (seed {seed}) to {summary.out_dir}")
    click.echo(f"  files: {', '.join(summary.written)}")
    click.echo(f"  rendering: {summary.render_ms_mean:.1f} ms per frame")


def _render_wide(out_dir: Path, cameras: int, frames: int | None, seed: int, rovers: int | None) -> None:
    from edge.sim.export import ensure_directory
    from edge.sim.wide import build_wide
    from edge.sim.wide_export import render_wide_to_directory

    total = build_wide(cameras, seed=seed, rovers=rovers, frames=frames).frames  # check before starting
    ensure_directory(out_dir)
    with click.progressbar(length=total, label=f"rendering wide, {cameras} cameras") as bar:
        summary = render_wide_to_directory(
            out_dir, cameras=cameras, frames=frames, seed=seed, rovers=rovers, progress=lambda n: bar.update(n)
        )
    click.echo(f"wrote {summary.frames} frames of the wide arena (seed {seed}) to {summary.out_dir}")
    click.echo(f"  cameras: {', '.join(summary.cameras)}; truth.csv, wide.json")
    click.echo(f"  rendering: {summary.render_ms_mean:.1f} ms per camera frame")


@sim.command("scenarios")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list instead of a table.")
def sim_scenarios(as_json: bool) -> None:
    """List the simulator's scenarios, one line each.

    Example:

        edge-ips sim scenarios
    """
    from edge.sim.scenarios import SCENARIOS

    if as_json:
        import json

        rows = [
            {"name": s.name, "summary": s.summary, "rovers": s.default_rovers, "frames": s.default_frames}
            for s in SCENARIOS.values()
        ]
        click.echo(json.dumps(rows, indent=2))
        return
    width = max(len(name) for name in SCENARIOS)
    for s in SCENARIOS.values():
        click.echo(f"{s.name:<{width}}  {s.summary} ({s.default_rovers} rovers, {s.default_frames} frames)")


def _experiment_options(f: Any) -> Any:
    for option in reversed(
        [
            click.option(
                "--rovers", type=click.IntRange(min=1, max=12), default=3, show_default=True, help="Number of rovers."
            ),
            click.option(
                "--seed",
                type=int,
                default=0,
                show_default=True,
                help="Seed: starting layout (formations) or paths (trajectories), motors, noise.",
            ),
            click.option(
                "--out",
                "out_dir",
                type=click.Path(file_okay=False, path_type=Path),
                default=None,
                help="Output directory [runs/KIND-SEED].",
            ),
            click.option(
                "--broker",
                "broker_url",
                default=None,
                metavar="URL",
                help="mqtt://host:port of a running broker (Mosquitto) [an embedded amqtt broker].",
            ),
            click.option(
                "--frames",
                type=click.IntRange(min=1),
                default=None,
                help="Frames to run (30 per second) [formations: 360; trajectories: the whole path].",
            ),
            click.option(
                "--heading",
                type=click.Choice(["two_tone", "plain"]),
                default="two_tone",
                show_default=True,
                help="Markers: front 30% near-white (heading even standing) or one colour.",
            ),
            click.option(
                "--link",
                default="wire",
                show_default=True,
                metavar="SETTINGS",
                help="Wi-Fi between the broker and each rover: a preset (wire, good, typical, poor) and/or "
                "key=value items, e.g. typical,loss=3% or latency=10ms,jitter=10ms,tail=150ms,loss=2%,outages=1/min.",
            ),
            click.option("--video", is_flag=True, help="Also write camera.mp4, the annotated camera view."),
            click.option("--json", "as_json", is_flag=True, help="Print metrics.json instead of a summary."),
        ]
    ):
        f = option(f)
    return f


@dataclass(frozen=True)
class ExperimentOptions:
    """The options the closed-loop commands share (:func:`_experiment_options`), by name."""

    rovers: int
    seed: int
    out_dir: Path | None
    broker_url: str | None
    frames: int | None
    heading: str
    link: str
    video: bool
    as_json: bool


def _run_experiment(kind: str, options: ExperimentOptions) -> dict[str, Any]:
    from edge.sim.link import LinkSettings
    from edge.sim.loop import LoopConfig
    from edge.sim.report import link_line, run_to_directory

    o = options
    config = LoopConfig(
        kind,
        rovers=o.rovers,
        seed=o.seed,
        frames=o.frames,
        broker_url=o.broker_url,
        heading=cast("Any", o.heading),
        link=LinkSettings.parse(o.link),
    )
    out = o.out_dir if o.out_dir is not None else Path("runs") / f"{kind}-{o.seed}"
    with click.progressbar(
        length=config.n_frames if config.formation else 0, label=f"{kind} (seed {o.seed})", file=sys.stderr
    ) as bar:
        metrics = run_to_directory(config, out, video=o.video, progress=lambda k: bar.update(1))
    if o.as_json:
        import json

        click.echo(json.dumps(metrics, indent=2))
    else:
        click.echo(
            f"wrote {out}: metrics.json, truth.csv, poses.jsonl, motors.csv, map.png, snapshots.png, "
            f"xy_time.png{', camera.mp4' if o.video else ''}"
        )
        e = metrics["ips_error_cm"]
        if e["n"]:
            click.echo(
                f"  IPS error: mean {e['mean']:.2f} cm, p95 {e['p95']:.2f} cm, max {e['max']:.2f} cm "
                f"over {e['n']} poses"
            )
        m = metrics["messages"]
        late = sum(m["deliveries_late"].values())
        click.echo(f"  messages: {m['poses_published']} poses published, {m['poses_dropped']} dropped, {late} late")
        if "link" in metrics:
            click.echo("  " + link_line(metrics["link"]))
    return metrics


@sim.command("formation")
@click.argument("kind", type=click.Choice(["line", "rendezvous", "triangle"]))
@_experiment_options
def sim_formation(kind: str, **options: Any) -> None:
    """Closed-loop formation (paper Figs. 27-32): rendered camera -> tracker -> MQTT -> rover firmware -> rovers.

    The rovers start at random places at least 1.5 m apart (1 m beyond 8 rovers; --seed) and form KIND: a
    vertical line 60 cm apart, a rendezvous (all inside 40 cm), or a triangle of 100 cm sides. Writes
    metrics.json, truth.csv (frame,id,x,y,theta), poses.jsonl (every pose published), motors.csv and the figures.
    Exit status 1 when the run misses a bar (formed by frame 240, no bodies touching, every rover's motors off
    within 0.5 s of its last fresh pose). --link puts a modelled Wi-Fi link between the broker and each rover.

    Example:

    \b
        edge-ips sim formation line --seed 3 --out runs/line-3
        edge-ips sim formation triangle --broker mqtt://localhost:1883 --video
        edge-ips sim formation line --link poor --seed 4
    """
    run = ExperimentOptions(**options)
    metrics = _run_experiment(kind, run)
    if not run.as_json:
        conv = metrics["converged_frame"]
        final = metrics["final"]
        shape = ", ".join(
            f"{k} {', '.join(f'{x:.1f}' for x in v) if isinstance(v, list) else f'{v:.1f}'}" for k, v in final.items()
        )
        passed = metrics["passed"]
        verdict = "passes" if all(passed.values()) else "FAILS " + ", ".join(k for k, v in passed.items() if not v)
        click.echo(
            f"  {kind}: {shape}; converged at frame {conv}; closest centres "
            f"{metrics['min_centre_distance_cm']:.1f} cm, body gap {metrics['min_body_gap_cm']:.1f} cm; "
            f"{verdict}"
        )
    if not all(metrics["passed"].values()):
        sys.exit(1)  # the run is written; the exit status says a bar was missed


@sim.command("trajectory")
@click.argument("kind", type=click.Choice(["circle", "diagonal"]))
@_experiment_options
def sim_trajectory(kind: str, **options: Any) -> None:
    """Scripted paths tracked by the IPS (paper Figs. 33-38): circles, or the diagonal of the working area.

    The rovers follow edge.sim.trajectories plans; every frame is rendered, tracked and published through the
    broker; the figures put the IPS output beside the ground truth.

    Example:

    \b
        edge-ips sim trajectory circle --out runs/circle
        edge-ips sim trajectory diagonal --seed 2
    """
    _run_experiment(kind, ExperimentOptions(**options))


@sim.command("rovers")
@click.option(
    "--broker", "broker_url", required=True, metavar="URL", help="The broker to connect to: mqtt://host:port."
)
@click.option("--ids", default=None, help="Comma-separated rover ids [those in --config-dir, else red,green,blue].")
@click.option(
    "--config-dir",
    type=click.Path(path_type=Path),
    default=None,
    help="Per-rover configs with their credentials: <id>/config.json (edge-ips flash --bundle DIR/<id>) or <id>.json.",
)
@click.option(
    "--credentials",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="[rovers.<id>] username and password for each rover (the credentials.toml of edge-ips broker-config).",
)
def sim_rovers(broker_url: str, ids: str | None, config_dir: Path | None, credentials: Path | None) -> None:
    """Run the real firmware of each rover on this computer against a broker, until Ctrl-C.

    Each rover is its own MQTT client (client id rover-<id>) with its own credentials, running the modules that are
    flashed onto the board; motors, Wi-Fi and the clock are host stand-ins. Prints each status a rover publishes that
    says something new (halt reason, formation applied) and each change of its link. A way to try a broker and its
    ACLs before flashing anything.

    Example:

    \b
        edge-ips sim rovers --broker mqtt://localhost:1883
        edge-ips sim rovers --broker mqtt://10.0.0.5:1883 --credentials broker/credentials.toml
    """
    import signal
    import threading
    import time

    from edge.sim.fleet import FleetEvent, parse_ids, start_fleet

    lock = threading.Lock()

    def show(event: FleetEvent) -> None:
        with lock:
            click.echo(f"{time.strftime('%H:%M:%S')} {event.rover_id}: {event.text}")

    from edge.errors import BrokerError

    chosen = parse_ids(ids) if ids is not None else None
    try:
        fleet = start_fleet(broker_url, chosen, config_dir=config_dir, credentials=credentials, on_event=show)
    except BrokerError as exc:
        if config_dir is not None or credentials is not None or "refused rover" not in str(exc):
            raise
        raise BrokerError(
            f"{exc}; without --credentials or --config-dir the rovers log in with no password: give them their "
            "logins (the embedded broker of edge-ips start: --credentials <state dir>/broker-credentials.toml; "
            "Mosquitto: the credentials.toml of edge-ips broker-config)"
        ) from None
    show(FleetEvent("sim", f"{', '.join(r.id for r in fleet.runners)} running on {broker_url}; Ctrl-C stops them"))
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *args: stop.set())
    try:
        while not stop.wait(1.0):
            pass
    finally:
        fleet.close()
    show(FleetEvent("sim", "stopped: each rover said offline"))
