"""What a closed-loop run leaves behind: ``metrics.json``, ``truth.csv``, ``poses.jsonl``, ``motors.csv``.

``truth.csv`` (``frame,id,x,y,theta``) and ``poses.jsonl`` (every pose published to the rovers, the exact bytes, one
per line) are enough to recompute every figure of ``metrics.json``; ``motors.csv`` (``t_ms,id,left_duty,
left_forward,right_duty,right_forward,halt,own_seq``, one row per firmware step; ``own_seq``: the seq of the newest
pose of its own the rover had, empty before the first) lets anyone check the safety bar and how old the poses were
that the rovers drove on.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from edge.errors import SimulationError
from edge.messages import parse_pose
from edge.sim.loop import LoopRecord
from edge.sim.metrics import (
    converged_frame,
    enclosing_diameter_cm,
    error_stats_cm,
    formation_error,
    line_errors,
    min_body_gap_cm,
    min_centre_distance_cm,
    polygon_sides_cm,
)
from edge.sim.rover import BODY_LENGTH_CM, BODY_WIDTH_CM, max_wheel_speed_cm_s, rover_config


def formation_errors(record: LoopRecord) -> list[float]:
    """The bar's error (<= 0: holds) at every frame, on the ground truth."""
    bar = record.config.bar
    return [formation_error(bar, record.truth[k, :, :2]) for k in range(len(record.truth))]


def shape(kind: str, xy_cm: np.ndarray) -> dict[str, Any]:
    """The formation's own numbers for one frame."""
    if kind == "line":
        displacement, _, gaps = line_errors(xy_cm)
        return {"line_x_cm": float(xy_cm[:, 0].mean()), "line_displacement_cm": displacement, "gaps_cm": gaps.tolist()}
    if kind == "rendezvous":
        return {"zone_diameter_cm": enclosing_diameter_cm(xy_cm)}
    if kind == "triangle":
        return {"sides_cm": polygon_sides_cm(xy_cm).tolist()}
    return {}


def ips_errors_cm(record: LoopRecord) -> np.ndarray:
    """Distance between every published pose and the truth at its frame, cm."""
    index = {rid: k for k, rid in enumerate(record.ids)}
    out = []
    for frame, rid, payload in record.published:
        pose = parse_pose(payload)
        tx, ty = record.truth[frame, index[rid], :2]
        out.append(math.hypot(pose.x - tx, pose.y - ty))
    return np.asarray(out)


YOUNG_BAR_MS = 500  # no rover may drive on a pose of its own older than this since its frame was captured


def _frames(record: LoopRecord) -> dict[tuple[str, int], int]:
    """(rover id, seq) -> the frame of every pose published."""
    return {(rid, parse_pose(payload).seq): frame for frame, rid, payload in record.published}


def young_arrivals(record: LoopRecord, rover_id: str) -> list[int]:
    """When (simulated ms, the firmware step) a rover took a new pose of its own that was *young*: it arrived at most
    ``stale_ms`` later than the fastest capture-to-arrival of the run. A pose that waited on the air (a backlog after
    an outage) arrives, but is not fresh: the firmware dates it by its capture time and does not drive on it."""
    log = record.motors.get(rover_id)
    if log is None:
        return []
    frame_of = _frames(record)
    arrivals: list[tuple[int, float]] = []
    last = None
    for t, seq in zip(log.t_ms, log.own_seq, strict=True):
        if seq is not None and seq != last and (rover_id, seq) in frame_of:
            arrivals.append((t, t - frame_of[(rover_id, seq)] * 1000.0 / record.fps))
        last = seq
    if not arrivals:
        return []
    fastest = min(age for _, age in arrivals)
    stale_ms = rover_config(rover_id)["control"]["stale_ms"]
    return [t for t, age in arrivals if age - fastest <= stale_ms]


def safety(record: LoopRecord) -> dict[str, Any] | None:
    """After the camera feed stopped or the broker died: for each rover, its last fresh (young) own pose (simulated
    ms of the step that took it), when its motors were cut for good (both duties 0 from then on), and when its body
    came to rest (ground truth)."""
    cfg = record.config
    stop_frame = min(f for f in (cfg.feed_stop_frame, cfg.broker_stop_frame, len(record.truth)) if f is not None)
    if stop_frame >= len(record.truth) or not record.motors:
        return None
    t_stop_ms = stop_frame * 1000.0 / record.fps
    rovers: dict[str, Any] = {}
    for k, rid in enumerate(record.ids):
        log = record.motors[rid]
        fresh = young_arrivals(record, rid)
        last_fresh = fresh[-1] if fresh else 0
        duty = np.asarray(log.left_duty) + np.asarray(log.right_duty)
        t = np.asarray(log.t_ms)
        running = np.flatnonzero(duty > 0)
        off_ms = int(t[running[-1] + 1]) if running.size and running[-1] + 1 < len(t) else None
        if not running.size:
            off_ms = int(t[0])
        driving_at_stop = bool(np.any((duty > 0) & (t <= t_stop_ms) & (t >= t_stop_ms - 100)))
        xy = record.truth[:, k, :2]
        moved = np.flatnonzero(np.hypot(*np.diff(xy, axis=0).T) > 0.01)
        rest_ms = (moved[-1] + 1) * 1000.0 / record.fps if moved.size else 0.0
        rovers[rid] = {
            "last_fresh_pose_ms": last_fresh,
            "driving_when_stopped": driving_at_stop,
            "motors_off_ms": off_ms,
            "motors_off_after_ms": None if off_ms is None else max(0, off_ms - last_fresh),
            "at_rest_ms": rest_ms,
            "at_rest_after_ms": max(0.0, rest_ms - last_fresh),
            "halt": log.halt[-1] if log.halt else None,
        }
    worst = [r["motors_off_after_ms"] for r in rovers.values()]
    return {
        "event": "feed stopped" if cfg.feed_stop_frame == stop_frame else "broker killed",
        "event_frame": stop_frame,
        "event_ms": t_stop_ms,
        "rovers": rovers,
        "motors_off_after_ms_max": None if None in worst else max(worst),
        "bar_ms": 500,
        "passed": None not in worst and max(w for w in worst if w is not None) <= 500,
    }


def stale_stops(record: LoopRecord, bar_ms: int = 500) -> list[dict[str, Any]]:
    """Every time a rover went without a fresh (young: :func:`young_arrivals`) pose of its own for longer than its
    stale bound (an outage and the backlog after it, a long retransmission, the feed or the broker gone): when its
    motors were cut for good and its body came to rest, counted from its last fresh pose, and when it drove again
    after the next one (None: the run ended first).

    Times are simulated ms; ``passed``: motors off and body at rest within ``bar_ms`` of the last fresh pose."""
    out: list[dict[str, Any]] = []
    for k, rid in enumerate(record.ids):
        log = record.motors.get(rid)
        fresh = young_arrivals(record, rid)
        if log is None or not fresh:
            continue
        stale_ms = stale_bound_ms(rid)
        t = np.asarray(log.t_ms)
        duty = np.asarray(log.left_duty) + np.asarray(log.right_duty)
        driving = np.isin(np.asarray(log.halt), ("none", "probe"))
        end_ms = int(t[-1])
        frame_ms = np.arange(len(record.truth)) * 1000.0 / record.fps
        moved = np.r_[False, np.hypot(*np.diff(record.truth[:, k, :2], axis=0).T) > 0.01]
        for last, following in zip(fresh, [*fresh[1:], None], strict=True):
            until = following if following is not None else end_ms
            if until - last <= stale_ms:
                continue
            during = (t >= last) & (t < until)
            running = np.flatnonzero(during & (duty > 0))
            off_ms = int(t[running[-1] + 1]) if running.size else last
            motion = np.flatnonzero(moved & (frame_ms >= last) & (frame_ms < until))
            rest_ms = float(frame_ms[motion[-1]]) if motion.size else float(last)
            rejoin = None
            if following is not None:
                again = np.flatnonzero((t >= following) & driving)
                rejoin = int(t[again[0]]) - following if again.size else None
            observed = until - last >= bar_ms + 100  # long enough to see the body come to rest
            out.append(
                {
                    "rover": rid,
                    "last_fresh_ms": last,
                    "next_fresh_ms": following,
                    "without_pose_ms": until - last,
                    "driving_before": bool(np.any((duty > 0) & (t <= last) & (t > last - 100))),
                    "motors_off_after_ms": off_ms - last,
                    "at_rest_after_ms": rest_ms - last,
                    "drove_again_after_ms": rejoin,
                    "passed": off_ms - last <= bar_ms and (not observed or rest_ms - last <= bar_ms),
                }
            )
    return out


def driven_pose_age_ms(record: LoopRecord) -> dict[str, Any]:
    """How old (since its frame was captured) the newest pose of its own was at every control step in which a rover
    drove: a pose that waited on the air (a retransmission, the backlog after an outage) arrives recently but old,
    and the firmware must judge it by its age. Stats over all rovers and steps, ms."""
    frame_of = _frames(record)
    ages: list[float] = []
    for rid, log in record.motors.items():
        for t, seq, halt, left, right in zip(
            log.t_ms, log.own_seq, log.halt, log.left_duty, log.right_duty, strict=True
        ):
            if seq is not None and halt in ("none", "probe") and left + right > 0 and (rid, seq) in frame_of:
                ages.append(t - frame_of[(rid, seq)] * 1000.0 / record.fps)
    return error_stats_cm(ages)


def stale_bound_ms(rover_id: str) -> int:
    """How long a rover may go without a fresh pose of its own before its firmware cuts the motors: ``stale_ms``,
    checked once a control period."""
    control = rover_config(rover_id)["control"]
    return int(control["stale_ms"]) + int(control["period_ms"])


def link_summary(record: LoopRecord, bar_ms: int = 500) -> dict[str, Any]:
    """What the rovers' Wi-Fi links did: the settings, each rover's outages, pose delays on the air (from the
    broker to the rover's socket, head-of-line waits included), poses lost with a connection, connections made,
    and the stops for want of a fresh pose (:func:`stale_stops`), each outage with the stop it caused.

    An outage longer than the stale bound that began at least ``bar_ms`` + 100 ms before the run ended *must* stop
    its rover; ``stops_passed`` says every such outage did, and every stop came within ``bar_ms``."""
    stops = stale_stops(record, bar_ms)
    rovers: dict[str, Any] = {}
    must_stop = stopped = rejoined = 0
    for rid in record.ids:
        log = record.links.get(rid)
        if log is None:
            continue
        bound = stale_bound_ms(rid)
        end_of_run = record.motors[rid].t_ms[-1] if record.motors.get(rid) and record.motors[rid].t_ms else 0
        outages = []
        for o in record.outages.get(rid, []):
            start_ms, end_ms = 1000.0 * o.start_s, 1000.0 * o.end_s
            stop = next(
                (
                    s
                    for s in stops
                    if s["rover"] == rid
                    and s["last_fresh_ms"] <= start_ms + 200.0  # its last pose may still be on the air
                    and (s["next_fresh_ms"] is None or s["next_fresh_ms"] >= end_ms)
                ),
                None,
            )
            must = end_ms - start_ms > bound and start_ms + bar_ms + 100 < end_of_run
            if must:
                must_stop += 1
                if stop is not None:
                    stopped += stop["passed"]
                    rejoined += stop["next_fresh_ms"] is None or stop["drove_again_after_ms"] is not None
            outages.append(
                {
                    "start_ms": round(start_ms),
                    "duration_ms": round(end_ms - start_ms),
                    "dropped": o.dropped,
                    "must_stop": must,
                    "stop": stop,
                }
            )
        rovers[rid] = {
            "outages": outages,
            "pose_delay_ms": error_stats_cm(1000.0 * np.asarray(log.pose_delays_s)),
            "poses_retransmitted": log.poses_retransmitted,
            "poses_lost": log.poses_lost,
            "connections": log.connections,
        }
    return {
        "settings": str(record.config.link),
        "driven_pose_age_ms": driven_pose_age_ms(record),
        "rovers": rovers,
        "stale_stops": stops,
        "outages_must_stop": must_stop,
        "outages_stopped_in_time": stopped,
        "outages_rejoined": rejoined,
        "stops_passed": all(s["passed"] for s in stops) and stopped == must_stop,
    }


def link_line(link: dict[str, Any]) -> str:
    """One line about the links of a run, for the CLI."""
    outages = [o for r in link["rovers"].values() for o in r["outages"]]
    stops = link["stale_stops"]
    worst = max((s["motors_off_after_ms"] for s in stops), default=None)
    lost = sum(r["poses_lost"] for r in link["rovers"].values())
    text = f"link {link['settings']}: {len(outages)} outages, {lost} poses lost with a connection"
    if stops:
        verdict = "within" if link["stops_passed"] else "NOT within"
        text += f"; {len(stops)} stops for want of a pose, motors off after {worst} ms at worst ({verdict} 0.5 s)"
    return text


def summarize(record: LoopRecord) -> dict[str, Any]:
    """metrics.json of one run."""
    cfg = record.config
    truth = record.truth
    n_frames = len(truth)
    cfg0 = rover_config(record.ids[0])
    centre = [min_centre_distance_cm(truth[k, :, :2]) for k in range(n_frames)]
    gaps = [min_body_gap_cm(truth[k], BODY_LENGTH_CM, BODY_WIDTH_CM) for k in range(n_frames)]
    missed = {
        rid: int(np.isnan(record.measured[: record.frames_tracked, k, 0]).sum()) for k, rid in enumerate(record.ids)
    }
    out: dict[str, Any] = {
        "experiment": cfg.kind,
        "seed": cfg.seed,
        "rovers": list(record.ids),
        "frames": n_frames,
        "fps": record.fps,
        "heading_marker": cfg.heading,
        "latency_ms": cfg.latency_ms,
        "rover": {
            "track_cm": cfg0["geometry"]["track_cm"],
            "wheel_radius_cm": cfg0["geometry"]["wheel_radius_cm"],
            "max_wheel_speed_cm_s": max_wheel_speed_cm_s(cfg0),
            "body_cm": [BODY_LENGTH_CM, BODY_WIDTH_CM],
            "body_radius_cm": cfg0["geometry"]["body_radius_cm"],
            "safety_cm": cfg0["control"]["safety_cm"],
            "max_speed_cm_s": cfg0["control"]["max_speed_cm_s"],
            "stale_ms": cfg0["control"]["stale_ms"],
            "fade_ms": cfg0["control"]["fade_ms"],
        },
        "starts": truth[0].round(2).tolist(),
        "min_centre_distance_cm": float(min(centre)),
        "min_body_gap_cm": float(min(gaps)),
        "collision": bool(min(gaps) <= 0.0),
        "ips_error_cm": error_stats_cm(ips_errors_cm(record)),
        "messages": {
            "frames_tracked": record.frames_tracked,
            "poses_published": len(record.published),
            "poses_dropped": record.poses_dropped,
            "tracker_missed": missed,
            "deliveries_late": dict(record.deliveries_late),
        },
        "wall_s": round(record.wall_s, 2),
    }
    if cfg.formation:
        bar = cfg.bar
        errors = formation_errors(record)
        conv = converged_frame(errors)
        out["formation"] = record.formation
        out["bar"] = {
            "tolerance_cm": bar.tol_cm,
            "spacing_cm": bar.spacing_cm if cfg.kind == "line" else None,
            "side_cm": bar.side_cm if cfg.kind == "triangle" else None,
            "zone_cm": bar.zone_cm if cfg.kind == "rendezvous" else None,
            "within_frames": bar.within_frames,
        }
        out["converged_frame"] = conv
        out["converged_s"] = None if conv is None else conv / record.fps
        out["final"] = shape(cfg.kind, truth[-1, :, :2])
        out["final_beyond_bar_cm"] = errors[-1]  # how far the last frame is from the bar: <= 0 holds
        out["passed"] = {
            "formation": conv is not None,
            "within_frames": conv is not None and conv <= bar.within_frames,
            "no_collision": not out["collision"],
        }
    if record.plans is not None:
        out["plans_s"] = {rid: p.duration_s for rid, p in record.plans.items()}
    s = safety(record)
    if s is not None:
        out["safety"] = s
    if record.links:
        out["link"] = link_summary(record)
        if "passed" in out:
            out["passed"]["stops_in_time"] = out["link"]["stops_passed"]
            oldest = out["link"]["driven_pose_age_ms"]["max"]
            out["passed"]["young_poses"] = oldest is None or oldest <= YOUNG_BAR_MS
    return out


def write_run(record: LoopRecord, out_dir: Path) -> dict[str, Any]:
    """Write truth.csv, poses.jsonl, motors.csv and metrics.json into ``out_dir``; returns the metrics."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with (out_dir / "truth.csv").open("w") as f:
        f.write("frame,id,x,y,theta\n")
        for k in range(len(record.truth)):
            for j, rid in enumerate(record.ids):
                x, y, th = record.truth[k, j]
                f.write(f"{k},{rid},{x:.3f},{y:.3f},{th:.5f}\n")
    with (out_dir / "poses.jsonl").open("wb") as fb:
        for _, _, payload in record.published:
            fb.write(payload + b"\n")
    with (out_dir / "motors.csv").open("w") as f:
        f.write("t_ms,id,left_duty,left_forward,right_duty,right_forward,halt,own_seq\n")
        for rid, log in record.motors.items():
            for row in zip(
                log.t_ms,
                log.left_duty,
                log.left_forward,
                log.right_duty,
                log.right_forward,
                log.halt,
                log.own_seq,
                strict=True,
            ):
                t, ld, lf, rd, rf, halt, seq = row
                f.write(f"{t},{rid},{ld},{int(lf)},{rd},{int(rf)},{halt},{'' if seq is None else seq}\n")
    metrics = summarize(record)
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


def run_to_directory(
    config: Any,
    out_dir: Path,
    *,
    video: bool = False,
    figures: bool = True,
    progress: Any = None,
) -> dict[str, Any]:
    """Run one experiment (:class:`edge.sim.loop.LoopConfig`) and write everything it produces into ``out_dir``:
    the files of :func:`write_run`, the figures and, with ``video``, ``camera.mp4`` (the annotated camera view)."""
    from edge.sim.figures import draw_all
    from edge.sim.loop import FPS, run

    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SimulationError(f"{out_dir}: cannot create the output directory ({exc.strerror})") from None
    writer: Any = None
    sink = None
    if video:
        import cv2

        def sink(image: np.ndarray) -> None:
            nonlocal writer
            if writer is None:
                fourcc = cv2.VideoWriter_fourcc(*"mp4v")  # type: ignore[attr-defined]
                writer = cv2.VideoWriter(str(out_dir / "camera.mp4"), fourcc, FPS, (image.shape[1], image.shape[0]))
            writer.write(image)

    try:
        record = run(config, progress=progress, video=sink)
    finally:
        if writer is not None:
            writer.release()
    metrics = write_run(record, out_dir)
    if figures:
        draw_all(record, metrics, out_dir, formation_errors(record) if config.formation else None)
    return metrics
