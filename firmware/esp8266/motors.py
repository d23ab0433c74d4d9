# Two DC motors through an H-bridge: one PWM pin (speed) and one or two direction pins per motor.
#
# Wiring (docs/firmware.md): the NodeMCU motor shield (L293D) takes PWM on D1/D2 (GPIO5, GPIO4) and direction on
# D3/D4 (GPIO0, GPIO2); an L298N takes ENA/ENB as PWM and IN1/IN2 as dir/dir2 (dir2 driven opposite to dir).
#
# Wheel speed <-> PWM duty, a model the simulator can invert: a motor does not turn below a deadband duty, then its
# speed grows about linearly with duty up to max_wheel_rad_s at full duty (1023):
#     duty = deadband + (1023 - deadband) * |w| / max_wheel_rad_s,   0 when |w| < min_wheel_rad_s.
# speed_for_duty() is its inverse (exact up to the rounding of duty to an integer).
from machine import PWM, Pin
from micropython import const

MAX_DUTY = const(1023)


def duty_for_speed(speed_rad_s, max_rad_s, deadband_duty, min_rad_s):
    """|wheel speed| (rad/s) -> PWM duty 0..1023."""
    s = abs(speed_rad_s)
    if s < min_rad_s or s <= 0.0:
        return 0
    d = int(deadband_duty + (MAX_DUTY - deadband_duty) * s / max_rad_s + 0.5)
    return MAX_DUTY if d > MAX_DUTY else d


def speed_for_duty(duty, forward, max_rad_s, deadband_duty):
    """PWM duty and direction -> wheel speed (rad/s, negative backwards): the inverse of duty_for_speed."""
    if duty <= deadband_duty:
        return 0.0
    s = (duty - deadband_duty) * max_rad_s / (MAX_DUTY - deadband_duty)
    return s if forward else -s


class _Motor:
    def __init__(self, pwm_pin, dir_pin, dir2_pin, invert, freq_hz):
        self.invert = invert
        self.dir = Pin(dir_pin, Pin.OUT, value=1 if invert else 0)
        self.dir2 = None if dir2_pin is None else Pin(dir2_pin, Pin.OUT, value=0 if invert else 1)
        self.pwm = PWM(Pin(pwm_pin), freq=freq_hz, duty_u16=0)  # created stopped
        self.duty = 0
        self.forward = True

    def set(self, duty, forward):
        if forward != self.forward and self.duty:
            self.pwm.duty(0)  # never reverse a turning motor at full voltage
        level = 1 if forward != self.invert else 0
        self.dir.value(level)
        if self.dir2 is not None:
            self.dir2.value(1 - level)
        self.pwm.duty(duty)
        self.duty = duty
        self.forward = forward


class Motors:
    """Left and right motors from the `motors` section of config.json."""

    def __init__(self, cfg):
        self.max_rad_s = cfg["max_wheel_rad_s"]
        self.deadband = cfg["deadband_duty"]
        self.min_rad_s = cfg["min_wheel_rad_s"]
        freq = cfg["freq_hz"]
        left = cfg["left"]
        right = cfg["right"]
        self.left = _Motor(left["pwm"], left["dir"], left.get("dir2"), left.get("invert", False), freq)
        self.right = _Motor(right["pwm"], right["dir"], right.get("dir2"), right.get("invert", False), freq)

    def drive(self, left_rad_s, right_rad_s):
        """Wheel speeds in rad/s (positive: forward)."""
        self.left.set(duty_for_speed(left_rad_s, self.max_rad_s, self.deadband, self.min_rad_s), left_rad_s >= 0.0)
        self.right.set(duty_for_speed(right_rad_s, self.max_rad_s, self.deadband, self.min_rad_s), right_rad_s >= 0.0)

    def stop(self):
        self.left.set(0, self.left.forward)
        self.right.set(0, self.right.forward)

    def speeds(self):
        """(left, right) wheel speeds, rad/s, that the duties now set stand for."""
        return (
            speed_for_duty(self.left.duty, self.left.forward, self.max_rad_s, self.deadband),
            speed_for_duty(self.right.duty, self.right.forward, self.max_rad_s, self.deadband),
        )
