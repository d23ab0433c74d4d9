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


# -- sim ---------------------------------------------------------------------------------------------------------
@main.group()
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
@click.option("--rovers", type=click.IntRange(min=1, max=48), default=None, help="Number of rovers [scenario's].")
def sim_render(scenario: str, out_dir: Path, frames: int | None, seed: int, rovers: int | None) -> None:
    """Render SCENARIO to a 30 fps video with per-frame ground truth.

    truth.csv has one row per rover per frame: frame,id,x,y,theta,vx,vy (marker centre in world cm at marker
    height, heading in radians, velocity in cm/s).

    Example:

        edge-ips sim render lab --out runs/lab --frames 300 --seed 1
    """
    from edge.sim.export import ensure_directory, render_to_directory
    from edge.sim.scenarios import build

    total = build(scenario, seed=seed, rovers=rovers, frames=frames).frames  # checks the request before starting
    ensure_directory(out_dir)
    with click.progressbar(length=total, label=f"rendering {scenario}") as bar:
        summary = render_to_directory(
            scenario, out_dir, frames=frames, seed=seed, rovers=rovers, progress=lambda n: bar.update(n)
        )
    click.echo(f"wrote {summary.frames} frames of {scenario} (seed {seed}) to {summary.out_dir}")
    click.echo(f"  files: {', '.join(summary.written)}")
    for skipped in summary.skipped:
        click.echo(f"  skipped: {skipped}")
    click.echo(f"  rendering: {summary.render_ms_mean:.1f} ms per frame")


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


if __name__ == "__main__":  # pragma: no cover
    main()
