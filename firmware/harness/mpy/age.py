# MicroPython driver: how the rover dates poses. Each function takes its cases and returns its results as plain
# lists; main(name) reads the cases from /input/data/<name> (one JSON list) and prints the results as one JSON line.
# tests/test_firmware_age.py runs the same functions in CPython and compares.
import gc
import json

import formation as fm
import msg
import rover as rv


def t_ms(payloads):
    # Each pose payload (a str of hex digits) -> its t in ms modulo 2**26, or None when the pose is refused.
    import binascii

    out = []
    for hexed in payloads:
        p = msg.parse_pose(binascii.unhexlify(hexed))
        out.append(None if p is None else p[3])  # t_ms (msg._P_T, a private const: no attribute in MicroPython)
    return out


def t_alloc(payloads):
    # [hex payload, repeats] -> bytes of heap the extraction of t took over that many repeats (the parse around it
    # allocates; finding t's digits and reading them must not).
    import binascii

    out = []
    for hexed, repeats in payloads:
        b = binascii.unhexlify(hexed)
        gc.collect()
        before = gc.mem_alloc()
        for _ in range(repeats):
            msg._t_ms(b, msg._t_at(b))
        out.append(gc.mem_alloc() - before)
    return out


def clock(cases):
    # Each case: [[receive tick, t ms], ...] of one rover's own poses -> [[excess ms, ...], restarts].
    out = []
    for rows in cases:
        c = rv.PoseClock()
        excess = []
        for r, t in rows:
            excess.append(c.own(r, t))
        out.append([excess, c.restarts])
    return out


def heading(cases):
    # Each case: a list of ["m", v, w, dt_s] (a step's command) and ["p", x, y, theta or None, age_ms] (an own pose)
    # rows -> the estimate (theta, spread, known) after each pose.
    out = []
    for rows in cases:
        h = fm.Heading(6.0)
        got = []
        for row in rows:
            if row[0] == "m":
                h.moved(row[1], row[2], row[3], 0.5)
            else:
                h.measured(row[1], row[2], row[3], row[4])
                got.append([h.theta, h.spread, h.known])
        out.append(got)
    return out


def main(name):
    gc.disable()
    with open("/input/data/" + name) as f:
        cases = json.loads(f.read())
    print(json.dumps(globals()[name](cases)))
