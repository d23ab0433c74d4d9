"""The pictures of a closed-loop run, as the paper draws them (matplotlib, Agg backend, PNG).

* ``map.png``: the world map with each rover's true path (line) and what the edge measured (dots), start (o) and end
  (square) marks and the formation's tolerance zone in yellow (paper Figs. 28, 30, 32; Figs. 33, 35, 37 for the
  trajectory tests);
* ``snapshots.png``: the camera view at four frames with the tracker's estimates drawn on (Figs. 27, 29, 31);
* ``xy_time.png``: X and Y against time, truth and measurement (Figs. 34, 36, 38), and below, the formation's
  error against the bar (formations) or the IPS error (trajectories).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.plotting import ROVER_COLORS
from edge.sim.loop import LoopRecord
from edge.sim.metrics import polygon_sides_cm


def color(rover_id: str, k: int) -> str:
    return ROVER_COLORS.get(rover_id, f"C{k % 10}")


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_map(record: LoopRecord, metrics: dict[str, Any], out: Path) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.6, 7.2))
    ax.add_patch(plt.Rectangle((0, 0), AREA_WIDTH_CM, AREA_LENGTH_CM, fill=False, lw=1.0, ec="0.5", ls="--"))
    kind = record.config.kind
    final = record.truth[-1, :, :2]
    if kind == "line":
        x = float(final[:, 0].mean())
        tol = record.config.bar.tol_cm
        ax.axvspan(x - tol, x + tol, color="gold", alpha=0.6, lw=0, label=f"line +-{tol:g} cm")
    elif kind == "rendezvous":
        zone = record.config.bar.zone_cm
        cx, cy = final.mean(axis=0)
        ax.add_patch(plt.Circle((cx, cy), zone / 2, color="gold", alpha=0.6, lw=0, label=f"{zone:g} cm zone"))
    elif kind == "triangle":
        rel = final - final.mean(axis=0)
        ring = final[np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))]
        ax.add_patch(plt.Polygon(ring, closed=True, color="gold", alpha=0.6, lw=0, label="final triangle"))
        for (a, b), s in zip(zip(ring, np.roll(ring, -1, axis=0), strict=True), polygon_sides_cm(final), strict=True):
            ax.annotate(f"{s:.1f}", 0.5 * (a + b), fontsize=7, ha="center", va="center")
    for k, rid in enumerate(record.ids):
        c = color(rid, k)
        xy = record.truth[:, k, :2]
        ax.plot(xy[:, 0], xy[:, 1], "-", color=c, lw=1.2, label=f"{rid} truth")
        m = record.measured[:, k, :2]
        ax.plot(m[::3, 0], m[::3, 1], ".", color=c, ms=2.0, alpha=0.6)
        ax.plot(xy[0, 0], xy[0, 1], "o", mfc="none", mec=c, ms=8)
        ax.plot(xy[-1, 0], xy[-1, 1], "s", color=c, ms=6)
    ax.set_xlim(-20, AREA_WIDTH_CM + 20)
    ax.set_ylim(-20, AREA_LENGTH_CM + 20)
    ax.set_aspect("equal")
    ax.set_xlabel("x (cm)")
    ax.set_ylabel("y (cm)")
    ax.set_title(_title(record, metrics), fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _title(record: LoopRecord, metrics: dict[str, Any]) -> str:
    kind = record.config.kind
    head = f"{kind}, seed {record.config.seed}: "
    if kind == "line":
        f = metrics["final"]
        gaps = ", ".join(f"{g:.1f}" for g in f["gaps_cm"])
        body = f"off line <= {f['line_displacement_cm']:.1f} cm, gaps {gaps} cm"
    elif kind == "rendezvous":
        body = f"zone {metrics['final']['zone_diameter_cm']:.1f} cm"
    elif kind == "triangle":
        body = "sides " + ", ".join(f"{s:.1f}" for s in metrics["final"]["sides_cm"]) + " cm"
    else:
        e = metrics["ips_error_cm"]
        return head + f"IPS error mean {e['mean']:.2f} cm, max {e['max']:.2f} cm (dots: measured)"
    conv = metrics.get("converged_frame")
    when = f"converged at frame {conv}" if conv is not None else "not converged"
    return head + body + f"\n{when}; closest centres {metrics['min_centre_distance_cm']:.1f} cm"


def snapshot_frames(record: LoopRecord, converged: int | None) -> list[int]:
    """Four stored frames: the start, two on the way, and the convergence frame (or the last one)."""
    stored = sorted(record.snapshots)
    if not stored:
        return []
    end = converged if converged is not None else stored[-1]
    wanted = [0, end / 3, 2 * end / 3, end]
    picks: list[int] = []
    for w in wanted:
        best = min(stored, key=lambda s: (abs(s - w), -s))
        if best not in picks:
            picks.append(best)
    return picks


def draw_snapshots(record: LoopRecord, metrics: dict[str, Any], out: Path) -> None:
    plt = _pyplot()
    frames = snapshot_frames(record, metrics.get("converged_frame"))
    cols = 2
    rows = max(1, math.ceil(len(frames) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(10, 3.0 * rows))
    for ax in np.ravel(axes):
        ax.axis("off")
    for ax, k in zip(np.ravel(axes), frames, strict=False):
        image = record.snapshots[k]
        ax.imshow(image[:, :, ::-1])
        for j, (rid, u, v) in enumerate(record.overlays.get(k, [])):
            ax.plot(u / 2, v / 2, "+", color="white", ms=12, mew=2)
            ax.text(u / 2 + 8, v / 2 - 8, rid, color=color(rid, j), fontsize=8, weight="bold")
        ax.set_title(f"n = {k}", fontsize=9)
    fig.suptitle(f"{record.config.kind}, seed {record.config.seed}: the camera view (+: the tracker's estimate)")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)


def draw_xy_time(record: LoopRecord, metrics: dict[str, Any], out: Path, errors: list[float] | None) -> None:
    plt = _pyplot()
    t = np.arange(len(record.truth)) / record.fps
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 7.5), sharex=True)
    for k, rid in enumerate(record.ids):
        c = color(rid, k)
        for ax, dim, name in ((axes[0], 0, "X (cm)"), (axes[1], 1, "Y (cm)")):
            ax.plot(t, record.truth[:, k, dim], "-", color=c, lw=1.0, label=f"{rid} truth")
            ax.plot(t[::2], record.measured[::2, k, dim], ".", color=c, ms=1.6, alpha=0.7)
            ax.set_ylabel(name)
    axes[0].legend(fontsize=7, ncol=3)
    ax = axes[2]
    if errors is not None:
        bar = record.config.bar
        unit = "zone diameter - 40 cm" if record.config.kind == "rendezvous" else f"worst error - {bar.tol_cm:g} cm"
        ax.plot(t, errors, "k-", lw=1.0)
        ax.axhline(0.0, color="gold", lw=2)
        ax.set_ylabel(f"bar ({unit})", fontsize=8)
        ax.set_yscale("symlog", linthresh=5.0)
        conv = metrics.get("converged_frame")
        if conv is not None:
            ax.axvline(conv / record.fps, color="tab:green", ls="--", lw=1, label=f"converged, frame {conv}")
        ax.axvline(bar.within_frames / record.fps, color="0.5", ls=":", lw=1, label=f"frame {bar.within_frames}")
        ax.legend(fontsize=7)
    else:
        d = np.hypot(*(record.measured[:, :, :2] - record.truth[:, :, :2]).transpose(2, 0, 1))
        for k, rid in enumerate(record.ids):
            ax.plot(t, d[:, k], "-", color=color(rid, k), lw=0.8)
        ax.set_ylabel("IPS error (cm)")
    ax.set_xlabel("time (s)")
    fig.suptitle(f"{record.config.kind}, seed {record.config.seed}: X and Y against time (line: truth, dots: IPS)")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


def draw_all(record: LoopRecord, metrics: dict[str, Any], out_dir: Path, errors: list[float] | None) -> list[Path]:
    """Every figure of a run into ``out_dir``; returns the paths."""
    paths = [out_dir / "map.png", out_dir / "snapshots.png", out_dir / "xy_time.png"]
    draw_map(record, metrics, paths[0])
    draw_snapshots(record, metrics, paths[1])
    draw_xy_time(record, metrics, paths[2], errors)
    return paths
