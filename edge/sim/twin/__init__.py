"""The live twin: ``edge-ips start --source sim:twin`` tracks a simulated lab whose rovers run their real firmware.

Two processes, as in the field::

    edge-ips sim twin (the lab)                                     edge-ips start (the appliance)
    ┌───────────────────────────────────────────────┐   frames    ┌──────────────────────────────────┐
    │ world (bodies, drive model) ─▶ camera ─────────┼───────────▶│ TwinSource → tracker → publisher │
    │   ▲ PWM duties                                  │ lab socket │ dashboard (scatter, faults)      │
    │ firmware ×N (HostRover, real time, own logins) │            └───────────────┬──────────────────┘
    └──────────────────────▲──────────────────────────┘                            │ poses, formation
                           │        MQTT (embedded amqtt or Mosquitto)              │
                           └───────────────────────────── broker ◀──────────────────┘

* :mod:`~edge.sim.twin.lab`: the world, the camera, the rovers, scatter and faults;
* :mod:`~edge.sim.twin.camera`: rendering in real time with a webcam's delay; :mod:`~edge.sim.twin.rovers`: the
  firmware on its threads, with a station interface faults can take the access point from;
* :mod:`~edge.sim.twin.server` and :mod:`~edge.sim.twin.wire`: the lab's Unix socket (camera streams, controls);
* :mod:`~edge.sim.twin.service`: the lab as a process (``edge-ips sim twin``);
* :mod:`~edge.sim.twin.source`: the appliance's frame source, the lab's controls, starting a lab when none runs.

Why the world lives with the firmware and not in the appliance: the motors drive the bodies directly, as wires do,
and the only thing that crosses to the appliance is what a camera sends, pictures; the appliance knows it tracks a
twin only by its frame source. A killed or restarted edge leaves the lab running (the rovers stop on their own and
come back), as a crashed camera board leaves the floor.
"""
