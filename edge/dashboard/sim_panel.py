"""The dashboard's simulator panel: scatter the rovers and cause faults, when the frame source is a simulated lab
that offers them (``--source sim:twin``); nothing is served otherwise.

Routes (access levels of :mod:`edge.httpguard`):

- ``GET /api/sim`` (read): the faults on offer (``offered``), the lab's rovers (switched on, connected, moving: the
  lab's ground truth), the faults in effect (``active``) and what happened lately (``events``: each fault, and how
  long each rover took to come to rest after it; ``?after=N``: only those after event N), this edge's camera
  (``camera``) and every camera of the lab (``cameras``: name, floor region, frames, skipped, readers, stalled).
- ``POST /api/sim/scatter`` (control): every rover picked up and put down at a random free spot.
- ``POST /api/sim/fault`` (control): JSON ``{kind, seconds, rover}``: ``wifi`` (that rover's Wi-Fi gone) and
  ``camera`` (the camera hangs) happen in the lab; ``broker`` (the embedded broker stopped and started again) and
  ``edge`` (this process killed, restarted ``seconds`` later as a service manager would) happen here, announced to
  the lab first so it times how fast the rovers stop.

"Killed" is a real kill as far as everyone else can tell: the process replaces itself (``exec``) without running
any clean-up, so its sockets close unannounced (no offline status, no clean MQTT disconnect, the embedded broker
and its retained messages gone), and the same command starts again after the delay, with the same process id, so
a terminal or service manager running it sees it carry on.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from edge.errors import EdgeIpsError, describe_validation
from edge.httpserver import HttpServer, Request, Response, json_response

log = logging.getLogger("edge.dashboard")

MAX_EDGE_DOWN_S = 20.0  # a killed edge must be back before its lab gives up on it (30 s without a camera reader)
MAX_FAULT_S = 300.0
EXEC_DELAY_S = 0.3  # the reply to the request leaves before the process goes


class LabControls(Protocol):
    """What a simulated lab lets the dashboard do (``edge.sim.twin.source.LabClient``)."""

    def scatter(self) -> dict[str, Any]: ...

    def fault(self, kind: str, seconds: float, rover: str | None = None) -> str: ...

    def note(self, label: str) -> None: ...

    def status(self, after: int = 0) -> dict[str, Any]: ...


@runtime_checkable
class ControllableSource(Protocol):
    """A frame source that is a lab with controls (optional capability, checked with ``isinstance``)."""

    controls: LabControls


class Restartable(Protocol):
    """The embedded broker as far as a restart goes."""

    def stop(self, timeout_s: float = 10.0) -> None: ...

    def start(self, timeout_s: float = 10.0) -> Any: ...


class FaultRequest(BaseModel):
    """What the page posts to ``/api/sim/fault``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: str = Field(pattern="^(wifi|camera|broker|edge)$")
    seconds: float = Field(gt=0.0, le=MAX_FAULT_S)
    rover: str | None = Field(default=None, max_length=16)


@dataclass
class EdgeFaults:
    """The faults that happen at the edge: the embedded broker (None: an external one, not ours to restart) and
    ``restart_argv`` (how this process was started; None: not started by ``edge-ips start``, no kill)."""

    broker: Restartable | None
    restart_argv: Sequence[str] | None

    def offered(self) -> list[str]:
        return [k for k, ok in (("broker", self.broker is not None), ("edge", self.restart_argv is not None)) if ok]

    def check(self, kind: str, seconds: float) -> str:
        """What ``kind`` (``broker`` or ``edge``) for ``seconds`` will do; :class:`EdgeIpsError` when it cannot."""
        if kind == "broker":
            if self.broker is None:
                raise EdgeIpsError("the broker is an external one: restart it where it runs (e.g. systemctl restart)")
            return f"broker restart ({seconds:g} s down)"
        if self.restart_argv is None:
            raise EdgeIpsError("this edge was not started by `edge-ips start`: it cannot be killed and restarted")
        if seconds > MAX_EDGE_DOWN_S:
            raise EdgeIpsError(f"an edge is killed for at most {MAX_EDGE_DOWN_S:g} s (its lab waits 30 s for it)")
        return f"edge killed for {seconds:g} s"

    def cause(self, kind: str, seconds: float, announce: Callable[[str], None]) -> str:
        """Do it (after :meth:`check`) on a thread of its own, so the HTTP reply leaves first; ``announce(label)``
        is called the moment before (the lab times the rovers from then)."""
        label = self.check(kind, seconds)
        target = self._cycle_broker if kind == "broker" else self._kill
        threading.Thread(target=target, args=(seconds, label, announce), name=f"fault-{kind}", daemon=True).start()
        return label

    def _cycle_broker(self, seconds: float, label: str, announce: Callable[[str], None]) -> None:
        assert self.broker is not None
        log.warning("fault: the embedded broker stops for %g s (its retained messages go with it)", seconds)
        announce(label)
        self.broker.stop()
        threading.Event().wait(seconds)
        try:
            self.broker.start()
        except EdgeIpsError as exc:
            log.error("fault: the embedded broker did not start again: %s", exc)

    def _kill(self, seconds: float, label: str, announce: Callable[[str], None]) -> None:
        assert self.restart_argv is not None
        again = [*without_after_kill(self.restart_argv), "--after-kill", f"{seconds:g}"]
        threading.Event().wait(EXEC_DELAY_S)
        log.warning("fault: killed; starting again in %g s", seconds)
        for handler in logging.getLogger().handlers:
            handler.flush()
        announce(label)
        os.execv(sys.executable, [sys.executable, *again])


def without_after_kill(argv: Sequence[str]) -> list[str]:
    """``argv`` without an earlier ``--after-kill S`` (a second kill must not add a second one)."""
    out: list[str] = []
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg == "--after-kill":
            skip = True
        elif not arg.startswith("--after-kill="):
            out.append(arg)
    return out


class SimPanel:
    """The routes above over a lab's ``controls`` and the edge's own ``faults``. ``enabled``: a control token is
    configured (without one, the controls answer 403, as the formation controls do)."""

    def __init__(self, controls: LabControls, faults: EdgeFaults, *, enabled: bool) -> None:
        self.controls = controls
        self.faults = faults
        self.enabled = enabled

    def attach(self, http: HttpServer) -> SimPanel:
        http.route("/api/sim", self.describe, access="read")
        http.route("/api/sim/scatter", self.scatter, method="POST", access="control")
        http.route("/api/sim/fault", self.fault, method="POST", access="control")
        return self

    def describe(self, request: Request) -> Response:
        after = request.query.get("after", ["0"])[0]
        try:
            lab = self.controls.status(int(after) if after.isdigit() else 0)
        except EdgeIpsError as exc:
            return json_response(503, {"error": str(exc)})
        offered = ["wifi", "camera", *self.faults.offered()]
        return json_response(
            200,
            {
                "controls_enabled": self.enabled,
                "offered": offered,
                "active": lab.get("faults", []),
                "rovers": lab.get("rovers", []),
                "events": lab.get("events", []),
                "camera": lab.get("camera", {}),
                "cameras": lab.get("cameras", []),
            },
        )

    def _refused(self) -> Response | None:
        if not self.enabled:
            return json_response(403, {"error": "simulator controls are disabled: no dashboard token is configured"})
        return None

    def scatter(self, request: Request) -> Response:
        refused = self._refused()
        if refused is not None:
            return refused
        try:
            placed = self.controls.scatter()
        except EdgeIpsError as exc:
            return json_response(502, {"error": str(exc)})
        log.info("dashboard: rovers scattered")
        return json_response(200, {"ok": True, "placed": placed})

    def fault(self, request: Request) -> Response:
        refused = self._refused()
        if refused is not None:
            return refused
        try:
            req = FaultRequest.model_validate(json.loads(request.body or b"null"))
        except (ValueError, UnicodeDecodeError) as exc:
            detail = describe_validation(exc, top_level="(body)") if isinstance(exc, ValidationError) else str(exc)
            return json_response(400, {"error": f"fault request: {detail}"})
        try:
            done = self._cause(req)
        except EdgeIpsError as exc:
            return json_response(409, {"error": str(exc)})
        log.warning("dashboard: fault: %s", done)
        return json_response(200, {"ok": True, "done": done})

    def _cause(self, req: FaultRequest) -> str:
        if req.kind in ("wifi", "camera"):
            return self.controls.fault(req.kind, req.seconds, req.rover)
        return self.faults.cause(req.kind, req.seconds, self._announce)

    def _announce(self, label: str) -> None:
        try:
            self.controls.note(label)  # the lab times the rovers from now
        except EdgeIpsError as exc:
            log.warning("fault: the lab was not told (%s)", exc)


def attach_sim_panel(
    http: HttpServer,
    source: object,
    *,
    broker: Restartable | None,
    restart_argv: Sequence[str] | None,
    enabled: bool,
) -> SimPanel | None:
    """Serve the panel when ``source`` is a lab with controls; None otherwise."""
    if not isinstance(source, ControllableSource):
        return None
    return SimPanel(source.controls, EdgeFaults(broker, restart_argv), enabled=enabled).attach(http)
