"""``edge-ips calibrate``: pixels to world cm on the marker plane (points, intrinsics, aruco, check), and the
rolling shutter's line time (line-time)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click

from edge.cli.common import UserError, config_option, load, quiet

if TYPE_CHECKING:
    from edge.calibration.check import CheckResult
    from edge.calibration.points import PointTable
    from edge.calibration.refine import Refined


def parse_size(text: str | None, option: str) -> tuple[float, float] | None:
    """``WIDTHxHEIGHT`` (``--size 1280x720``, ``--area 380x550``) as two positive numbers (None: not given)."""
    if text is None:
        return None
    try:
        a, b = (float(p) for p in text.lower().replace(" ", "").split("x"))
    except ValueError:
        raise UserError(f"{option} {text!r}: expected WIDTHxHEIGHT, e.g. 1280x720") from None
    if not (0 < a < 1e6 and 0 < b < 1e6):
        raise UserError(f"{option} {text!r}: both numbers must be positive and finite")
    return a, b


def parse_area(text: str | None) -> tuple[float, float, float, float] | None:
    """``--area WIDTHxLENGTH``: the working area from the origin, cm."""
    size = parse_size(text, "--area")
    return None if size is None else (0.0, 0.0, size[0], size[1])


@click.group()
def calibrate() -> None:
    """Calibrate the camera: pixels to world cm on the marker plane.

    Point pairs (`points`), lens intrinsics from checkerboards (`intrinsics`), ArUco floor markers (`aruco`),
    checking a calibration against independently measured points (`check`), and the rolling shutter's line time
    from the lamps' flicker (`line-time`).

    Example:

        edge-ips calibrate points points.csv --out calibration.json --error-map map.png
    """


@calibrate.command("points")
@click.argument("points_csv", type=click.Path(path_type=Path))
@click.option("--out", "out", type=click.Path(path_type=Path), required=True, help="Calibration file to write.")
@click.option("--image", "image", type=click.Path(path_type=Path), help="Reference image (size; map background).")
@click.option("--error-map", "error_map", type=click.Path(path_type=Path), help="Write the error map PNG here.")
@click.option("--height", "height_cm", type=float, default=13.0, show_default=True, help="Plane height, cm.")
@click.option("--intrinsics", "intrinsics", type=click.Path(path_type=Path), help="Lens intrinsics (undistort).")
@click.option("--size", "size", help="Image size WxH when no --image or --intrinsics is given.  [default: 1280x720]")
@click.option("--area", "area", help="Working area WIDTHxLENGTH cm from the origin.  [default: the points' box]")
@click.option("--no-outlier-test", is_flag=True, help="Keep every point (the outlier test is on by default).")
@click.option(
    "--refine-on",
    "refine_on",
    type=click.Path(path_type=Path),
    help="Photo of printed 2x2 checker targets on the points: each click moved onto its target's corner.",
)
def calibrate_points_cmd(
    points_csv: Path,
    out: Path,
    image: Path | None,
    error_map: Path | None,
    height_cm: float,
    intrinsics: Path | None,
    size: str | None,
    area: str | None,
    no_outlier_test: bool,
    refine_on: Path | None,
) -> None:
    """Fit the image-to-world mapping to surveyed points (CSV with header u,v,x,y: pixels; world cm).

    A mis-measured point is detected (leave-one-out), reported and left out. Accuracy is reported as
    leave-one-out errors: each point predicted by a fit made without it. With printed targets on the points and a
    photo of them (--refine-on), each click is moved onto its target's corner: clicks are good to about half a
    pixel, the targets' corners to a tenth, and at the far side a pixel is 2 cm.

    Example:

    \b
        edge-ips calibrate points points.csv --out calibration.json --image reference.png --error-map map.png
        edge-ips calibrate points points.csv --refine-on targets.png --out calibration.json
    """
    from edge.calibration.workflow import calibrate_points_files

    given = parse_size(size, "--size")
    run = calibrate_points_files(
        points_csv,
        out,
        image=image,
        error_map=error_map,
        height_cm=height_cm,
        intrinsics=intrinsics,
        size=None if given is None else (int(given[0]), int(given[1])),
        area_cm=parse_area(area),
        detect_outliers=not no_outlier_test,
        refine_on=refine_on,
    )
    fit, stats, table = run.result.fit, run.result.stats, run.table
    if run.refined is not None and refine_on is not None:
        for line in _refined_lines("clicks", points_csv, table, run.refined, refine_on):
            click.echo(line)
    click.echo(
        f"calibrated from {len(table)} points in {points_csv} ({fit.n_used} used, {len(fit.rejected)} rejected), "
        f"plane z = {height_cm:g} cm, {run.image_size[0]}x{run.image_size[1]} images"
        + (", lens undistorted with " + str(intrinsics) if intrinsics else "")
    )
    for r in fit.rejected:
        click.echo(
            f"REJECTED {points_csv} row {r.row} (line {r.line}): u,v = {r.uv_px[0]:g},{r.uv_px[1]:g} "
            f"x,y = {r.xy_world_cm[0]:g},{r.xy_world_cm[1]:g}: off by {r.loo_residual_px:.1f} px when fitted without "
            f"it ({r.score:.1f} sigma); maps {r.error_cm:.2f} cm from its x,y. Re-measure it."
        )
    if stats.sigma_px is not None:
        click.echo(
            f"fit residuals: sigma {stats.sigma_px:.2f} px; mean {stats.residual_mean_cm:.3f} cm, "
            f"max {stats.residual_max_cm:.3f} cm"
        )
    if stats.loo_mean_cm is not None:
        click.echo(
            f"leave-one-out error: mean {stats.loo_mean_cm:.3f} cm, max {stats.loo_max_cm:.3f} cm, "
            f"rms {stats.loo_rms_cm:.3f} cm (each point predicted by a fit without it; includes its own "
            "measuring noise)"
        )
    for note in stats.notes:
        click.echo(f"note: {note}")
    em = run.result.error_map
    if em is not None:
        click.echo(
            f"error map (predicted 95% error of the mapping, working area): mean {em.mean_cm:.3f} cm, "
            f"max {em.max_cm:.3f} cm{f' -> {error_map}' if error_map is not None else ''}"
        )
    click.echo(f"wrote {out}")


@calibrate.command("intrinsics")
@click.argument("images", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--board", default="9x6", show_default=True, help="Inner corners COLSxROWS.")
@click.option("--square", "square_cm", type=float, default=2.5, show_default=True, help="Square side, cm.")
@click.option("--out", "out", type=click.Path(path_type=Path), required=True, help="Intrinsics file to write.")
@click.option("--allow-missing", is_flag=True, help="Skip (and list) photos where the board is not found.")
def calibrate_intrinsics_cmd(
    images: tuple[Path, ...], board: str, square_cm: float, out: Path, allow_missing: bool
) -> None:
    """Lens intrinsics (focal length, principal point, distortion) from photos of a printed checkerboard.

    Hold the board at different tilts all over the image, the corners of the image included.

    Example:

        edge-ips calibrate intrinsics board_*.png --board 9x6 --square 2.5 --out intrinsics.json
    """
    from edge.calibration.intrinsics import parse_board
    from edge.calibration.workflow import calibrate_intrinsics_files

    pattern = parse_board(board)
    show = sys.stderr.isatty()  # a bar on a terminal; nothing in logs and pipes
    with click.progressbar(images, label="finding the board", file=sys.stderr if show else quiet()) as bar:
        result = calibrate_intrinsics_files(bar, pattern, square_cm, out, allow_missing=allow_missing)
    for name, reason in result.skipped:
        click.echo(f"skipped {name}: {reason}")
    k = result.intrinsics.camera_matrix
    d = result.intrinsics.dist_coeffs
    per_view = result.per_view_rms_px
    click.echo(
        f"board {pattern[0]}x{pattern[1]} found in {len(result.used)} of {len(images)} images; reprojection error "
        f"RMS {result.rms_px:.3f} px (per image: mean {sum(per_view) / len(per_view):.3f} px, "
        f"max {max(per_view):.3f} px)"
    )
    click.echo(
        f"fx {k[0, 0]:.2f} px, fy {k[1, 1]:.2f} px, principal point ({k[0, 2]:.2f}, {k[1, 2]:.2f}); "
        f"k1 {d[0]:.4f}, k2 {d[1]:.4f}, p1 {d[2]:.5f}, p2 {d[3]:.5f}, k3 {d[4]:.4f}"
    )
    click.echo(f"wrote {out}")


@calibrate.command("aruco")
@click.argument("image", type=click.Path(path_type=Path))
@click.option("--markers", "markers", type=click.Path(path_type=Path), required=True, help="CSV id,x,y,z[,size] cm.")
@click.option("--out", "out", type=click.Path(path_type=Path), required=True, help="Calibration file to write.")
@click.option("--marker-size", "marker_size", type=float, help="Black-square side, cm (when the CSV has no size).")
@click.option("--intrinsics", "intrinsics", type=click.Path(path_type=Path), help="Lens intrinsics file.")
@click.option("--height", "height_cm", type=float, default=13.0, show_default=True, help="Plane to map onto, cm.")
@click.option("--dictionary", default="DICT_4X4_50", show_default=True, help="ArUco dictionary of the markers.")
@click.option("--area", "area", help="Working area WIDTHxLENGTH cm from the origin.  [default: the markers' box]")
def calibrate_aruco_cmd(
    image: Path,
    markers: Path,
    out: Path,
    marker_size: float | None,
    intrinsics: Path | None,
    height_cm: float,
    dictionary: str,
    area: str | None,
) -> None:
    """Calibrate from one image of ArUco markers laid flat at known positions (no clicking).

    Each marker lies upright with its top edge toward +y. The camera pose is recovered, so a calibration made
    with markers on the floor (z = 0) maps the rovers' marker plane (--height 13).

    Example:

        edge-ips calibrate aruco floor.png --markers markers.csv --intrinsics intrinsics.json --out calibration.json
    """
    from edge.calibration.workflow import calibrate_aruco_files

    run = calibrate_aruco_files(
        image,
        markers,
        out,
        marker_size_cm=marker_size,
        intrinsics=intrinsics,
        height_cm=height_cm,
        dictionary=dictionary,
        area_cm=parse_area(area),
    )
    result, table = run.result, run.table
    cam = result.camera
    click.echo(
        f"found {len(result.ids_used)} of {len(table.ids)} markers in {image} (ids {list(result.ids_used)}); "
        f"camera at ({cam.position_cm[0]:.1f}, {cam.position_cm[1]:.1f}, {cam.position_cm[2]:.1f}) cm, "
        f"mapping the plane z = {height_cm:g} cm"
    )
    if result.ids_missing:
        click.echo(f"not found: ids {list(result.ids_missing)}")
    if result.ids_unknown:
        click.echo(f"ignored (not in {markers}): ids {list(result.ids_unknown)}")
    click.echo(f"corner reprojection error: RMS {result.reprojection_rms_px:.3f} px")
    loo = result.loo_error_cm
    if loo is not None:
        click.echo(
            f"leave-one-marker-out error: mean {loo.mean():.3f} cm, max {loo.max():.3f} cm (each marker centre "
            "predicted by a pose fitted without it)"
        )
    for note in result.notes:
        click.echo(f"note: {note}")
    click.echo(f"wrote {out}")


@calibrate.command("line-time")
@click.option("--source", "source", metavar="SPEC", help="The camera (default: the configuration's [camera] source).")
@click.option("--mains", "mains_hz", type=click.Choice(["50", "60"]), required=True, help="The mains frequency, Hz.")
@click.option("--frames", "count", type=click.IntRange(8, 120), default=60, show_default=True, help="Frames to read.")
@config_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (line_time_us, period_rows, ...).")
def calibrate_line_time_cmd(
    source: str | None, mains_hz: str, count: int, config_path: Path | None, as_json: bool
) -> None:
    """Measure the camera's rolling-shutter line time ([tracker] line_time_us) from the lamps' flicker bands.

    Lamps on mains power ripple at twice its frequency, and a rolling shutter shows the ripple as horizontal bands
    that roll from frame to frame; their spacing gives the time between two rows' exposures. Point the camera at
    the floor under mains-powered lamps with a short manual exposure for the measurement (exposure = 5, 0.5 ms, in
    [camera.controls]); the camera's size and frame rate are the configuration's (the line time can change with
    them). At 30 fps under 60 Hz mains (or 25 under 50 Hz) the bands stand still: measure at the other rate.

    Example:

    \b
        edge-ips calibrate line-time --mains 50 --config /etc/edge-ips/config.toml
    """
    import dataclasses
    import json

    from edge.appliance import default_sim_factory
    from edge.line_time import line_time_from_flicker
    from edge.source_spec import camera_source
    from edge.sources import grab_frames

    config = load(config_path, **{"camera.source": source}).config
    # the simulator unpaced: consecutive frames however slow the reader (a live camera paces itself)
    frames = grab_frames(camera_source(config.camera, default_sim_factory(config), realtime=False), count)
    result = line_time_from_flicker(frames, float(mains_hz), config.camera.fps)
    if as_json:
        click.echo(json.dumps(dataclasses.asdict(result)))
        return
    click.echo(
        f"line_time_us = {result.line_time_us:.1f}   # bands {result.period_rows:.1f} rows apart, contrast "
        f"{100 * result.contrast:.1f} %, {100 * result.share:.0f} % of the rows' variation, {result.frames} frames"
    )
    click.echo("put it in the [tracker] section of the configuration")


@calibrate.command("check")
@click.argument("pairs", nargs=-1, required=True, metavar="CALIBRATION CHECK_CSV [CALIBRATION CHECK_CSV ...]")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (mean_cm, max_cm, n, points...).")
@click.option(
    "--refine-on",
    "refine_on",
    type=click.Path(path_type=Path),
    multiple=True,
    help="Photo of printed targets on the check points (one per board, in order): each moved onto its corner.",
)
def calibrate_check_cmd(pairs: tuple[str, ...], as_json: bool, refine_on: tuple[Path, ...]) -> None:
    """Check a calibration against points measured but not used in the fit (CSV u,v,x,y).

    Maps each point's u,v and reports its distance to the surveyed x,y, and the mean and max. Given several boards
    (a calibration and its check points each, all in one floor frame), also reports the seam error of every pair:
    where the two boards put the check points both see (the same x,y), and how far apart.

    Check points are clicked like survey points, to about half a pixel, and at the far side that is a centimetre of
    their own: with printed targets on them and a photo (--refine-on, one per board) each is moved onto its target's
    corner first, and the figures are the calibration's.

    Example:

    \b
        edge-ips calibrate check calibration.json check.csv --json
        edge-ips calibrate check calibration.json check.csv --refine-on check_targets.png
        edge-ips calibrate check cam1/calibration.json cam1/check.csv cam2/calibration.json cam2/check.csv
    """
    import json

    from edge.calibration.check import check_summary
    from edge.calibration.files import load_calibration
    from edge.calibration.points import read_points_csv
    from edge.fusion.seams import check_boards, seams

    if len(pairs) % 2:
        raise UserError("give a calibration file and its check points CSV for every board (pairs of arguments)")
    paths = [Path(p) for p in pairs]
    boards = [(paths[i], load_calibration(paths[i]), read_points_csv(paths[i + 1])) for i in range(0, len(paths), 2)]
    if refine_on:
        from edge.calibration.workflow import refine_points

        if len(refine_on) != len(boards):
            raise UserError(
                f"--refine-on: one photo per board, in order ({len(boards)} boards, {len(refine_on)} photos)"
            )
        refined_boards = []
        for k, ((cal_path, cal, table), photo) in enumerate(zip(boards, refine_on, strict=True)):
            moved, refined = refine_points(table, photo, cal.image_size)
            refined_boards.append((cal_path, cal, moved))
            if not as_json:
                for line in _refined_lines("check points", paths[2 * k + 1], table, refined, photo):
                    click.echo(line)
        boards = refined_boards
    checks = check_boards(boards)
    names = [c.name for c in checks]
    if len(set(names)) != len(names):
        raise UserError(f"two calibrations have the same board name ({', '.join(names)}): name them apart")
    if len(checks) == 1:
        if as_json:
            click.echo(json.dumps(check_summary(checks[0].check, paths[0], paths[1])))
        else:
            _print_check(checks[0].check, paths[0], paths[1])
        return
    found = seams(checks)
    if as_json:
        doc = {
            "boards": [
                check_summary(c.check, c.calibration_path, paths[2 * k + 1]) | {"board": c.name}
                for k, c in enumerate(checks)
            ],
            "seams": [
                {"a": s.a, "b": s.b, "n": s.n}
                | {k: round(v, 4) for k, v in (("mean_cm", s.mean_cm), ("max_cm", s.max_cm), ("rms_cm", s.rms_cm))}
                for s in found
            ],
        }
        click.echo(json.dumps(doc))
        return
    for k, c in enumerate(checks):
        r = c.check
        click.echo(
            f"{c.name}: {r.n} check points from {paths[2 * k + 1]}: mean {r.mean_cm:.3f} cm, max {r.max_cm:.3f} cm, "
            f"rms {r.rms_cm:.3f} cm"
        )
    if not found:
        click.echo("no check point is seen by two boards: survey some in the overlaps to measure the seams")
    for s in found:
        click.echo(
            f"seam {s.a}/{s.b}: {s.n} shared points, the boards disagree by mean {s.mean_cm:.3f} cm, "
            f"max {s.max_cm:.3f} cm, rms {s.rms_cm:.3f} cm"
        )


def _refined_lines(what: str, csv_path: Path, table: PointTable, refined: Refined, photo: Path) -> list[str]:
    """What refining ``table``'s points on ``photo`` did: how many moved and how far, and each that did not."""
    from edge.calibration.refine import MAX_MOVE_PX

    found = refined.found.tolist()
    moved = sorted(m for m, f in zip(refined.moved_px.tolist(), found, strict=True) if f)
    lines = [
        f"{what} refined on {photo}: {len(moved)} of {len(found)} moved onto their targets' corners "
        f"(median move {moved[len(moved) // 2]:.2f} px, largest {moved[-1]:.2f} px)"
    ]
    for k in (k for k, f in enumerate(found) if not f):
        lines.append(
            f"NOT REFINED {csv_path} row {table.rows[k]} (line {table.lines[k]}): no target's corner within "
            f"{MAX_MOVE_PX:g} px of u,v = {table.uv_px[k, 0]:g},{table.uv_px[k, 1]:g} in {photo}; kept as measured"
        )
    return lines


def _print_check(result: CheckResult, calibration_json: Path, check_csv: Path) -> None:
    t = result.table
    click.echo(f"{'row':>4} {'u':>9} {'v':>9} {'x':>8} {'y':>8} {'mapped x':>9} {'mapped y':>9} {'error cm':>8}")
    for i in range(result.n):
        click.echo(
            f"{int(t.rows[i]):>4} {t.uv_px[i, 0]:>9.2f} {t.uv_px[i, 1]:>9.2f} {t.xy_world_cm[i, 0]:>8.2f} "
            f"{t.xy_world_cm[i, 1]:>8.2f} {result.mapped_cm[i, 0]:>9.2f} {result.mapped_cm[i, 1]:>9.2f} "
            f"{result.error_cm[i]:>8.3f}"
        )
    click.echo(
        f"{result.n} check points from {check_csv} against {calibration_json}: mean {result.mean_cm:.3f} cm, "
        f"max {result.max_cm:.3f} cm, rms {result.rms_cm:.3f} cm"
    )
