"""Bodies that cannot pass through each other: rover boxes on the floor, pushed apart where they overlap.

Each rover's body is a ``length_cm`` x ``width_cm`` box round its marker centre, along its heading (the footprint
:mod:`edge.sim.metrics` measures gaps with). Where two boxes overlap, both move apart by half the overlap along the
axis that separates them with the least movement (the separating-axis theorem's minimum translation): equal masses,
no rotation, no bounce. The world calls :func:`separate` after each integration sub-step, so two rovers driving
into each other end up pressed together, wheels slipping, as on a real floor, never through each other. A few
passes settle a rover squeezed between two others.

Pure numpy; poses are ``(N, 3)`` float64 rows ``x_cm, y_cm, theta_rad``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from edge.errors import SimulationError
from edge.messages import wrap_angle
from edge.sim.metrics import box_corners_cm
from edge.sim.world import DriveModel, Pose, WheelCommand, World, WorldState

FloatArray = NDArray[np.float64]

PASSES = 8  # a rover between two others needs several passes to settle (each halves what is left)


def push_apart_cm(a: FloatArray, b: FloatArray) -> FloatArray | None:
    """The shortest translation of box ``b`` that separates it from box ``a`` (both (4, 2) corners), or None when
    they do not overlap. ``a`` moved by its negative separates them too."""
    best_depth = math.inf
    best_axis = np.zeros(2)
    for poly in (a, b):
        for k in range(2):  # a box has two distinct edge normals
            edge = poly[k + 1] - poly[k]
            axis = np.array([-edge[1], edge[0]]) / math.hypot(float(edge[0]), float(edge[1]))
            pa, pb = a @ axis, b @ axis
            depth = min(float(pa.max() - pb.min()), float(pb.max() - pa.min()))
            if depth <= 0.0:
                return None
            if depth < best_depth:
                best_depth, best_axis = depth, axis
    if float((b.mean(axis=0) - a.mean(axis=0)) @ best_axis) < 0.0:
        best_axis = -best_axis
    return np.asarray(best_axis * best_depth, dtype=np.float64)


def separate(poses: FloatArray, length_cm: float, width_cm: float, passes: int = PASSES) -> FloatArray:
    """``(N, 2)`` displacements (cm) that push overlapping bodies apart, half each (see the module docstring)."""
    xy = np.array(poses[:, :2], dtype=np.float64)
    n = len(xy)
    reach = math.hypot(length_cm, width_cm)  # centres farther apart than two half-diagonals cannot touch
    for _ in range(passes):
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        close = np.argwhere(np.triu(d < reach, k=1))
        if close.size == 0:
            break
        moved = False
        for i, j in close:
            a = box_corners_cm(float(xy[i, 0]), float(xy[i, 1]), float(poses[i, 2]), length_cm, width_cm)
            b = box_corners_cm(float(xy[j, 0]), float(xy[j, 1]), float(poses[j, 2]), length_cm, width_cm)
            push = push_apart_cm(a, b)
            if push is None:
                continue
            xy[i] -= 0.5 * push
            xy[j] += 0.5 * push
            moved = True
        if not moved:
            break
    return np.asarray(xy - poses[:, :2], dtype=np.float64) if n else np.zeros((0, 2))


class SolidWorld(World):
    """A :class:`~edge.sim.world.World` of commanded rovers whose bodies (``bodies_cm``: length, width) cannot pass
    through each other: the same drive model, sub-step by sub-step, with :func:`separate` after each one; and rovers
    can be picked up and put down elsewhere (:meth:`place`)."""

    def __init__(
        self,
        rovers: Mapping[str, Pose],
        drive: DriveModel,
        *,
        bodies_cm: tuple[float, float],
        seed: int = 0,
        substep_s: float = 0.005,
    ) -> None:
        super().__init__(rovers, drive, seed=seed, substep_s=substep_s)
        self.bodies_cm = bodies_cm
        self._step_s = substep_s

    def step(self, dt_s: float, commands: Mapping[str, WheelCommand | tuple[float, float]] | None = None) -> WorldState:
        remaining = dt_s
        given = commands
        while remaining > 1e-12:
            h = min(self._step_s, remaining)
            super().step(h, given)
            given = None  # queued once, at the start of the interval: the actuation delay counts from there
            self._push_apart()
            remaining -= h
        return self.state()

    def _push_apart(self) -> None:
        bodies = list(self._driven.values())
        if len(bodies) < 2:
            return
        poses = np.array([(r.x_cm, r.y_cm, r.theta_rad) for r in bodies])
        for rover, (dx, dy) in zip(bodies, separate(poses, *self.bodies_cm), strict=True):
            rover.x_cm += float(dx)
            rover.y_cm += float(dy)

    def place(self, rover_id: str, pose: Pose) -> None:
        """Pick a rover up and put it down at ``pose``: its wheels stop turning; its motors keep their command."""
        rover = self._driven.get(rover_id)
        if rover is None:
            raise SimulationError(f"world: no rover {rover_id!r} to place")
        rover.x_cm, rover.y_cm, rover.theta_rad = pose.x_cm, pose.y_cm, wrap_angle(pose.theta_rad)
        rover.left_cm_s = rover.right_cm_s = 0.0
