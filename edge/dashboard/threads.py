"""The dashboard's threads run at background priority: :func:`edge.priority.background_priority` (shared with the
HTTP server's threads)."""

from __future__ import annotations

from edge.priority import BACKGROUND_NICE, background_priority

__all__ = ["BACKGROUND_NICE", "background_priority"]
