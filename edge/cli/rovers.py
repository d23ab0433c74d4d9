"""``edge-ips rovers``: the rovers' marker colours as this camera sees them under this light."""

from __future__ import annotations

from pathlib import Path

import click

from edge.cli.common import UserError, config_option, load


@click.group()
def rovers() -> None:
    """The rovers' marker colours as this camera sees them under this light.

    Example:

        edge-ips rovers enroll --image frame.png --background empty.png --calibration calibration.json --out rovers.toml
    """


@rovers.command("enroll")
@click.option("--image", "image", type=click.Path(path_type=Path), help="A frame with the rovers in view.")
@click.option("--source", "source", metavar="SPEC", help="Take the frame from this camera, stream, video or sim.")
@click.option(
    "--background", "background", type=click.Path(path_type=Path), required=True, help="The empty floor, same camera."
)
@click.option(
    "--calibration",
    "calibration",
    type=click.Path(path_type=Path),
    required=True,
    help="calibration.json (or camera.json).",
)
@click.option(
    "--out", "out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="rovers.toml to write."
)
@click.option("--ids", "ids", default=None, help="Comma-separated rover ids, one per marker (default: named by hue).")
@config_option
@click.option("--json", "as_json", is_flag=True, help="Print the markers as JSON.")
def rovers_enroll(
    image: Path | None,
    source: str | None,
    background: Path,
    calibration: Path,
    out: Path,
    ids: str | None,
    config_path: Path | None,
    as_json: bool,
) -> None:
    """Measure every rover marker in view against the empty floor and write their [[rovers]] tables.

    Each marker's colour is the median of its interior (glare and edge pixels left out); a two-tone marker's light
    front part is measured too. Without --ids the rovers are named by hue; ids that are hue names (red, green...)
    go to the marker of the nearest hue, others in order of x, then y, on the floor. Two hues this camera and light
    cannot keep apart are named in a warning. The file is a configuration of its own (--config rovers.toml) or
    its [[rovers]] tables go into the appliance's. --source takes the camera settings (size, controls) from the
    configuration: enroll with the controls the appliance runs with.

    Example:

    \b
        edge-ips rovers enroll --image frame.png --background empty.png --calibration calibration.json --out rovers.toml
        edge-ips rovers enroll --source /dev/video0 --background empty.png --calibration calibration.json \\
            --ids r1,r2,r3 --out rovers.toml --config /etc/edge-ips/config.toml
    """
    import dataclasses
    import json

    from edge.calibration.intrinsics import read_image
    from edge.enroll import enroll, save_enrolment
    from edge.offline import load_plane_mapping

    if (image is None) == (source is None):
        raise UserError("give the frame with either --image FRAME.png or --source SPEC")
    config = load(config_path, **{"camera.source": source}).config
    if image is not None:
        frame, where = read_image(image), str(image)
    else:
        from edge.appliance import grab_configured_frame

        frame, where = grab_configured_frame(config), config.camera.source
    empty = read_image(background)
    mapping = load_plane_mapping(calibration, (frame.shape[1], frame.shape[0]))
    tracker = config.tracker
    result = enroll(
        frame,
        empty,
        mapping,
        ids=[i.strip() for i in ids.split(",")] if ids else None,
        marker_length_cm=tracker.marker_length_cm,
        marker_width_cm=tracker.marker_width_cm,
    )
    save_enrolment(result, out, where)
    if as_json:
        rows = [dataclasses.asdict(m) for m in result.markers]
        click.echo(json.dumps({"markers": rows, "warnings": list(result.warnings), "out": str(out)}))
        return
    for m in result.markers:
        front = f"; front {m.front_color_bgr}, {m.front_fraction:g} of its length" if m.front_color_bgr else ""
        click.echo(
            f"{m.rover_id}: color_bgr {m.color_bgr}, hue {m.hue_deg:.0f} deg (spread {m.spread_deg:.1f}), at "
            f"({m.xy_cm[0]:.1f}, {m.xy_cm[1]:.1f}) cm, {m.length_cm:.1f} x {m.width_cm:.1f} cm{front}"
        )
    for line in result.ignored:
        click.echo(f"ignored: {line}")
    for warning in result.warnings:
        click.echo(f"WARNING: {warning}")
    click.echo(f"wrote {len(result.markers)} rovers to {out}")
