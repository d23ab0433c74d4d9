# MicroPython driver: heap use of the firmware's loop over many messages and control steps.
# /input/data/events: as for replay.py (config, then "m ..." / "s ..." lines), played again and again.
# Prints one JSON object: heap after collection before and after, the band it stayed in (measured after each batch
# of 100 steps), the rover's retained state, and the largest allocation a single loop iteration (its messages and
# its step) makes between collections. Floats are heap objects in this build (not on the ESP8266), so the values
# the rover holds at the moment of a measurement (a float here, an int there) move the count by a few 16-byte
# blocks: "no leak" shows as a band of a few dozen bytes that does not drift.
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


def _mark(i):
    _s["marks"][i] = gc.mem_alloc()


def _reset_counts():
    _s["messages"] = 0
    _s["steps"] = 0
    _s["peak"] = 0


def _report():
    marks = _s["marks"]
    r = _s["rover"]
    print(
        json.dumps(
            {
                "heap_start": marks[0],
                "heap_end": marks[-1],
                "growth": marks[-1] - marks[0],
                "band": max(marks) - min(marks),
                "messages": _s["messages"],
                "steps": _s["steps"],
                "state_bytes": _s["state_bytes"],
                "peak_iteration_bytes": _s["peak"],
                "halt": r.halt,
                "received": r.received,
                "rejected": r.rejected,
            }
        )
    )


def main(total_steps=10000, chunk=100):
    # Every frame running during gc.collect() keeps to a handful of locals (firmware/harness/runner.py): the state
    # lives in _s, the work in _chunk.
    gc.disable()
    _setup()
    _make_rover()
    _s["marks"] = [0] * (total_steps // chunk + 1)
    for _ in range(10):  # warm-up: the formation, fleet slots, heading
        _chunk(chunk)
        gc.collect()
    _mark(0)
    _reset_counts()
    for i in range(total_steps // chunk):
        _chunk(chunk)
        gc.collect()
        _mark(i + 1)
    _report()
