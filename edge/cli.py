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


# -- track, plot -------------------------------------------------------------------------------------------------
@main.command()
@click.argument("video", type=click.Path(path_type=Path))
@click.option(
    "--calibration",
    "calibration_path",
    type=click.Path(path_type=Path),
    required=True,
    help="calibration.json (edge-ips calibrate) or a camera.json of a known camera (the simulator writes one).",
)
@click.option("--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Poses file.")
@click.option(
    "--background",
    "background_path",
    type=click.Path(path_type=Path),
    default=None,
    help="An empty-scene frame (the paper's reference). Without it the reference is learned from the video.",
)
@click.option(
    "--method",
    type=click.Choice(["centroid", "particles", "meanshift", "paper"]),
    default=None,
    help="Tracker (default: the configuration's, else particles). paper: the full-frame baseline.",
)
@click.option(
    "--config",
    "config_path",
    type=click.Path(path_type=Path),
    default=None,
    help="TOML with the rovers ([[rovers]] id, color_bgr) and tracker settings (or a [tracker] table).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON object.")
def track(
    video: Path,
    calibration_path: Path,
    out_path: Path,
    background_path: Path | None,
    method: str | None,
    config_path: Path | None,
    as_json: bool,
) -> None:
    """Track the rovers in a video file and write one pose v1 JSON line per rover per frame.

    Each line is byte for byte the message the edge would publish. At the end prints the processing frame rate,
    the detection rate and how many poses each rover got.

    Example:

        edge-ips track run/video.mp4 --calibration run/camera.json --background run/background.png --out poses.jsonl
    """
    import json

    from edge.offline import open_track_job
    from edge.pipeline import TrackerConfig, load_tracker_config

    config = load_tracker_config(config_path) if config_path is not None else TrackerConfig()
    if method is not None:
        config = config.model_copy(update={"method": method})
    job = open_track_job(video, calibration_path, config, background_path)
    total = max(job.frames.frame_count, 1)
    with click.progressbar(length=total, label="tracking", file=_null() if as_json else None) as bar:
        summary = job.run(out_path, on_frame=lambda _r: bar.update(1))
    if as_json:
        click.echo(json.dumps(summary.as_dict()))
        return
    click.echo(
        f"{summary.frames} frames, {summary.processing_fps:.1f} frames/s processing "
        f"({summary.wall_fps:.1f} with decoding), detection {100.0 * summary.detection_rate:.1f}%"
    )
    for rover_id, count in summary.per_rover.items():
        click.echo(f"  {rover_id}: {count} poses")
    click.echo(f"wrote {out_path}")


def _null() -> Any:
    import io

    return io.StringIO()


@main.command()
@click.argument("poses", type=click.Path(path_type=Path))
@click.option("--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Image.")
@click.option("--title", default=None, help="Figure title.")
def plot(poses: Path, out_path: Path, title: str | None) -> None:
    """Plot pose JSON lines as the paper's Figs. 33-38: X-Y map and X, Y against time per rover.

    Example:

        edge-ips plot poses.jsonl --out plot.png
    """
    from edge.plotting import plot_poses

    counts = plot_poses(poses, out_path, title)
    click.echo(f"wrote {out_path} ({', '.join(f'{k}: {v}' for k, v in counts.items())} poses)")


if __name__ == "__main__":  # pragma: no cover
    main()
