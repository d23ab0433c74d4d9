"""Trajectory plots of pose JSON lines, as the paper's Figs. 33-38 (``edge-ips plot``).

One figure: the X-Y map of every rover over the working area (Figs. 33, 35, 37), and X and Y against time per
rover (Figs. 34, 36, 38). matplotlib with the Agg backend (no display needed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.errors import ConfigError, MessageError
from edge.messages import parse_pose

ROVER_COLORS = {  # matplotlib colours for the usual rover ids (marker colours)
    "red": "tab:red",
    "green": "tab:green",
    "blue": "tab:blue",
    "yellow": "goldenrod",
    "orange": "tab:orange",
    "purple": "tab:purple",
    "magenta": "m",
    "cyan": "c",
    "pink": "tab:pink",
    "brown": "tab:brown",
}


@dataclass
class Trajectory:
    """One rover's poses in file order: time (s), x, y (cm)."""

    t: list[float] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)


def read_trajectories(path: Path) -> dict[str, Trajectory]:
    """Pose v1 JSON lines, or the poses of a recording (``edge-ips start --record DIR``: give the directory) ->
    trajectory per rover id. A bad line is an error naming the file and line."""
    if path.is_dir():
        lines = _recorded_poses(path)
    else:
        try:
            lines = path.read_bytes().splitlines()
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read poses ({exc.strerror})") from exc
    out: dict[str, Trajectory] = {}
    for number, raw in enumerate(lines, start=1):
        if not raw.strip():
            continue
        try:
            pose = parse_pose(raw.strip())
        except MessageError as exc:
            raise MessageError(f"{path}: line {number}: {exc}") from exc
        tr = out.setdefault(pose.id, Trajectory())
        tr.t.append(pose.t)
        tr.x.append(pose.x)
        tr.y.append(pose.y)
    if not out:
        raise ConfigError(f"{path}: no poses to plot")
    return out


def _recorded_poses(directory: Path) -> list[bytes]:
    """The pose payloads of a recording directory, in the order they were published."""
    import json

    from edge.recording import read_recording

    return [
        json.dumps(record["payload"], separators=(",", ":")).encode()
        for record in read_recording(directory)
        if str(record.get("topic", "")).endswith("/pose") and isinstance(record.get("payload"), dict)
    ]


def plot_trajectories(trajectories: dict[str, Trajectory], out: Path, title: str | None = None) -> None:
    """Write the X-Y map and the X(t), Y(t) panels to ``out`` (PNG, PDF or SVG by suffix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 7), constrained_layout=True)
    grid = fig.add_gridspec(2, 2, width_ratios=(1, 1.4))
    ax_map = fig.add_subplot(grid[:, 0])
    ax_x = fig.add_subplot(grid[0, 1])
    ax_y = fig.add_subplot(grid[1, 1], sharex=ax_x)
    t0 = min(min(tr.t) for tr in trajectories.values() if tr.t)
    ax_map.add_patch(
        matplotlib.patches.Rectangle((0, 0), AREA_WIDTH_CM, AREA_LENGTH_CM, fill=False, ls="--", color="0.5")
    )
    for rover_id, tr in sorted(trajectories.items()):
        color: Any = ROVER_COLORS.get(rover_id)
        t = np.asarray(tr.t) - t0
        x, y = np.asarray(tr.x), np.asarray(tr.y)
        # Break lines where the rover was missing for more than half a second.
        gaps = np.flatnonzero(np.diff(t) > 0.5) + 1
        for k, (ts, xs, ys) in enumerate(zip(np.split(t, gaps), np.split(x, gaps), np.split(y, gaps), strict=True)):
            label = rover_id if k == 0 else None
            (line,) = ax_map.plot(xs, ys, lw=1.2, color=color, label=label)
            color = line.get_color()
            ax_x.plot(ts, xs, lw=1.0, color=color)
            ax_y.plot(ts, ys, lw=1.0, color=color)
        ax_map.plot(x[:1], y[:1], "o", color=color, ms=5)
        ax_map.plot(x[-1:], y[-1:], "s", color=color, ms=5)
    ax_map.set_xlim(-20, AREA_WIDTH_CM + 20)
    ax_map.set_ylim(-20, AREA_LENGTH_CM + 20)
    ax_map.set_aspect("equal")
    ax_map.set_xlabel("X (cm)")
    ax_map.set_ylabel("Y (cm)")
    ax_map.set_title("X-Y map (o start, s end)")
    ax_map.legend(loc="upper right", fontsize="small")
    ax_x.set_ylabel("X (cm)")
    ax_y.set_ylabel("Y (cm)")
    ax_y.set_xlabel("time (s)")
    ax_x.set_title("X and Y against time")
    for ax in (ax_map, ax_x, ax_y):
        ax.grid(True, lw=0.3)
    if title:
        fig.suptitle(title)
    try:
        fig.savefig(out, dpi=110)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{out}: cannot write plot ({exc})") from exc
    finally:
        plt.close(fig)


def plot_poses(poses: Path, out: Path, title: str | None = None) -> dict[str, int]:
    """Read ``poses`` and write the plot to ``out``; returns the number of poses per rover."""
    trajectories = read_trajectories(poses)
    plot_trajectories(trajectories, out, title)
    return {k: len(v.t) for k, v in sorted(trajectories.items())}
