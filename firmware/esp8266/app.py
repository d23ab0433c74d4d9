# The rover's program: loads the config, wires motors, rover and link, and runs the control loop under a software
# watchdog. main.py calls run() at every boot, after boot.py has driven the motor driver's PWM pins low.
#
# Interrupting it is always safe and final: Ctrl-C (or an mpremote connection, which sends one) stops the watchdog,
# stops the motors and says goodbye to the broker, and nothing restarts the loop until the board is reset. That is
# why the watchdog is a machine.Timer and not machine.WDT: on the ESP8266 a started WDT cannot be stopped and the
# REPL does not feed it (ports/esp8266/machine_wdt.c, ets_alt_task.c), so an interrupted rover would reset a few
# seconds later, run main.py again and drive on the retained formation.
#
# A failure before the loop (a bad config.json, a broken module) leaves the motors off, logs one line, publishes an
# "error" status when the config got far enough to reach the broker, and waits there: no reboot loop.
import sys
import time

import link
import machine
import motors
import msg
import rover
from micropython import const

_WATCHDOG_PERIOD_MS = const(50)
_WATCHDOG_LIMIT_MS = const(150)  # no finished step for this long: the motors stop
_FAILED_POLL_MS = const(200)


class Watchdog:
    """Stops the motors when the loop has not finished a step for limit_ms: a call that blocks where nothing was
    expected to. The timer's callback runs between bytecodes and inside every wait of the port (socket waits,
    sleep_ms), so it acts while the loop is stuck. It never resets the board; start() arms it, stop() disarms it for
    good. Made unarmed, so that the code that arms it can already hold it where a finally disarms it."""

    def __init__(self, motors, limit_ms=_WATCHDOG_LIMIT_MS):
        self.motors = motors
        self.limit_ms = limit_ms
        self.fed = time.ticks_ms()
        self.bites = 0
        self.timer = machine.Timer(-1)  # not armed until start()

    def start(self):
        self.fed = time.ticks_ms()
        self.timer.init(mode=machine.Timer.PERIODIC, period=_WATCHDOG_PERIOD_MS, callback=self._check)

    def feed(self):
        self.fed = time.ticks_ms()

    def _check(self, timer):
        try:
            if time.ticks_diff(time.ticks_ms(), self.fed) > self.limit_ms:
                self.motors.stop()
                self.bites += 1
        except Exception:  # an exception here would be raised inside the loop, wherever it was
            pass

    def stop(self):
        self.timer.deinit()


def start(path, log=print):
    """config.json -> (motors, rover with its link): everything the loop needs, the motors stopped."""
    return build(configure(path, log), log)


def configure(path, log=print):
    """config.json merged with the defaults and checked (ValueError names the key at fault); the checks are
    dropped from RAM afterwards."""
    import config

    cfg = config.load(path)
    for text in config.warnings(cfg):
        log("config:", text)
    del config
    del sys.modules["config"]  # the checks are done: the next collection takes their RAM back
    return cfg


def build(cfg, log=print):
    """Motors (stopped), rover and link from a checked config."""
    if cfg["cpu_mhz"] == 160:
        machine.freq(160000000)
    m = motors.Motors(cfg["motors"])
    m.stop()
    r = rover.Rover(cfg, m, log=log)
    r.link = link.Link(cfg, r.on_message, r.on_connect, log, m.stop)
    return m, r


def run(path="config.json", steps=None, log=print):
    """The board's program. `steps` bounds the loop (tests); returns the rover."""
    try:
        m, r = start(path, log)
    except Exception as e:
        _failed(e, path, steps, log)
        return None
    wd = Watchdog(m) if r.watchdog else None  # unarmed: a Ctrl-C up to the try leaves nothing running
    try:
        if wd is not None:
            wd.start()  # armed inside the try: a Ctrl-C right after it still reaches the finally
        loop(r, wd, steps)
    finally:  # Ctrl-C, an mpremote connection, or the end of a bounded run: stop for good
        stop(r, wd)
    return r


def loop(r, wd, steps=None):
    """Step the rover every period_ms (`steps` times; None: for ever), feeding the watchdog after each step."""
    period = r.period_ms
    n = 0
    while steps is None or n < steps:
        t0 = time.ticks_ms()
        r.step(t0)  # never raises: an error stops the motors and is logged
        if wd is not None:
            wd.feed()
        n += 1
        rest = period - time.ticks_diff(time.ticks_ms(), t0)
        if rest > 0:
            time.sleep_ms(rest)


def stop(r, wd):
    """The end of the loop, whatever ended it: the motors off, the watchdog disarmed, an offline status. A second
    Ctrl-C (a user pressing it twice) lands wherever the first one's stop has got to: each part runs whatever
    interrupted the one before, the motors first (a disarmed watchdog cannot stop them any more) and again last."""
    try:
        r.motors.stop()
    finally:
        try:
            if wd is not None:
                wd.stop()
        finally:
            try:
                r.motors.stop()
            finally:
                r.link.close(r.status_payload("offline"))


def _failed(e, path, steps, log):
    # The motors are off (boot.py drove their pins low; start() had not driven them). Say why once, tell the broker
    # if the config names one, and wait here.
    log("rover not started:", repr(e))
    lk = _error_link(path, log)
    n = 0
    while steps is None or n < steps:
        if lk is not None:
            was_up = lk.up
            if lk.poll(time.ticks_ms()) and not was_up:
                lk.publish_status(msg.rover_status(lk.id, "online", rover.HALT_ERROR, None, None, None))
        n += 1
        time.sleep_ms(_FAILED_POLL_MS)
    if lk is not None:
        lk.close()


def _error_link(path, log):
    try:
        import config

        cfg = config.load(path)
        return link.Link(cfg, _ignore, None, log)
    except Exception:  # the config itself is what failed: nobody to tell
        return None


def _ignore(topic, payload):
    pass
