# The board's entry point: MicroPython runs main.py after boot.py. Wires motors, rover and link, and runs the loop.
# Everything else is precompiled (.mpy); this file stays small because the board compiles it at every boot.
import gc
import sys
import time

import link
import machine
import motors
import rover


def run(path="config.json", steps=None):
    """Load the config, stop the motors, then step the rover every period_ms. `steps` bounds the loop (tests)."""
    import config

    cfg = config.load(path)
    del config
    del sys.modules["config"]  # the checks are done: give their RAM back
    gc.collect()
    if cfg["cpu_mhz"] == 160:
        machine.freq(160000000)
    m = motors.Motors(cfg["motors"])
    m.stop()
    r = rover.Rover(cfg, m)
    r.link = link.Link(cfg, r.on_message, r.on_connect)
    wdt = machine.WDT() if cfg["watchdog"] else None  # resets the board if a step ever hangs
    period = cfg["control"]["period_ms"]
    n = 0
    try:
        while steps is None or n < steps:
            t0 = time.ticks_ms()
            r.step(t0)  # never raises: an error stops the motors and is logged
            if wdt is not None:
                wdt.feed()
            n += 1
            rest = period - time.ticks_diff(time.ticks_ms(), t0)
            if rest > 0:
                time.sleep_ms(rest)
    finally:  # Ctrl-C from mpremote, or the end of a bounded run
        m.stop()
        r.link.close(r.status_payload("offline"))
    return r


if __name__ == "__main__":
    run()
