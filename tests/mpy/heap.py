# MicroPython driver: heap use of the firmware's loop over many messages and control steps.
# /input/data/events: as for replay.py (config, then "m ..." / "s ..." lines), played again and again.
# Prints one JSON object: heap after collection before and after, the rover's retained state, and the largest
# allocation a single loop iteration (its messages and its step) makes between collections.
import binascii
import gc
import json

import rover as rv
from replay import Motors

_s = {}


def _setup():
    with open("/input/data/events") as f:
        lines = f.read().split("\n")
    cfg = json.loads(lines[0])
    # Decoded once: the link hands the rover bytes it already holds, so the driver's own parsing stays out.
    events = []
    for line in lines[1:]:
        parts = line.split(" ")
        if parts[0] == "m":
            events.append((int(parts[1]), parts[2].encode(), binascii.unhexlify(parts[3])))
        elif parts[0] == "s":
            events.append((int(parts[1]), None, None))
    _s["events"] = events
    _s["cfg"] = cfg
    _s["k"] = 0
    _s["messages"] = 0
    _s["steps"] = 0
    _s["peak"] = 0
    _s["lap_ms"] = events[-1][0] + 20


def _make_rover():
    gc.collect()
    before = gc.mem_alloc()
    _s["rover"] = rv.Rover(_s["cfg"], Motors(), log=lambda *a: None)
    gc.collect()
    _s["state_bytes"] = gc.mem_alloc() - before


def _chunk(steps):
    # Plays events until `steps` control steps have run; the clock keeps running across laps.
    r = _s["rover"]
    events = _s["events"]
    n_events = len(events)
    k = _s["k"]
    done = 0
    peak = _s["peak"]
    mark = gc.mem_alloc()
    while done < steps:
        t, topic, payload = events[k % n_events]
        now = (t + (k // n_events) * _s["lap_ms"]) & 0x3FFFFFFF
        k += 1
        if topic is not None:
            r._now = now
            r.on_message(topic, payload)
            _s["messages"] += 1
        else:
            r.step(now)
            done += 1
            used = gc.mem_alloc() - mark
            if used > peak:
                peak = used
            mark = gc.mem_alloc()
    _s["k"] = k
    _s["peak"] = peak
    _s["steps"] += done


def main(total_steps=10000, chunk=100):
    gc.disable()
    _setup()
    _make_rover()
    _chunk(chunk)  # warm-up: first formation, fleet slots, heading
    gc.collect()
    start = gc.mem_alloc()
    _s["messages"] = 0
    _s["steps"] = 0
    _s["peak"] = 0
    for _ in range(total_steps // chunk):
        _chunk(chunk)
        gc.collect()
    gc.collect()
    end = gc.mem_alloc()
    print(
        json.dumps(
            {
                "heap_start": start,
                "heap_end": end,
                "growth": end - start,
                "messages": _s["messages"],
                "steps": _s["steps"],
                "state_bytes": _s["state_bytes"],
                "peak_iteration_bytes": _s["peak"],
                "halt": _s["rover"].halt,
                "received": _s["rover"].received,
                "rejected": _s["rover"].rejected,
            }
        )
    )
