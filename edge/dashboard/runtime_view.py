"""What the dashboard reads from the running appliance: a small protocol, so that the dashboard does not depend on
:class:`edge.runtime.EdgeRuntime` (which implements it) and the runtime knows nothing of the dashboard."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from edge.metrics import Snapshot
    from edge.sources import SourceInfo
    from edge.tracking import Frame, FrameResult


class RuntimeView(Protocol):
    """The newest results and figures of the tracker, read (never written) by the dashboard's threads."""

    @property
    def edge_id(self) -> str: ...

    @property
    def info(self) -> SourceInfo:
        """What the source delivers (image size)."""
        ...

    @property
    def latest_result(self) -> FrameResult | None:
        """The newest tracked frame's result (None before the first)."""
        ...

    @property
    def last_frame(self) -> Frame | None:
        """The frame :attr:`latest_result` came from."""
        ...

    def newest_frame(self) -> Frame | None:
        """The newest captured frame, tracked or not (None before the first)."""
        ...

    def snapshot(self) -> Snapshot:
        """Status and figures now (the status event)."""
        ...

    def wait_tracked(self, timeout_s: float) -> None:
        """Block until the tracker has finished its next frame (or ``timeout_s``)."""
        ...

    def camera_state(self) -> str:
        """The camera's state now ("ok", "stalled", ...)."""
        ...

    @property
    def tracker(self) -> object:
        """The tracker in use (enrolment reads its background model)."""
        ...
