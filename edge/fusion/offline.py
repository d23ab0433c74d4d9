"""``edge-ips fuse DET1.jsonl DET2.jsonl ... --out poses.jsonl``: the fusion over recorded detections.

Each file is one board's detections v1 lines (``edge-ips track --detections``, or a recording of the topic). The
first file's clock is the reference. The boards' clock offsets are estimated over the whole recording first (two
passes, the second interpolating with the first's estimates), then every frame is fused in the order of its
corrected capture time, as the live fuser does on arrival. The output is one pose v1 line per rover per frame of
the shared clock (``frame`` = ``round(t * fps)`` of the reference clock, ``t`` the frame's instant: the live fuser
dates its poses at their newest capture instant instead).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from edge.board_messages import parse_detections
from edge.errors import ConfigError, MessageError
from edge.fusion.clock import ClockAligner, OffsetEstimate
from edge.fusion.core import FusedPose, Fuser, FusionSettings, FusionStatus
from edge.fusion.detections import Detections, from_message
from edge.messages import encode_pose


@dataclass
class FuseSummary:
    """What a run of the offline fusion did."""

    frames: int = 0  # detections messages read
    poses: int = 0
    per_rover: dict[str, int] = field(default_factory=dict)
    offsets: dict[str, OffsetEstimate] = field(default_factory=dict)
    pair_samples: dict[tuple[str, str], int] = field(default_factory=dict)
    status: FusionStatus | None = None

    def as_dict(self) -> dict[str, object]:
        boards = self.status.boards if self.status is not None else ()
        return {
            "frames": self.frames,
            "poses": self.poses,
            "per_rover": self.per_rover,
            "boards": {
                b.edge_id: {
                    "frames": b.frames,
                    "offset_ms": round(1e3 * self.offsets[b.edge_id].offset_s, 3)
                    if b.edge_id in self.offsets
                    else None,
                    "offset_sigma_ms": round(1e3 * self.offsets[b.edge_id].sigma_s, 3)
                    if b.edge_id in self.offsets
                    else None,
                    "offset_source": self.offsets[b.edge_id].source if b.edge_id in self.offsets else None,
                    "refused": b.refused,
                    "late": b.late,
                }
                for b in boards
            },
            "overlap_comparisons": {f"{a}/{b}": n for (a, b), n in self.pair_samples.items()},
        }


def read_detections(path: Path) -> list[Detections]:
    """Every detections v1 line of ``path``; a line that breaks the contract is an error naming the file and line."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read detections ({exc.strerror})") from exc
    out = []
    for number, line in enumerate(raw.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            out.append(from_message(parse_detections(line.strip())))
        except MessageError as exc:
            raise MessageError(f"{path}:{number}: {exc}") from None
    if not out:
        raise ConfigError(f"{path}: no detections in the file")
    return out


def estimate_offsets(boards: Sequence[Sequence[Detections]], settings: FusionSettings, passes: int = 2) -> ClockAligner:
    """A :class:`ClockAligner` trained over the whole recording, the first board's clock the reference."""
    reference = boards[0][0].edge_id
    clock = replace(settings.clock, compare_every_s=0.0, solve_every_s=0.0)  # offline there is time for all of it
    aligner = ClockAligner(clock, reference)
    for k in range(passes):
        previous = {b: e.offset_s for b, e in aligner.estimates().items()}
        # the first pass learns as it goes; the next compare the tracks at the last pass's estimates throughout
        aligner = ClockAligner(clock, reference, previous if k > 0 else None)
        for d in sorted(
            (d for frames in boards for d in frames), key=lambda d: d.t_capture_s - previous.get(d.edge_id, 0.0)
        ):
            aligner.observe(d)
    return aligner


def _corrected(d: Detections, offsets: dict[str, OffsetEstimate]) -> float:
    est = offsets.get(d.edge_id)
    return d.t_capture_s - (est.offset_s if est is not None else 0.0)


def fuse_files(
    paths: Sequence[Path],
    out: Path,
    settings: FusionSettings | None = None,
    on_pose: Callable[[FusedPose], None] | None = None,
) -> FuseSummary:
    """Fuse the detections in ``paths`` (one board each) into pose v1 lines in ``out``."""
    # a recording's poses are a series on the shared clock's frames (live ones are at their capture instants)
    settings = replace(settings or FusionSettings(), pose_time="frame")
    if not paths:
        raise ConfigError("give at least one detections file")
    boards = [read_detections(p) for p in paths]
    owners: dict[str, Path] = {}
    for path, frames in zip(paths, boards, strict=True):
        for edge_id in {d.edge_id for d in frames}:
            if edge_id in owners:
                raise ConfigError(f"{path}: board {edge_id!r} is also in {owners[edge_id]} (one board per file)")
            owners[edge_id] = path
    aligner = estimate_offsets(boards, settings)
    offsets = aligner.estimates()
    fuser = Fuser(settings, aligner=aligner, learn_offsets=False)
    summary = FuseSummary(offsets=offsets, pair_samples=aligner.pair_samples())
    seq: dict[str, int] = {}
    ordered = sorted((d for frames in boards for d in frames), key=lambda d: _corrected(d, offsets))
    try:
        handle = out.open("wb")
    except OSError as exc:
        raise ConfigError(f"{out}: cannot write poses ({exc.strerror})") from exc
    with handle:
        for d in ordered:
            summary.frames += 1
            for pose in fuser.add(d):
                n = seq.get(pose.rover_id, 0)
                seq[pose.rover_id] = n + 1
                handle.write(pose_line(pose, n) + b"\n")
                summary.poses += 1
                summary.per_rover[pose.rover_id] = summary.per_rover.get(pose.rover_id, 0) + 1
                if on_pose is not None:
                    on_pose(pose)
    summary.status = fuser.status()
    return summary


def pose_line(pose: FusedPose, seq: int) -> bytes:
    """The pose v1 bytes of a fused pose (``frame`` is the shared clock's frame index)."""
    return encode_pose(
        pose.rover_id,
        seq,
        pose.tick,
        max(pose.t_s, 0.0),
        pose.x_cm,
        pose.y_cm,
        pose.theta_rad,
        pose.vx_cm_s,
        pose.vy_cm_s,
        pose.quality,
    )


def summary_json(summary: FuseSummary) -> str:
    return json.dumps(summary.as_dict())
