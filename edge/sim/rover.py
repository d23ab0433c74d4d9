"""The physical rover of the closed-loop experiments, described once: the firmware's config is the source of truth.

The simulator's :class:`~edge.sim.world.DriveModel` and :class:`~edge.sim.scene.RoverLook` are *derived* from the
rover's ``config.json`` (the one flashed onto the board, ``firmware/esp8266/configs/``), so the simulated rover and
the firmware that drives it can never describe two different machines:

* track width = ``geometry.track_cm``; top wheel rim speed = ``motors.max_wheel_rad_s * geometry.wheel_radius_cm``
  (the example configs: 13 cm track, 6.5 cm wheels at 15 rad/s = 48.75 cm/s, a TT/N20 gear-motor lab rover);
* the body is a box that fits inside the circle ``geometry.body_radius_cm`` the firmware's safety layer assumes
  (22 x 17.2 cm under a 21.5 x 16.8 cm marker: half-diagonal 13.96 cm <= 14), checked at construction;
* what the config does not say (how far the real motors are from the duty model) is :class:`MotorPhysics`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from edge.errors import ConfigError
from edge.sim.scene import Heading, RoverLook, fleet_looks
from edge.sim.world import DriveModel

EXAMPLE_IDS = ("red", "green", "blue")
BODY_LENGTH_CM = 22.0
BODY_WIDTH_CM = 17.2


@dataclass(frozen=True)
class MotorPhysics:
    """How the real motors differ from the firmware's duty model (nothing here is known to the firmware).

    ``gain_sigma``: per-wheel static gain error (5 %: two TT motors of one batch); ``noise_sigma``: per-step speed
    noise; ``delay_s``: PWM-to-wheel lag; ``accel_cm_s2``: wheel acceleration limit (a 1:48 TT motor on a 6.5 cm
    wheel reaches full speed in about a quarter of a second loaded).
    """

    gain_sigma: float = 0.05
    noise_sigma: float = 0.03
    delay_s: float = 0.03
    accel_cm_s2: float = 200.0


def rover_config(rover_id: str, control: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The config.json of one rover of the experiments: the example config of ``red``/``green``/``blue`` (others
    copy red's pins), as flashed, with ``control`` overrides; checked by the firmware's own rules."""
    from edge.rover_host import check_rover_config, load_rover_config

    base = load_rover_config(rover_id if rover_id in EXAMPLE_IDS else "red")
    base["id"] = rover_id
    base["control"] = {**base["control"], **(control or {})}
    return check_rover_config(base, where=f"rover {rover_id}")


def max_wheel_speed_cm_s(config: Mapping[str, Any]) -> float:
    """Top wheel rim speed the config stands for, cm/s."""
    return float(config["motors"]["max_wheel_rad_s"]) * float(config["geometry"]["wheel_radius_cm"])


def drive_model(config: Mapping[str, Any], physics: MotorPhysics | None = None) -> DriveModel:
    """The simulated drive of the rover a config describes."""
    p = physics or MotorPhysics()
    g = config["geometry"]
    m = config["motors"]
    return DriveModel(
        track_width_cm=float(g["track_cm"]),
        max_wheel_speed_cm_s=max_wheel_speed_cm_s(config),
        max_wheel_accel_cm_s2=p.accel_cm_s2,
        motor_gain_sigma=p.gain_sigma,
        motor_noise_sigma=p.noise_sigma,
        delay_s=p.delay_s,
        # Below min_wheel_rad_s the firmware writes duty 0; the motor does not turn.
        deadband_cm_s=float(m["min_wheel_rad_s"]) * float(g["wheel_radius_cm"]),
    )


def fleet_drive_model(configs: Sequence[Mapping[str, Any]], physics: MotorPhysics | None = None) -> DriveModel:
    """One drive model for a fleet (the world has one): every config must describe the same drive."""
    if not configs:
        raise ConfigError("fleet: at least one rover config is needed")
    models = {drive_model(c, physics) for c in configs}
    if len(models) != 1:
        ids = ", ".join(str(c["id"]) for c in configs)
        raise ConfigError(f"fleet {ids}: the rovers' geometry/motors differ; the simulated world has one drive")
    return models.pop()


def rover_looks(configs: Sequence[Mapping[str, Any]], heading: Heading = "two_tone") -> tuple[RoverLook, ...]:
    """The rovers as the camera sees them: fleet colours and markers, a body that fits the config's body circle."""
    from dataclasses import replace

    half_diagonal = 0.5 * math.hypot(BODY_LENGTH_CM, BODY_WIDTH_CM)
    for c in configs:
        radius = float(c["geometry"]["body_radius_cm"])
        if half_diagonal > radius:
            raise ConfigError(
                f"rover {c['id']}: geometry.body_radius_cm {radius:g} does not cover the {BODY_LENGTH_CM:g} x "
                f"{BODY_WIDTH_CM:g} cm body (needs {half_diagonal:.2f})"
            )
    looks = fleet_looks(len(configs), heading)
    return tuple(
        replace(look, rover_id=str(c["id"]), body_length_cm=BODY_LENGTH_CM, body_width_cm=BODY_WIDTH_CM)
        for look, c in zip(looks, configs, strict=True)
    )


def fleet_ids(n_rovers: int) -> tuple[str, ...]:
    """Rover ids of a fleet of ``n_rovers``, as the simulator names them (red, green, blue, then hues)."""
    return tuple(look.rover_id for look in fleet_looks(n_rovers))
