# Pose and formation messages (contract v1, shared/schema/) from bytes to small tuples, or None; the rover's own
# status (rover status v2) from its fields to canonical bytes.
#
# Never raises and never allocates more than the message itself: the payload size is checked before anything else
# (pose <= 160 bytes, formation <= 512). MicroPython's json.loads is lenient: it skips missing or doubled commas
# and colons, accepts 01, 5., 1.e5, trailing commas, "true1", a ] closing a {, and bytes after a NUL. So json.loads
# only builds the values (checked field by field against the schema) and the syntax is checked separately:
#   - fast path, for the canonical bytes the edge writes (edge.messages.encode_pose: no spaces, fixed key order):
#     every structural character is counted (C-speed bytes.count) and found at its place, and each number token is
#     checked for the two leniencies a lone number can still carry (leading zero, dot without a digit after it);
#   - slow path, for anything else (spaces, other key order, escapes, formations): a byte-by-byte RFC 8259 scan.
# The fast path costs about a third of the scan (benchmarks/bench_firmware.py), which matters at 90 poses a second
# on an 80 MHz ESP8266.
# The capture time t is read twice: json.loads checks its range (0 <= t < 1e10, the schema), and its digits give
# t in whole milliseconds modulo 2**26 (_T_WRAP, 18.6 hours), exactly: a Unix time needs 41 bits in ms and a float of
# the ESP8266 keeps 22 (its step near 1.7e9 s is 4 minutes), so the float can only be range-checked. The digits are
# read from the payload in place (no slice, no string, no big int: every intermediate stays below 2**30, the chip's
# small-int limit). Rovers use it only for the differences between poses' ages (rover.py, "Pose ages").
# Non-ASCII bytes are refused outright: in a valid v1 message they could only sit in a key or an id, and neither
# may contain them. Booleans are not numbers (type(True) is not int on either interpreter), ints may stand for
# floats and not the reverse, NaN and Infinity are not JSON.
import json

from micropython import const

_POSE_MAX_BYTES = const(160)
_FORMATION_MAX_BYTES = const(512)
_MAX_COUNTER = const(999_999_999)
_MAX_IDS = const(16)
_T_WRAP = const(1 << 26)  # a pose's t in ms is kept modulo this (18.6 hours); it divides time.ticks_ms()'s 2**30
_T_MASK = const((1 << 26) - 1)
_EXP_CAP = const(999)  # an exponent beyond this shifts every digit out, or the range check refused t already

# Pose tuple fields, in wire order (the version "v" is checked, not returned). Every const here is private, folded
# into the bytecode: a public one is an entry in the module's dict on the chip (rover.py keeps its own copies).
_P_ID = const(0)
_P_SEQ = const(1)
_P_FRAME = const(2)
_P_T = const(3)
_P_X = const(4)
_P_Y = const(5)
_P_THETA = const(6)
_P_VX = const(7)
_P_VY = const(8)
_P_Q = const(9)

# Formation tuple fields.
_F_SEQ = const(0)
_F_KIND = const(1)
_F_IDS = const(2)
_F_SPACING = const(3)
_F_SIDE = const(4)
_F_X = const(5)
_F_Y = const(6)
_F_THETA = const(7)

KINDS = ("line", "rendezvous", "triangle", "stop")
_POSE_KEYS = ("v", "id", "seq", "frame", "t", "x", "y", "theta", "vx", "vy", "q")
_FORMATION_KEYS = ("v", "seq", "kind", "ids", "spacing", "side", "x", "y", "theta")
_FORMATION_REQUIRED = const(4)  # v, seq, kind, ids; the rest default to null (FormationV1 defaults)
_MAX_DEPTH = const(3)

_MAX_ABS_CM = 9999.99
_MAX_ABS_CM_S = 999.9
_THETA_LIMIT = 3.1416
_T_LIMIT = 1e10
# On the ESP8266 (30-bit floats) the largest valid t, 9999999999.999, is the same float as the limit itself: there
# the limit counts as allowed (the float t is only range-checked), or the contract's longest valid pose would be
# refused.
_T_COARSE = 9999999999.999 == _T_LIMIT
_LENGTH_LIMIT = 1000.0


# -- strict JSON syntax (RFC 8259), byte by byte -----------------------------------------------------------------
def _ws(b, i, n):
    while i < n:
        c = b[i]
        if c != 32 and c != 10 and c != 13 and c != 9:
            return i
        i += 1
    return i


def _string(b, i, n):
    # b[i] is the opening quote; returns the index after the closing quote.
    i += 1
    while i < n:
        c = b[i]
        if c == 34:  # "
            return i + 1
        if c < 32:
            raise ValueError
        if c == 92:  # backslash
            i += 1
            if i >= n:
                raise ValueError
            c = b[i]
            if c == 117:  # \uXXXX
                if i + 4 >= n:
                    raise ValueError
                for k in range(1, 5):
                    h = b[i + k]
                    if not (48 <= h <= 57 or 65 <= h <= 70 or 97 <= h <= 102):
                        raise ValueError
                i += 4
            elif c not in b'"\\/bfnrt':
                raise ValueError
        i += 1
    raise ValueError


def _digits(b, i, n):
    start = i
    while i < n and 48 <= b[i] <= 57:
        i += 1
    if i == start:
        raise ValueError
    return i


def _number(b, i, n):
    if b[i] == 45:  # -
        i += 1
        if i >= n:
            raise ValueError
    if b[i] == 48:  # a leading 0 stands alone
        i += 1
    else:
        i = _digits(b, i, n)
    if i < n and b[i] == 46:  # .
        i = _digits(b, i + 1, n)
    if i < n and (b[i] == 101 or b[i] == 69):  # e E
        i += 1
        if i < n and (b[i] == 43 or b[i] == 45):
            i += 1
        i = _digits(b, i, n)
    return i


def _literal(b, i, n, word):
    m = len(word)
    if i + m > n:
        raise ValueError
    for k in range(m):
        if b[i + k] != word[k]:
            raise ValueError
    return i + m


def _value(b, i, n, depth):
    if i >= n:
        raise ValueError
    c = b[i]
    if c == 34:
        return _string(b, i, n)
    if c == 123 or c == 91:  # { [
        if depth >= _MAX_DEPTH:
            raise ValueError
        close = 125 if c == 123 else 93
        i = _ws(b, i + 1, n)
        if i < n and b[i] == close:
            return i + 1
        while True:
            if c == 123:
                if i >= n or b[i] != 34:
                    raise ValueError
                i = _ws(b, _string(b, i, n), n)
                if i >= n or b[i] != 58:  # :
                    raise ValueError
                i = _ws(b, i + 1, n)
            i = _ws(b, _value(b, i, n, depth + 1), n)
            if i >= n:
                raise ValueError
            if b[i] == close:
                return i + 1
            if b[i] != 44:  # ,
                raise ValueError
            i = _ws(b, i + 1, n)
    if c == 116:
        return _literal(b, i, n, b"true")
    if c == 102:
        return _literal(b, i, n, b"false")
    if c == 110:
        return _literal(b, i, n, b"null")
    if c == 45 or 48 <= c <= 57:
        return _number(b, i, n)
    raise ValueError


def _strict_object(b, limit):
    # Raises ValueError unless b is at most `limit` bytes of ASCII holding exactly one strict JSON object.
    n = len(b)
    if n > limit:
        raise ValueError
    for c in b:
        if c > 126:
            raise ValueError
    i = _ws(b, 0, n)
    if i >= n or b[i] != 123:
        raise ValueError
    if _ws(b, _value(b, i, n, 0), n) != n:
        raise ValueError


# -- field checks ---------------------------------------------------------------------------------------------------
def _counter(v):
    if type(v) is not int or v < 0 or v > _MAX_COUNTER:
        raise ValueError
    return v


def _number_in(v, lo, hi):
    # ints may stand for floats; NaN fails every comparison and so is refused.
    if type(v) is not float and type(v) is not int:
        raise ValueError
    if not (lo <= v <= hi):
        raise ValueError
    return float(v)


def _optional(v, lo, hi):
    if v is None:
        return None
    return _number_in(v, lo, hi)


def _positive_length(v):
    # spacing and side: null, or 0 < v <= 1000 cm
    if v is None:
        return None
    v = _number_in(v, 0.0, _LENGTH_LIMIT)
    if not v > 0.0:
        raise ValueError
    return v


def is_id(s):
    """True for a rover id: 1-16 characters of a-z, 0-9, _ and -."""
    if type(s) is not str:
        return False
    n = len(s)
    if n < 1 or n > 16:
        return False
    for ch in s:
        if ch not in "abcdefghijklmnopqrstuvwxyz0123456789_-":
            return False
    return True


# -- messages -------------------------------------------------------------------------------------------------------
# The canonical pose, as edge.messages.encode_pose writes it: each key with the delimiter before it.
_POSE_PREFIXES = (
    b'{"v":',
    b',"id":',
    b',"seq":',
    b',"frame":',
    b',"t":',
    b',"x":',
    b',"y":',
    b',"theta":',
    b',"vx":',
    b',"vy":',
    b',"q":',
)


def _canonical_pose(b, d):
    # Where t's number starts when b, which json.loads turned into the checked dict d, is strict JSON in the
    # canonical layout; 0 means "not canonical" (the slow scan decides), never "invalid".
    n = len(b)
    if min(b) < 33 or b.find(b"\\") >= 0:
        return 0
    # Every structural character of the canonical layout, and no other: 11 key strings and the id string.
    if b.count(b'"') != 24 or b.count(b":") != 11 or b.count(b",") != 10:
        return 0
    if b.count(b"{") != 1 or b.count(b"}") != 1 or b[n - 1] != 125 or b.find(b"[") >= 0 or b.find(b"]") >= 0:
        return 0
    pos = 0
    at = 0
    for k in range(11):
        pre = _POSE_PREFIXES[k]
        if not b.startswith(pre, pos):
            return 0
        pos += len(pre)
        end = b.find(b",", pos) if k < 10 else n - 1
        if end <= pos:
            return 0
        if k == 1:  # "id": the quotes sit right around the decoded id (no escapes, checked above)
            if end - pos != len(d["id"]) + 2 or b[pos] != 34:
                return 0
        elif d[_POSE_KEYS[k]] is None:
            if end - pos != 4:  # "null" and nothing glued to it
                return 0
        else:
            i = pos + 1 if b[pos] == 45 else pos
            if not 48 <= b[i] <= 57:  # ".5" or "-.5", which MicroPython's json.loads reads
                return 0
            if b[i] == 48 and i + 1 < end and 48 <= b[i + 1] <= 57:  # leading zero
                return 0
            dot = b.find(b".", pos, end)
            if dot >= 0 and not (dot + 1 < end and 48 <= b[dot + 1] <= 57):  # "5." or "1.e5"
                return 0
            if k == 4:
                at = pos
        pos = end
    return at


def _t_at(b):
    # Where t's number starts in a pose that passed the strict scan: after the last key spelt "t" or "\u0074" (the
    # only two spellings of a one-letter key; json.loads keeps the last of doubled keys), blanks and a colon. The id
    # may be "t" too, but a value is never followed by a colon.
    n = len(b)
    last = -1
    at = 0
    for key in (b'"t"', b'"\\u0074"'):
        i = b.rfind(key)
        while i > last:
            j = _ws(b, i + len(key), n)
            if j < n and b[j] == 58:  # :
                last = i
                at = _ws(b, j + 1, n)
                break
            i = b.rfind(key, 0, i)
    if last < 0:
        raise ValueError
    return at


def _t_ms(b, i):
    # The strict JSON number at b[i] (0 <= value < 1e10, checked before) in whole milliseconds, rounded down, modulo
    # _T_WRAP: from its digits, so exact whatever the floats can hold. Value = mantissa digits x 10^(exp - fraction
    # digits); the ms are the mantissa's first (whole + exp + 3) digits, padded with zeros where it has fewer.
    n = len(b)
    if b[i] == 45:  # -0 is >= 0 too
        i += 1
    start = i
    while i < n and 48 <= b[i] <= 57:
        i += 1
    whole = i - start
    if i < n and b[i] == 46:  # .
        i += 1
        while i < n and 48 <= b[i] <= 57:
            i += 1
    end = i
    exp = 0
    if i < n and (b[i] == 101 or b[i] == 69):  # e E
        i += 1
        sign = 1
        if b[i] == 43 or b[i] == 45:
            if b[i] == 45:
                sign = -1
            i += 1
        while i < n and 48 <= b[i] <= 57:
            if exp < _EXP_CAP:
                exp = exp * 10 + b[i] - 48
            i += 1
        exp *= sign
    keep = whole + exp + 3
    ms = 0
    while start < end and keep > 0:
        c = b[start]
        start += 1
        if c != 46:
            ms = (ms * 10 + c - 48) & _T_MASK  # < 10 * 2**26 + 9 < 2**30 before the mask: a small int
            keep -= 1
    while keep > 0 and ms != 0:  # 0 stays 0: "0e999" costs nothing
        ms = (ms * 10) & _T_MASK
        keep -= 1
    return ms


def parse_pose(payload):
    """Pose v1 bytes -> (id, seq, frame, t_ms, x, y, theta, vx, vy, q), or None when the schema would reject them.

    t_ms: the capture time t in whole milliseconds modulo _T_WRAP (an int, exact from the digits). theta, vx and vy
    may be None. Numbers are floats, seq and frame ints.
    """
    try:
        if len(payload) > _POSE_MAX_BYTES or max(payload) > 126:
            return None
        d = json.loads(payload)
        if type(d) is not dict or len(d) != 11:
            return None
        for k in _POSE_KEYS:
            if k not in d:
                return None
        v = d["v"]
        if type(v) is not int or v != 1:
            return None
        rid = d["id"]
        if not is_id(rid):
            return None
        t = _number_in(d["t"], 0.0, _T_LIMIT)
        if not (t < _T_LIMIT or (_T_COARSE and t == _T_LIMIT)):
            return None
        seq = _counter(d["seq"])
        frame = _counter(d["frame"])
        x = _number_in(d["x"], -_MAX_ABS_CM, _MAX_ABS_CM)
        y = _number_in(d["y"], -_MAX_ABS_CM, _MAX_ABS_CM)
        theta = _optional(d["theta"], -_THETA_LIMIT, _THETA_LIMIT)
        vx = _optional(d["vx"], -_MAX_ABS_CM_S, _MAX_ABS_CM_S)
        vy = _optional(d["vy"], -_MAX_ABS_CM_S, _MAX_ABS_CM_S)
        q = _number_in(d["q"], 0.0, 1.0)
        at = _canonical_pose(payload, d)
        if not at:
            _strict_object(payload, _POSE_MAX_BYTES)
            at = _t_at(payload)
        return (rid, seq, frame, _t_ms(payload, at), x, y, theta, vx, vy, q)
    except Exception:  # ValueError from the checks, or anything the interpreter raises on hostile input: None
        return None


def parse_formation(payload):
    """Formation v1 bytes -> (seq, kind, ids, spacing, side, x, y, theta), or None when the schema would reject them.

    kind is one of KINDS, ids a tuple of ids in order; absent optional fields are None, as in FormationV1.
    """
    try:
        _strict_object(payload, _FORMATION_MAX_BYTES)  # formations are rare (retained, on change): always the full scan
        d = json.loads(payload)
        if type(d) is not dict or len(d) < _FORMATION_REQUIRED:
            return None
        for k in d:
            if k not in _FORMATION_KEYS:
                return None
        for i in range(_FORMATION_REQUIRED):
            if _FORMATION_KEYS[i] not in d:
                return None
        v = d["v"]
        if type(v) is not int or v != 1:
            return None
        kind = d["kind"]
        if type(kind) is not str or kind not in KINDS:
            return None
        ids = d["ids"]
        if type(ids) is not list or len(ids) > _MAX_IDS:
            return None
        for rid in ids:
            if not is_id(rid):
                return None
        return (
            _counter(d["seq"]),
            kind,
            tuple(ids),
            _positive_length(d.get("spacing")),
            _positive_length(d.get("side")),
            _optional(d.get("x"), -_MAX_ABS_CM, _MAX_ABS_CM),
            _optional(d.get("y"), -_MAX_ABS_CM, _MAX_ABS_CM),
            _optional(d.get("theta"), -_THETA_LIMIT, _THETA_LIMIT),
        )
    except Exception:
        return None


def rover_status(rid, state, halt, kind, seq, fw):
    """Rover status v2 bytes, canonical (no spaces, the contract's key order): `kind`, `seq` and `fw` may be None.

    What the rover says it applies (the formation's kind and seq) and why its motors are stopped (halt)."""
    return (
        '{"v":2,"id":"%s","state":"%s","halt":"%s","formation":%s,"seq":%s,"fw":%s}'
        % (
            rid,
            state,
            halt,
            "null" if kind is None else '"' + kind + '"',
            "null" if seq is None else str(seq),
            "null" if fw is None else '"' + fw + '"',
        )
    ).encode()


POSE_WILDCARD = b"ips/v1/rovers/+/pose"
FORMATION_TOPIC = b"ips/v1/formation"


def pose_topic(rid):
    """b"ips/v1/rovers/<id>/pose": the topic a rover's pose must arrive on."""
    return b"ips/v1/rovers/" + rid.encode() + b"/pose"


def status_topic(rid):
    """b"ips/v2/rovers/<id>/status" (rover status v2): the only topic a rover publishes on (retained, last will
    offline)."""
    return b"ips/v2/rovers/" + rid.encode() + b"/status"
