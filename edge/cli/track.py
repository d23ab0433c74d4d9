"""``edge-ips track`` and ``edge-ips plot``: a video file to pose lines, pose lines to the paper's figures."""

from __future__ import annotations

from pathlib import Path

import click

from edge.cli.common import quiet


@click.command()
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
    from edge.tracker_config import TrackerConfig, load_tracker_config

    config = load_tracker_config(config_path) if config_path is not None else TrackerConfig()
    if method is not None:
        config = config.model_copy(update={"method": method})
    job = open_track_job(video, calibration_path, config, background_path)
    total = max(job.frames.frame_count, 1)
    with click.progressbar(length=total, label="tracking", file=quiet() if as_json else None) as bar:
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


@click.command()
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
