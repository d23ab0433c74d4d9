# Driver: boot.py after a soft reset (Ctrl-D) that left PWM channels running on the motor pins, as on the ESP8266
# (esppwm.c's channels are C statics and outlive the Python heap), under CPython and inside MicroPython alike. Prints
# and returns what each GPIO puts out (machine.outputs(): a duty, 1023 for a pin held high) before and after boot.py.
import json

import machine


def _outputs():
    out = machine.outputs()
    return [[gpio, out[gpio]] for gpio in sorted(out)]


def main(boot_path, duties):
    """duties: [[gpio, duty], ...] running when the soft reset came."""
    machine.power_on()
    for gpio, duty in duties:
        machine.PWM(machine.Pin(gpio), freq=1000, duty=duty)
    before = _outputs()
    with open(boot_path) as f:
        exec(f.read(), {"__name__": "__main__"})
    out = {"before": before, "after": _outputs()}
    machine.power_on()
    print(json.dumps(out))
    return out
