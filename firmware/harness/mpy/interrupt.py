# Driver: Ctrl-C landing right after a given call did its work (the port raises a pending KeyboardInterrupt at the
# next bytecode): main() a second one inside app.stop, after each of its parts; run() the first one inside app.run,
# after each step of its start. Prints one JSON line per case: the duties and the timers armed after it. Runs
# unchanged in CPython and MicroPython.
import json

import app
import machine


def _quiet(*args):
    pass


def _interrupt_after(obj, name):
    done = getattr(obj, name)

    def call(*args, **kwargs):
        setattr(obj, name, done)  # once
        done(*args, **kwargs)
        raise KeyboardInterrupt()

    setattr(obj, name, call)


def main(path):
    for where in ("motors.stop", "watchdog.stop", "timer.deinit", "left.set"):
        machine.stop_timers()
        m, r = app.start(path, _quiet)
        wd = app.Watchdog(m)
        wd.start()
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


def run(path):
    """app.run interrupted right after its start (motors and link built) and right after the watchdog's timer was
    armed: whatever the window, the timer must end disarmed (an armed machine.Timer outlives the loop, and a soft
    reset frees the callback it fires into) and the motors off."""
    for where in ("app.start", "Timer.init"):
        machine.power_on()
        owner = {"app.start": app, "Timer.init": machine.Timer}[where]
        _interrupt_after(owner, where.split(".")[1])
        interrupted = False
        try:
            app.run(path, 0, _quiet)  # no step: the loop itself never runs
        except KeyboardInterrupt:
            interrupted = True
        duties = [d for d in machine._pwm if d is not None]  # the motors' PWM channels
        print(json.dumps([where, interrupted, len(machine._timers), max(duties or [0])]))
    machine.power_on()
