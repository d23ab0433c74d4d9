# MicroPython driver: heap taken by importing each firmware module from its .mpy (/input/data/*.mpy), after collection.
# machine, network and umqtt.simple are tiny stand-ins here (on the board they are built in or frozen: no heap).
# Every function that is running when gc.collect() runs keeps to a handful of locals (tests/support/firmware.py).
import gc
import json
import sys

_out = {}


def _one(name):
    gc.collect()
    before = gc.mem_alloc()
    __import__(name)
    gc.collect()
    _out[name] = gc.mem_alloc() - before


def _drop_config():
    del sys.modules["config"]


def main(modules):
    gc.disable()
    sys.path.insert(0, "/input/data")
    gc.collect()
    _out["_start"] = gc.mem_alloc()
    for name in modules:
        _one(name)
    gc.collect()
    _out["all"] = gc.mem_alloc() - _out["_start"]
    _drop_config()
    gc.collect()
    _out["all_after_boot"] = gc.mem_alloc() - _out["_start"]
    del _out["_start"]
    print(json.dumps(_out))
