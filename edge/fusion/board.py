"""A camera board of several (``edge.publish = "detections"``): what ``edge-ips start`` needs to publish detections.

The board tracks as usual; instead of poses it publishes each frame's :class:`edge.fusion.detections.Detections`
on ``ips/v1/edge/<edge-id>/detections``, and its status lists the rovers it sees without calling the others missing
(most rovers of a large arena are in other boards' views; the fuser reports the ones nobody sees).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from edge.fusion.uncertainty import CalibrationErrorModel, DetectionBuilder, calibration_error_model
from edge.messages import STATUS_MAX_BYTES

if TYPE_CHECKING:
    from edge.config import EdgeConfig
    from edge.sources import SourceInfo
    from edge.trackers.base import PlaneMapping

_STATUS_FIXED_BYTES = 140  # the longest status without its lists of rovers is 131 bytes
_MAX_LISTED = 32  # the status contract's limit on each list


def detection_builder_for(
    config: EdgeConfig, calibration: PlaneMapping, info: SourceInfo, simulated: bool
) -> DetectionBuilder | None:
    """The builder of this board's detections, or None when it publishes poses (the single-camera default).

    A simulated camera's calibration is exact (no calibration error) and its view is not clipped to the paper's
    working area; a real one's error model comes from its calibration file."""
    if config.edge.publish != "detections":
        return None
    path = config.calibration.path
    errors = calibration_error_model(path) if path is not None and not simulated else CalibrationErrorModel()
    from edge.calibration.files import Calibration

    area = calibration.area_cm if isinstance(calibration, Calibration) and not simulated else None
    return DetectionBuilder(config.edge.id, calibration, errors, (info.width_px, info.height_px), area)


def listed_rovers(seen: Sequence[str]) -> list[str]:
    """The seen rovers a board's status can carry: at most 32, within the status's byte budget."""
    out: list[str] = []
    size = _STATUS_FIXED_BYTES
    for rover_id in seen:
        size += len(rover_id) + 3
        if len(out) >= _MAX_LISTED or size > STATUS_MAX_BYTES:
            break
        out.append(rover_id)
    return out
