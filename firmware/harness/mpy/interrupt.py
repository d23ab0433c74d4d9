# Driver: a second Ctrl-C landing inside app.stop, right after each of its parts did its work (the port raises a
# pending KeyboardInterrupt at the next bytecode). Prints one JSON line per case: the duties and the timers armed
# after it. Runs unchanged in CPython and MicroPython.
import json

import app
import machine


def _quiet(*args):
    pass


def _interrupt_after(obj, name):
    done = getattr(obj, name)

    def call(*args):
        setattr(obj, name, done)  # once
        done(*args)
        raise KeyboardInterrupt()

    setattr(obj, name, call)


def main(path):
    for where in ("motors.stop", "watchdog.stop", "timer.deinit", "left.set"):
        machine.stop_timers()
        m, r = app.start(path, _quiet)
        wd = app.Watchdog(m)
        m.drive(5.0, -5.0)
        owner = {"motors.stop": m, "watchdog.stop": wd, "timer.deinit": wd.timer, "left.set": m.left}[where]
        _interrupt_after(owner, where.split(".")[1])
        interrupted = False
        try:
            app.stop(r, wd)
        except KeyboardInterrupt:
            interrupted = True
        print(json.dumps([where, interrupted, m.left.duty, m.right.duty, len(machine._timers)]))
    machine.stop_timers()
