# Driver: the rover's real program (app: start, loop, stop) with link.py and umqtt.simple against the scripted
# broker of fakenet.py, in simulated time, under CPython and inside MicroPython alike. The edge publishes three
# rovers' poses at 30 fps once the rover has subscribed; the rover ("red") drives towards its corner of a triangle;
# at `stall_ms` the case strikes. main() prints one JSON object: when the last whole own pose arrived, when the
# motors went off for good, and what the link did.
#
# The loop runs in chunks of CHUNK steps with collections only between them, from small frames (the wasm build frees
# heap-allocated frames of larger functions if a collection runs inside them: firmware/harness/runner.py).
import gc
import json
import sys

import app
import fakenet
import link
import machine
from umqtt import simple

MICROPYTHON = sys.implementation.name == "micropython"
ME = "red"
WORLD = (("red", 120.0, 100.0, 0.3), ("green", 250.0, 320.0, 2.0), ("blue", 330.0, 90.0, -1.0))
FORMATION = b'{"v":1,"seq":1,"kind":"triangle","ids":["red","green","blue"],"side":100.0}'
POSE = '{"v":1,"id":"%s","seq":%d,"frame":%d,"t":%d.%03d,"x":%s,"y":%s,"theta":%s,"vx":null,"vy":null,"q":1.0}'
FRAME_MS = 33
CHUNK = 1  # steps between collections: one step can wait for seconds of simulated traffic

# Where a case strikes. cut: the Wi-Fi drops after `cut` bytes of the first own pose packet sent at or after
# stall_ms (0: just before it); then nothing more arrives and the send buffer (2920 bytes, lwip's TCP_SND_BUF on the
# ESP8266) fills up. Other cases: see _strike().
CASES = {
    "boundary": {"cut": 0},
    "first byte": {"cut": 1},
    "remaining length": {"cut": 2},
    "topic length": {"cut": 4},
    "topic": {"cut": 15},
    "payload": {"cut": -20},
    "send buffer full": {"room": 0},
    "broker silent": {"silent": True},
    "broker never answers": {"never": True},
    "no SUBACK": {"no_suback": True},
    "oversize retained": {"oversize": 6000},
    "wifi back": {"cut": -20, "back_ms": 1000},
    "backlog": {"hold_ms": 1500},
    "ctrl-c": {"interrupt": True},
}

_s = {}


class _Edge:
    """Poses at 30 fps for the three rovers, to whoever subscribed; arranges the cut."""

    def __init__(self, broker, case, stall_ms):
        self.broker = broker
        self.case = case
        self.stall_ms = stall_ms
        self.frame = 0
        self.next_ms = 0
        self.own = []  # (connection, arrival ms, end offset in that connection's stream) of each own pose
        self.captured = {}  # frame -> capture ms, of own poses
        self.cut_done = False

    def __call__(self, now):
        b = self.broker
        if now < self.next_ms or b.conn is None:
            return
        self.next_ms = now + FRAME_MS
        self.frame += 1
        for rid, x, y, th in WORLD:
            t = 1763900000000 + now  # the edge's clock at capture, ms
            payload = (POSE % (rid, self.frame, self.frame, t // 1000, t % 1000, x, y, th)).encode()
            topic = b"ips/v1/rovers/" + rid.encode() + b"/pose"
            cut = self.case.get("cut")
            if rid == ME and cut is not None and not self.cut_done and now >= self.stall_ms:
                self.cut_done = True
                size = len(fakenet.publish_packet(topic, payload))
                b.cut_at = b.queued + (cut if cut >= 0 else size + cut)
                b.room = 2920
            at = b.publish(topic, payload)
            if rid == ME and at is not None:
                self.own.append((b.connections, at, b.queued))
                self.captured[self.frame] = now


def _motors(now):
    m = _s["motors"]
    on = m.left.duty > 0 or m.right.duty > 0
    if on != _s["on"]:
        _s["on"] = on
        _s["changes"].append((now, on))
        if on:  # the own pose it drives on (seq = frame here)
            r = _s["rover"]
            _s["drove_on"].append(r._seq[r._me] if r._me >= 0 else None)


def _strike(now):
    case = _s["case"]
    b = _s["broker"]
    if now == _s["stall_ms"]:
        if "room" in case:
            b.room = case["room"]
        if case.get("silent"):
            b.answers = False
            b.cut_at = b.queued  # nothing more is said on this connection either
        if case.get("interrupt"):
            _s["clock"].interrupt_at = now
        if "oversize" in case:
            b.publish(b"ips/v1/formation", FORMATION, 1)  # a legal formation after the dropped one
        if "hold_ms" in case:
            b.hold_until = now + case["hold_ms"]  # an outage TCP rides out: then everything at once, in order
    back = case.get("back_ms")
    if back is not None and now == _s["stall_ms"] + back:
        b.cut_at = None  # the air is back; the old TCP connection is gone for good
        b.conn = None


def _setup(case_name, path, stall_ms):
    case = CASES[case_name]
    clock = fakenet.Clock()
    broker = fakenet.Broker(clock)
    broker.retained = FORMATION
    if case.get("never"):
        broker.answers = False
    if case.get("no_suback"):
        broker.answers_subscribe = False
    if "oversize" in case:
        broker.retained = b'{"v":1,"pad":"' + b"x" * case["oversize"] + b'"}'
    net = fakenet.SocketModule(broker)
    _s["saved"] = (app.time, link.time, simple.socket)
    app.time = clock
    link.time = clock
    simple.socket = net
    machine.stop_timers()
    _s.update(
        case=case,
        clock=clock,
        broker=broker,
        net=net,
        stall_ms=stall_ms,
        on=False,
        changes=[],
        drove_on=[],
        log=[],
        interrupted=None,
    )
    edge = _Edge(broker, case, stall_ms)
    _s["edge"] = edge
    clock.watchers.append(edge)
    clock.watchers.append(_strike)
    clock.limit = stall_ms + 60000
    m, r = app.start(path, _log)
    _s["motors"] = m
    _s["rover"] = r
    _s["wd"] = app.Watchdog(m)
    _s["wd"].start()
    clock.watchers.append(_motors)


def _log(*args):
    line = " ".join([str(a) for a in args])
    _s["log"].append((_s["clock"].now, line))


def _chunk():
    # False once the run is over: the case's time has passed, or the loop was interrupted.
    try:
        app.loop(_s["rover"], _s["wd"], CHUNK)
    except KeyboardInterrupt:
        _s["interrupted"] = _s["clock"].now
        app.stop(_s["rover"], _s["wd"])
        _s["clock"].sleep_ms(_s["after_ms"])  # at the REPL: nothing runs, time passes
        return False
    return _s["clock"].now < _s["end_ms"]


def _summary():
    edge = _s["edge"]
    b = _s["broker"]
    r = _s["rover"]
    lk = r.link
    changes = _s["changes"]
    drove = [t for t, on in changes if on]
    stops = [t for t, on in changes if not on and t >= _s["stall_ms"]]
    off = stops[0] if stops else None
    # The freshest own pose the rover could have had when the motors went off: the last one that arrived whole.
    last = None
    for conn, at, end in edge.own:
        if end <= b.delivered[conn - 1] and (off is None or at <= off):
            last = at
    # When it drove again after the stall: how old (since capture) the own pose it drove on was.
    rejoin_age = None
    again = [t for t in drove if t > _s["stall_ms"]]
    if again:
        seq = _s["drove_on"][len(drove) - len(again)]
        rejoin_age = again[0] - edge.captured[seq]
    return {
        "stall_ms": _s["stall_ms"],
        "end_ms": _s["clock"].now,
        "first_drive_ms": drove[0] if drove else None,
        "drove_after_stall": again,
        "rejoin_pose_age_ms": rejoin_age,
        "stops": stops,
        "off_ms": off,
        "last_pose_ms": last,
        "on_at_end": _s["on"],
        "halt": r.halt,
        "connects": lk.connects,
        "drops": lk.drops,
        "waits": lk.stream.waits,
        "dropped_packets": lk.stream.dropped,
        "watchdog_bites": _s["wd"].bites,
        "timers_armed": len(machine._timers),
        "lookups": _s["net"].lookups,
        "disconnects": b.disconnects,
        "published": [p[1].decode() for p in b.published],
        "interrupted_ms": _s.get("interrupted"),
        "log": [str(t) + " " + line for t, line in _s["log"]][-12:],
    }


def _restore():
    app.time, link.time, simple.socket = _s["saved"]
    machine.stop_timers()


OPTIONS = {"stall_ms": 3000, "run_ms": 4000, "after_ms": 3000}  # when the case strikes; how long the run goes on


def timing(stall_ms, run_ms, after_ms):
    OPTIONS["stall_ms"] = stall_ms
    OPTIONS["run_ms"] = run_ms
    OPTIONS["after_ms"] = after_ms


def _run():
    # Every frame alive during gc.collect() is small (firmware/harness/runner.py).
    try:
        while _chunk():
            if MICROPYTHON:  # CPython needs no help, and its collections are slow in a big test process
                gc.collect()
        if _s.get("interrupted") is None:
            app.stop(_s["rover"], _s["wd"])
        _s["out"] = _summary()
    finally:
        _restore()


def main(case_name, path):
    """Run one case (OPTIONS: its timing); print and return its summary."""
    gc.disable()
    _s["end_ms"] = OPTIONS["stall_ms"] + OPTIONS["run_ms"]
    _s["after_ms"] = OPTIONS["after_ms"]
    _setup(case_name, path, OPTIONS["stall_ms"])
    _run()
    print(json.dumps(_s["out"]))
    return _s["out"]


def _exec_main(directory):
    # The board runs main.py as __main__ from its filesystem, whose working directory holds config.json.
    import os

    here = os.getcwd()
    os.chdir(directory)
    try:
        with open("main.py") as f:
            exec(f.read(), {"__name__": "__main__"})
    except KeyboardInterrupt:
        _s["interrupted"] = _s["clock"].now
    finally:
        try:
            os.chdir(here)
        except OSError:  # WASI cannot go back to "/", which it never opened
            pass


def board(directory, interrupt_ms):
    """main.py as the board runs it (boot.py first), against the scripted broker, until Ctrl-C at interrupt_ms;
    prints and returns what it did. No collection runs (the run is short): nothing here needs small frames."""
    import network

    gc.disable()
    case = {}
    clock = fakenet.Clock()
    broker = fakenet.Broker(clock)
    broker.retained = FORMATION
    net = fakenet.SocketModule(broker)
    _s["saved"] = (app.time, link.time, simple.socket)
    app.time = link.time = clock
    simple.socket = net
    machine.power_on()  # a chip just powered: no timer, no PWM channel, no pin driven
    _s.update(case=case, clock=clock, broker=broker, net=net, on=False, changes=[], log=[], interrupted=None)
    edge = _Edge(broker, case, 1 << 30)
    clock.watchers.append(edge)
    clock.watchers.append(_board_motors)
    clock.interrupt_at = interrupt_ms
    machine.board = _Pins()
    try:
        with open(directory + "/boot.py") as f:
            exec(f.read(), {"__name__": "__main__"})
        _exec_main(directory)
        clock.sleep_ms(1000)  # at the REPL: nothing runs
        out = {
            "interrupted_ms": _s["interrupted"],
            "first_drive_ms": ([t for t, on in _s["changes"] if on] or [None])[0],
            "changes": _s["changes"],
            "pins": machine.board.levels,
            "pwm_max": machine.board.pwm_max,
            "ap_active": network.ap_active(),
            "station_pm": network.station_pm(),
            "timers_armed": len(machine._timers),
            "connections": broker.connections,
            "subscribed": [t.decode() for t in broker.subscribed],
            "published": [p[1].decode() for p in broker.published],
            "disconnects": broker.disconnects,
        }
    finally:
        machine.board = None
        _restore()
    print(json.dumps(out))
    return out


class _Pins:
    """What the machine stand-in reports while main.py runs: every pin level and the motors' PWM duties."""

    def __init__(self):
        self.levels = {}
        self.duty = {}
        self.pwm_max = 0

    def pin_set(self, gpio, level):
        if str(gpio) not in self.levels:  # the first level each pin was driven to
            self.levels[str(gpio)] = level

    def pwm_set(self, gpio, duty):
        self.duty[gpio] = duty
        if duty > self.pwm_max:
            self.pwm_max = duty


def _board_motors(now):
    on = False
    for gpio in machine.board.duty:
        if machine.board.duty[gpio] > 0:
            on = True
    if on != _s["on"]:
        _s["on"] = on
        _s["changes"].append((now, on))
