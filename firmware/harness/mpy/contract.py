# MicroPython driver: parse every contract example with the firmware's msg.py; one JSON line per file.
# The automatic GC stays off (see firmware/harness/runner.py): a handful of messages fits the heap easily.
import gc
import json
import os

import msg


def _result(kind, payload):
    if kind == "pose":
        return msg.parse_pose(payload)
    if kind == "formation":
        return msg.parse_formation(payload)
    return [msg.parse_pose(payload), msg.parse_formation(payload)]


def main():
    gc.disable()
    for folder in ("valid", "invalid"):
        for name in sorted(os.listdir("/input/examples/" + folder)):
            with open("/input/examples/" + folder + "/" + name, "rb") as f:
                payload = f.read()
            print(json.dumps([folder, name, _result(name.split("-")[0], payload)]))


def _lines(f, n):
    # Up to n payloads from the open corpus file; False at its end.
    import binascii

    for _ in range(n):
        line = f.readline()
        if not line:
            return False
        kind, hexed = line.strip().split(" ")
        print(json.dumps(_result(kind, binascii.unhexlify(hexed))))
    return True


def corpus(name):
    # /input/data/<name>: one "kind hex" per line -> one JSON line per payload, in order. Read line by line and
    # collected between batches, from this small frame only (see firmware/harness/runner.py).
    gc.disable()
    f = open("/input/data/" + name)
    while _lines(f, 100):
        gc.collect()
    f.close()
