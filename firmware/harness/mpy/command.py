# Driver, for MicroPython and CPython alike: formation commands, (re)connects and steps into one Rover, with a link
# that is always up and keeps the statuses the rover hands it. The same file runs in both interpreters, so their
# outputs can be compared line for line.
# Events file: the config JSON on line 1, then "m <ms> <topic> <hex payload>" (a message), "c" (the link's
# on_connect after a CONNACK) or "s <ms>" (a step) per line. One JSON line per step:
#   [ms, halt, formation kind or null, its seq or null, its spacing or null, left, right, [statuses published then]]
import binascii
import gc
import json

import msg
import rover as rv


class Motors:
    def __init__(self):
        self.left = 0.0
        self.right = 0.0

    def drive(self, left, right):
        self.left = left
        self.right = right

    def stop(self):
        self.left = 0.0
        self.right = 0.0


class Link:
    up = True

    def __init__(self):
        self.sent = []

    def poll(self, now_ms):
        return True

    def publish_status(self, payload):
        self.sent.append(payload)


def _row(t, r, link):
    f = r.formation  # msg's _F_SEQ 0, _F_KIND 1, _F_SPACING 3 (private consts: no attributes in MicroPython)
    kind = None if f is None else f[1]
    seq = None if f is None else f[0]
    spacing = None if f is None else f[3]
    sent = [p.decode() for p in link.sent]
    link.sent = []
    return json.dumps([t, r.halt, kind, seq, spacing, r.motors.left, r.motors.right, sent])


_state = {}


def _setup(path):
    with open(path) as f:
        _state["lines"] = f.read().split("\n")
    _state["link"] = Link()
    _state["rover"] = rv.Rover(json.loads(_state["lines"][0]), Motors(), _state["link"], log=lambda *a: None)
    _state["next"] = 1


def _chunk(n):
    # Up to n events; False at the end. Collections happen between chunks, from run()'s small frame (see
    # firmware/harness/runner.py: a collection inside a large running function corrupts this wasm build's heap).
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
        elif parts[0] == "c":
            r.on_connect()
        elif parts[0] == "s":
            r.step(int(parts[1]))
            print(_row(int(parts[1]), r, _state["link"]))
    _state["next"] = k
    return k < len(lines)


def run(path):
    gc.disable()
    _setup(path)
    while _chunk(200):
        gc.collect()


def statuses(folder):
    # Every rover status vector in `folder`, rebuilt by the firmware from its fields: [name, the bytes it wrote].
    import os

    for name in sorted(os.listdir(folder)):
        if name.startswith("rover_status-"):
            with open(folder + "/" + name, "rb") as f:
                d = json.loads(f.read())
            out = msg.rover_status(d["id"], d["state"], d["halt"], d["formation"], d["seq"], d["fw"])
            print(json.dumps([name, out.decode()]))
