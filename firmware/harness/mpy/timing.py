# MicroPython driver: time per call of the parser and of one control step, in microseconds (ticks_us).
# Collections happen between batches, are not timed, and run only from small frames (firmware/harness/runner.py).
# Each figure is the fastest of 20 batches of 100 calls: the machine is shared, and the minimum is the least noisy.
import binascii
import gc
import json
import time

import msg
import rover as rv
from replay import Motors


def _example(name):
    with open("/input/examples/valid/" + name, "rb") as f:
        return f.read().strip()


POSE = _example("pose-red-moving.json")
SPACED = _example("pose-reordered-spaced.json")
FORMATION = _example("formation-line.json")
GARBAGE = b'{"v":1,"id":"red","seq":42 "frame":1234}'

_D = json.loads(POSE)


def _scan(b):
    msg._strict_object(b, 160)


def _canonical(b):
    msg._canonical_pose(b, _D)


CASES = (
    ("parse_pose_canonical_us", msg.parse_pose, POSE),
    ("syntax_fast_path_us", _canonical, POSE),
    ("syntax_strict_scan_us", _scan, POSE),
    ("parse_pose_spaced_us", msg.parse_pose, SPACED),
    ("parse_pose_invalid_us", msg.parse_pose, GARBAGE),
    ("parse_formation_us", msg.parse_formation, FORMATION),
    ("json_loads_us", json.loads, POSE),
)
BATCHES = 20
N = 100
N_STEPS = 40  # a step allocates ~7 KB here (floats are boxed): 40 of them stay well inside the heap between collections

_r = {}
_s = {}


def _parse_batch(k):
    name, fn, arg = CASES[k]
    t0 = time.ticks_us()
    for _ in range(N):
        fn(arg)
    _r[name] = min(_r.get(name, 1 << 29), time.ticks_diff(time.ticks_us(), t0))


def _setup_rover():
    # A rover that has a formation and three fresh poses (replay.py's input format).
    with open("/input/data/events") as f:
        lines = f.read().split("\n")
    _s["rover"] = rv.Rover(json.loads(lines[0]), Motors(), log=lambda *a: None)
    msgs = []
    for line in lines[1:]:
        p = line.split(" ")
        if p[0] == "m":
            msgs.append((p[2].encode(), binascii.unhexlify(p[3])))
    _s["msgs"] = msgs
    _s["t"] = 100000


def _replay(start):
    # Messages start..start+20 (and a step every 20 ms), so the rover has its formation and drives.
    r = _s["rover"]
    msgs = _s["msgs"]
    t = start * 7
    for k in range(start, min(start + 20, len(msgs))):
        r._now = t
        r.on_message(msgs[k][0], msgs[k][1])
        t += 7
        if t % 20 < 7:
            r.step(t)
    _s["t"] = t + 20
    return start + 20 < len(msgs)


def _split_t(payload):
    # (text before the capture time's digits, its value in ms, text after them)
    a = payload.find(b'"t":') + 4
    b = payload.find(b",", a)
    sec, _, frac = payload[a:b].partition(b".")
    return payload[:a], int(sec) * 1000 + int((frac + b"000")[:3]), payload[b:]


def _dated(parts, ms):
    return parts[0] + (b"%d.%03d" % (ms // 1000, ms % 1000)) + parts[2]


def _prepare_frames():
    # The last frame's three poses again and again, each time captured 20 ms later than the time before, as the
    # rover's clock moves on 20 ms: the rover drives on young poses (repeating the same t would age them to stale).
    # Built before the timed batch, outside it.
    msgs = _s["msgs"]
    k = len(msgs) - 3
    frames = []
    for i in range(N_STEPS):
        dt = _s["dt"] + 20 * i
        frames.append([(msgs[k + j][0], _dated(_s["parts"][j], _s["parts"][j][1] + dt)) for j in range(3)])
    _s["dt"] += 20 * N_STEPS
    _s["frames"] = frames


def _step_batch(unused):
    r = _s["rover"]
    frames = _s["frames"]
    t = _s["t"]
    t0 = time.ticks_us()
    for i in range(N_STEPS):
        r._now = t
        f = frames[i]
        r.on_message(f[0][0], f[0][1])  # the three poses of a frame, then the step
        r.on_message(f[1][0], f[1][1])
        r.on_message(f[2][0], f[2][1])
        r.step(t)
        t += 20
    _s["t"] = t
    key = "three_poses_and_step_us"
    _r[key] = min(_r.get(key, 1 << 29), time.ticks_diff(time.ticks_us(), t0))


def _repeat(job, k):
    for _ in range(BATCHES):
        job(k)
        gc.collect()


def main():
    gc.disable()
    for k in range(len(CASES)):
        _repeat(_parse_batch, k)
    _setup_rover()
    k = 0
    while _replay(k):
        gc.collect()
        k += 20
    gc.collect()
    k = len(_s["msgs"]) - 3
    _s["parts"] = [_split_t(_s["msgs"][k + j][1]) for j in range(3)]
    _s["dt"] = 20
    for _ in range(BATCHES):
        _prepare_frames()
        gc.collect()
        _step_batch(0)
        gc.collect()
    for name in _r:
        _r[name] = _r[name] / (N_STEPS if name == "three_poses_and_step_us" else N)
    _r["halt"] = _s["rover"].halt
    print(json.dumps(_r))
