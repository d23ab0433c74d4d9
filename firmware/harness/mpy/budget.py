# Driver: the firmware's heap inside a real MicroPython, deployed as on the chip, phase by phase.
#
# /input/data holds what the flash tool puts on a rover (rom.img, boot.py, main.py, config.json) and frozen.img, a
# ROMFS image of umqtt/simple.mpy standing for the umqtt.simple frozen into the firmware (frozen code keeps its
# qstrs and raw code in flash too, so this over-counts it a little). Before the baseline, as the chip has them before
# main.py runs: both images' bytes (on the chip they are flash, not heap), the ROMFS mounted, the stand-ins for the
# built-in machine and network, and a scripted socket whose bytes are all prepared in advance (on the chip they
# arrive in lwip's buffers, outside the MicroPython heap). Then the chip's own sequence: boot.py and main.py
# compiled from source, main.py's imports from ROMFS in the chip's order, app.start (config, motors, rover, link),
# the first connection (CONNACK, on_connect, two SUBACKs, the retained formation, a status), the loop with three
# poses a frame, the largest message the rover accepts, and a packet too long to keep.
#
# Each phase runs with the collector off: `alloc` is what it allocated (live objects and garbage), `transient` the
# most that was allocated at once, counting buffers freed before its end (micropython.mem_peak); the live heap
# inside a phase is at most `live` before it plus `transient`, so `peak` = that sum bounds what a collection on
# the chip would have to find room for. Floats are heap objects here (16 B each) and not on the ESP8266: one more
# reason these figures are upper bounds.
import gc
import json
import sys

import fakenet
import machine
import micropython
import network
import vfs
from micropython import const

_s = {}
_FRAME = const(3)  # poses per frame


class QuietSocket:
    """lwip as the rover sees it, from a byte string prepared before the measurement: `limit` says how much of it
    has arrived. Writes are counted, not kept."""

    def __init__(self, data):
        self.data = data
        self.pos = 0
        self.limit = 0
        self.written = 0
        self.timeout = None

    def settimeout(self, t):
        self.timeout = t

    def setblocking(self, flag):
        self.timeout = None if flag else 0

    def connect(self, addr):
        pass

    def readinto(self, buf, n=None):
        k = min(len(buf) if n is None else min(n, len(buf)), self.limit - self.pos)
        if k <= 0:
            if self.timeout == 0:
                return None
            raise OSError(110)
        data = self.data
        pos = self.pos
        for i in range(k):  # byte by byte: a slice would allocate, and lwip's readinto does not
            buf[i] = data[pos + i]
        self.pos = pos + k
        return k

    def read(self, n):
        k = min(n, self.limit - self.pos)
        if k <= 0:
            return None if self.timeout == 0 else b""
        out = self.data[self.pos : self.pos + k]
        self.pos += k
        return out

    def write(self, buf, n=None):
        k = len(buf) if n is None else n
        self.written += k
        return k

    def close(self):
        pass


class QuietNet:
    def __init__(self, sock):
        self.sock = sock

    def socket(self, *args):
        return self.sock

    def getaddrinfo(self, host, port, *args):
        return [(2, 1, 0, "", (host, port))]


def _read(name):
    with open("/input/data/" + name, "rb") as f:
        return f.read()


def _prepare():
    # Everything the measurement must not count: images, stream, stand-ins, clock.
    _s["rom"] = _read("rom.img")
    _s["frozen"] = _read("frozen.img")
    stream = _read("stream")
    _s["marks"] = json.loads(_read("marks"))  # stream offsets: after the session set-up, after each frame...
    _s["sock"] = QuietSocket(stream)
    _s["clock"] = fakenet.Clock()
    vfs.mount(vfs.VfsRom(_s["rom"]), "/rom")
    vfs.mount(vfs.VfsRom(_s["frozen"]), "/frozen")
    sys.path[:0] = ["/input/data", "/frozen", "/rom"]
    machine.stop_timers()
    network.ap_active()


def _collect():
    gc.collect()
    return gc.mem_alloc()


def _begin():
    _s["live0"] = _collect()
    _s["cur0"] = micropython.mem_current()
    _s["top0"] = micropython.mem_peak()


# Phase records go into a list of small ints allocated before the baseline, so the bookkeeping allocates nothing
# the measurement would count: per record, the fields of FIELDS.
FIELDS = ("alloc", "transient", "live_before", "peak", "live_after", "live_floats")
_W = const(6)


def _end(name):
    # Locals and stack kept small: a collection runs inside (firmware/harness/runner.py).
    rec = _s["rec"]
    i = _s["n"] * _W
    rec[i] = gc.mem_alloc() - _s["live0"]
    # mem_peak has no reset: a phase's own high-water mark shows only when it tops every earlier one.
    if micropython.mem_peak() > _s["top0"]:
        rec[i + 1] = micropython.mem_peak() - _s["cur0"]
    else:
        rec[i + 1] = micropython.mem_current() - _s["cur0"]
    if rec[i + 1] < rec[i]:
        rec[i + 1] = rec[i]
    rec[i + 2] = _s["live0"] - _s["base"]
    rec[i + 3] = rec[i + 2] + rec[i + 1]
    rec[i + 4] = _collect() - _s["base"]
    rec[i + 5] = _live_floats()
    _collect()
    _s["names"][_s["n"]] = name
    _s["n"] += 1
    print("qstr after", _s["n"])  # the host reads the pools' size from the line qstr_info prints
    micropython.qstr_info()


_SCALARS = (int, bool, str, bytes, bytearray, memoryview, type(None))


def _live_floats():
    # Distinct float objects the firmware's state holds (16 B each here, nothing on the ESP8266); module constants
    # are counted from the .mpy files instead (firmware/harness/runner.py).
    seen = {}
    done = {}
    todo = [_s["rover"], _s["wd"], _s["cfg"]]
    while todo:
        o = todo.pop()
        t = type(o)
        if t is float:
            seen[id(o)] = 1
        elif t in _SCALARS or id(o) in done:
            pass
        elif t is list or t is tuple:
            done[id(o)] = 1
            todo.extend(o)
        elif t is dict:
            done[id(o)] = 1
            todo.extend(o.values())
        elif hasattr(o, "__dict__") and t.__name__ not in ("module", "function", "bound_method", "type"):
            done[id(o)] = 1
            todo.extend(o.__dict__.values())
    return len(seen)


def _boot():
    with open("/input/data/boot.py") as f:
        exec(f.read(), {"__name__": "__main__"})


def _main_py():
    # The board compiles main.py from source and runs it as __main__; here as "main", so app.run() is not called:
    # its imports are what counts, and app.start and app.loop follow, as run() would call them.
    _s["main"] = __import__("main")


def _standins():
    import app
    import link
    from umqtt import simple

    app.time = _s["clock"]
    link.time = _s["clock"]
    simple.socket = QuietNet(_s["sock"])
    _s["app"] = app


def _import_config():
    __import__("config")


def _configure():
    _s["cfg"] = _s["app"].configure("/input/data/config.json", _quiet)


def _build():
    m, r = _s["app"].build(_s["cfg"], _quiet)
    _s["cfg"] = None
    _s["rover"] = r
    _s["wd"] = _s["app"].Watchdog(m)
    _s["wd"].start()


def _quiet(*args):
    pass


def _arrive(k):
    _s["sock"].limit = _s["marks"][k]


def _step():
    _s["app"].loop(_s["rover"], _s["wd"], 1)


def _connect():
    _arrive(0)  # CONNACK, two SUBACKs, the retained formation
    _step()


def _poll():
    # What a step does first: the link takes what arrived (umqtt reads, on_message keeps the poses' bytes),
    # stamped with the step's time.
    r = _s["rover"]
    r._now = _s["clock"].ticks_ms()
    r.link.poll(r._now)


def _flush():
    _s["rover"].flush()  # then the newest pose of each rover is parsed


def _sub(name, job):
    _begin()
    job()
    _end(name)


STEADY = ("steady state: receive", "steady state: parse", "steady state: control, status, sleep")
LARGEST = ("largest message: receive", "largest message: parse", "largest message: control, status, sleep")
DROPPED = ("6 KB packet: receive (dropped unread)", "6 KB packet: parse", "6 KB packet: control, status, sleep")


def _iteration(names, k):
    # One loop iteration in three parts, each measured from a collected heap: the sum of the work of one
    # app.loop() step (its poll finds nothing left, its flush nothing to parse), split where the step itself
    # moves from one to the next, so the live heap at each split is the step's own.
    _arrive(k)
    _sub(names[0], _poll)
    _sub(names[1], _flush)
    _sub(names[2], _step)


def _worse():
    # True when the iteration just recorded (the last three records) has a larger part than the kept one.
    rec = _s["rec"]
    i = (_s["n"] - 3) * _W
    w = _s["kept"] * _W
    return max(rec[i + 3], rec[i + 3 + _W], rec[i + 3 + 2 * _W]) > max(rec[w + 3], rec[w + 3 + _W], rec[w + 3 + 2 * _W])


def _frame():
    _iteration(STEADY, _s["k"])
    if _s["kept"] < 0:
        _s["kept"] = _s["n"] - 3
    elif _worse():
        rec = _s["rec"]
        for j in range(3 * _W):  # the worst iteration so far takes the kept records' place
            rec[_s["kept"] * _W + j] = rec[(_s["n"] - 3) * _W + j]
        _s["n"] -= 3
    else:
        _s["n"] -= 3
    _s["k"] += 1


def _frames(count):
    _s["k"] = 1
    _s["kept"] = -1
    while _s["k"] <= count:
        _frame()


def _run(frames):
    # Every function that is running when gc.collect() runs keeps to a handful of locals (firmware/harness/runner.py).
    _begin()
    _boot()
    _end("boot.py")
    _begin()
    _main_py()
    _end("main.py and its imports")
    _standins()
    _sub("app.start: import config", _import_config)
    _sub("app.start: load and check config.json", _configure)
    _sub("app.start: motors, rover, link, watchdog", _build)
    _begin()
    _connect()
    _end("connect: CONNACK, on_connect, SUBSCRIBE x2, retained formation")
    _frames(frames)
    _iteration(LARGEST, frames + 1)
    _iteration(DROPPED, frames + 2)


def _summary():
    r = _s["rover"]
    phases = []
    for n in range(_s["n"]):
        p = {"phase": _s["names"][n]}
        for j in range(_W):
            p[FIELDS[j]] = _s["rec"][n * _W + j]
        phases.append(p)
    return {
        "phases": phases,
        "halt": r.halt,
        "received": r.received,
        "rejected": r.rejected,
        "dropped": r.link.stream.dropped,
        "connects": r.link.connects,
        "formation": r.formation[1] if r.formation else None,
    }


def main(frames):
    gc.disable()
    _prepare()
    print("qstr after", 0)
    micropython.qstr_info()
    _s["rec"] = [0] * (32 * _W)
    _s["names"] = [None] * 32
    _s["n"] = 0
    _s["live0"] = _s["cur0"] = _s["top0"] = _s["k"] = _s["kept"] = 0
    _s["cfg"] = _s["app"] = _s["rover"] = _s["wd"] = None
    _s["base"] = _collect()
    _run(frames)
    print(json.dumps(_summary()))


def _import(name):
    __import__(name)


def _imports(names):
    _s["out"] = {}
    _s["i"] = 0
    _s["before"] = _collect()
    while _s["i"] < len(names):
        _import(names[_s["i"]])
        now = _collect()
        _s["out"][names[_s["i"]]] = now - _s["before"]
        _s["before"] = now
        _s["i"] += 1


def modules(names, where):
    # Heap taken by each module imported on its own (in dependency order), from ROMFS ("rom") or from .mpy files
    # on the filesystem ("files": read into the heap).
    gc.disable()
    _prepare()
    if where == "files":
        sys.path.remove("/rom")
        sys.path.insert(0, "/input/data/mpy")
    _imports(names)
    print(json.dumps(_s["out"]))
