# config.json: defaults, checks, loading. Imported once at boot by app.py and then dropped (its module objects and
# the defaults table are ~3 KB of the ESP8266's 36 KB heap); the host harness and the flash tool use the same checks.
import json

import msg

DEFAULTS = {
    "id": "",
    "wifi": {"ssid": "", "password": ""},
    "broker": {"host": "", "port": 1883, "user": "", "password": "", "keepalive_s": 10, "timeout_s": 2},
    "motors": {
        "freq_hz": 1000,
        "left": {"pwm": 5, "dir": 0, "dir2": None, "invert": False},
        "right": {"pwm": 4, "dir": 2, "dir2": None, "invert": False},
        "max_wheel_rad_s": 15.0,
        "deadband_duty": 250,
        "min_wheel_rad_s": 0.3,
    },
    "geometry": {"wheel_radius_cm": 3.25, "track_cm": 13.0, "body_radius_cm": 14.0, "lookahead_cm": 6.0},
    "control": {
        "period_ms": 20,
        "stale_ms": 400,
        "fade_ms": 100,
        "forget_ms": 10000,
        "latency_ms": 50,
        "gain_per_s": 1.0,
        "anchor_gain_per_s": 2.0,
        "max_speed_cm_s": 45.0,
        "min_speed_cm_s": 4.0,
        "hold_cm": 1.0,
        "safety_cm": 30.0,
        "barrier_gain_per_s": 4.0,
        "slide_gain": 1.0,
        "pass_cm": 3.0,
        "heading_margin_rad": 0.35,
        "ring_gap_cm": 1.0,
        "heading_fix_cm": 6.0,
        "probe_speed_cm_s": 12.0,
    },
    "watchdog": True,
    "cpu_mhz": 160,
}

# (section, key, lowest, highest, whole) for every number a config may carry. whole: the firmware hands it to calls
# that take only ints on the chip (time.sleep_ms, struct.pack, PWM, sockets), where 20.0 is a TypeError in the loop,
# not at boot. (Kept in one table so that checking builds no strings: this runs at the heap's peak.)
_NUMBERS = (
    ("broker", "port", 1, 65535, True),
    ("broker", "keepalive_s", 2, 3600, True),
    ("broker", "timeout_s", 0.1, 30, False),
    ("motors", "freq_hz", 100, 1000, True),
    ("motors", "max_wheel_rad_s", 0.1, 200, False),
    ("motors", "deadband_duty", 0, 1000, True),
    ("motors", "min_wheel_rad_s", 0, 10, False),
    ("geometry", "wheel_radius_cm", 0.5, 20, False),
    ("geometry", "track_cm", 2, 100, False),
    ("geometry", "body_radius_cm", 1, 100, False),
    ("geometry", "lookahead_cm", 0.5, 50, False),
    ("control", "period_ms", 5, 200, True),
    ("control", "stale_ms", 50, 5000, True),
    ("control", "fade_ms", 0, 5000, True),
    ("control", "forget_ms", 500, 600000, True),
    ("control", "latency_ms", 0, 1000, True),
    ("control", "gain_per_s", 0.001, 10, False),
    ("control", "anchor_gain_per_s", 0, 10, False),
    ("control", "max_speed_cm_s", 1, 200, False),
    ("control", "min_speed_cm_s", 0, 50, False),
    ("control", "hold_cm", 0, 20, False),
    ("control", "safety_cm", 1, 500, False),
    ("control", "barrier_gain_per_s", 0.1, 100, False),
    ("control", "slide_gain", 0, 10, False),
    ("control", "pass_cm", 0, 100, False),
    ("control", "heading_margin_rad", 0, 1.5, False),
    ("control", "ring_gap_cm", 0, 100, False),
    ("control", "heading_fix_cm", 1, 100, False),
    ("control", "probe_speed_cm_s", 0, 50, False),
)

# The GPIOs the port's PWM drives (esppwm.c's pin_num); PWM() on any other raises ValueError, in boot.py too.
_PWM_GPIOS = (0, 2, 4, 5, 12, 13, 14, 15)

# GPIOs the ESP8266 reads at reset to choose how to boot: a motor driver that pulls them the wrong way at power-on
# stops the board from booting (or boots it into the serial bootloader).
_STRAPPING = {
    0: "must be high at reset (low: serial bootloader)",
    2: "must be high at reset",
    15: "must be low at reset (most boards pull it down)",
}


def merge(defaults, given):
    """A new dict: defaults overlaid with the given config, section by section."""
    out = {}
    for k in defaults:
        d = defaults[k]
        if k in given:
            g = given[k]
            out[k] = merge(d, g) if type(d) is dict and type(g) is dict else g
        else:
            out[k] = merge(d, {}) if type(d) is dict else d
    for k in given:
        if k not in out:
            out[k] = given[k]
    return out


def check(cfg):
    """Raises ValueError("key motors.left.pwm: ...") for the first problem in a merged config."""
    for k in cfg:
        if k not in DEFAULTS:
            raise ValueError("unknown key " + k)
    for section in DEFAULTS:
        d = DEFAULTS[section]
        if type(d) is dict:
            if type(cfg[section]) is not dict:
                raise ValueError("key " + section + ": expected an object")
            for k in cfg[section]:
                if k not in d:
                    raise ValueError("unknown key " + section + "." + k)
    if not msg.is_id(cfg["id"]):
        raise ValueError("key id: expected 1-16 characters of a-z, 0-9, _ and -, got " + repr(cfg["id"]))
    host = cfg["broker"]["host"]
    if type(host) is not str or not host:
        raise ValueError("key broker.host: expected the broker's host name or address")
    for section, key, lo, hi, whole in _NUMBERS:
        v = cfg[section][key]
        if type(v) is not int and (type(v) is not float or whole):
            what = "a whole number" if whole else "a number"
            raise ValueError("key " + section + "." + key + ": expected " + what + ", got " + repr(v))
        if not (lo <= v <= hi):
            name = "key " + section + "." + key
            raise ValueError(name + ": " + repr(v) + " is outside " + repr(lo) + ".." + repr(hi))
    used = {}  # type: dict[int, str]
    for side in ("left", "right"):
        m = cfg["motors"][side]
        if type(m) is not dict:
            raise ValueError("key motors." + side + ": expected an object")
        for k in m:
            if k not in ("pwm", "dir", "dir2", "invert"):
                raise ValueError("unknown key motors." + side + "." + k)
        for k in ("pwm", "dir", "dir2"):
            v = m.get(k)
            if v is None and k == "dir2":
                continue
            name = "key motors." + side + "." + k
            if type(v) is not int or not (0 <= v <= 16):
                raise ValueError(name + ": expected a GPIO number 0-16, got " + repr(v))
            if 6 <= v <= 11:
                raise ValueError(name + ": GPIO " + str(v) + " is wired to the flash chip (GPIO 6-11)")
            if v == 1 or v == 3:  # driving UART0's pins silences the REPL: no Ctrl-C, mpremote or flash tool
                raise ValueError(name + ": GPIO " + str(v) + " is the serial REPL (GPIO 1 TX, 3 RX)")
            if k == "pwm" and v not in _PWM_GPIOS:
                raise ValueError(name + ": GPIO " + str(v) + " has no PWM on the ESP8266")
            if v in used:
                raise ValueError(name + ": GPIO " + str(v) + " is already " + used[v])
            used[v] = "motors." + side + "." + k
        if type(m.get("invert", False)) is not bool:
            raise ValueError("key motors." + side + ".invert: expected true or false")
    for section, key in (("wifi", "ssid"), ("wifi", "password"), ("broker", "user"), ("broker", "password")):
        if type(cfg[section][key]) is not str:
            raise ValueError("key " + section + "." + key + ": expected a string")
    if cfg["cpu_mhz"] not in (80, 160):
        raise ValueError("key cpu_mhz: expected 80 or 160, got " + repr(cfg["cpu_mhz"]))
    if type(cfg["watchdog"]) is not bool:
        raise ValueError("key watchdog: expected true or false")
    g = cfg["geometry"]
    if cfg["control"]["fade_ms"] >= cfg["control"]["stale_ms"]:
        raise ValueError("key control.fade_ms: must be below control.stale_ms (the rover slows down in between)")
    if cfg["control"]["safety_cm"] < 2 * g["body_radius_cm"]:
        raise ValueError("key control.safety_cm: must be at least 2 * geometry.body_radius_cm (bodies would touch)")
    return cfg


def warnings(cfg):
    """What a checked config allows but a user should know: motor pins on the boot-strapping GPIOs."""
    out = []
    for side in ("left", "right"):
        m = cfg["motors"][side]
        for k in ("pwm", "dir", "dir2"):
            v = m.get(k)
            if v in _STRAPPING:
                out.append("motors." + side + "." + k + " on GPIO " + str(v) + ": " + _STRAPPING[v])
    return out


def load(path):
    """config.json -> the merged, checked config (ValueError names the key at fault)."""
    with open(path) as f:
        given = json.load(f)
    if type(given) is not dict:
        raise ValueError("expected a JSON object")
    return check(merge(DEFAULTS, given))
