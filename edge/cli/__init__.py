"""The ``edge-ips`` command line: one click group, thin commands over the library, one module per command group.

Every user mistake the library detects arrives here as an :class:`edge.errors.EdgeIpsError` and leaves as a
one-line message with exit code 2 (:class:`edge.cli.common.UserError`); nothing else in the package talks to the
terminal's exit code. The commands:

- :mod:`edge.cli.start`: ``start`` (the appliance), ``doctor``;
- :mod:`edge.cli.settings`: ``config show``, ``config init``, ``schema``;
- :mod:`edge.cli.formation`: ``formation``; :mod:`edge.cli.broker`: ``broker-config``;
- :mod:`edge.cli.calibrate`: ``calibrate points|intrinsics|aruco|check``; :mod:`edge.cli.rovers`: ``rovers enroll``;
- :mod:`edge.cli.track`: ``track``, ``plot``; :mod:`edge.cli.sim`: ``sim ...``; :mod:`edge.cli.flash`: ``flash``.
"""

from __future__ import annotations

import click

from edge.cli import broker, calibrate, flash, formation, rovers, settings, sim, start, track
from edge.cli.common import EdgeGroup, UserError

__all__ = ["UserError", "main"]


@click.group(cls=EdgeGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="edge-ips")
def main() -> None:
    """edge-ips: optical indoor positioning for small robot fleets.

    One static camera tracks coloured markers on rovers and publishes each rover's world pose over MQTT.
    """


for command in (
    settings.schema,
    settings.config,
    start.start,
    start.doctor,
    formation.formation,
    broker.broker_config,
    track.track,
    track.plot,
    flash.flash,
    calibrate.calibrate,
    rovers.rovers,
    sim.sim,
):
    main.add_command(command)
