# The formation law, pure: no hardware, no clock, no I/O. Runs unchanged under CPython and MicroPython.
#
# One control step, for rover i among m present members of the commanded formation:
#   1. offsets c_j of the formation (line, triangle, rendezvous ring), oriented by the message's theta or, when
#      theta is null, fitted to where the rovers are (rotation/reflection, least squares);
#   2. the paper's displacement consensus, u_i = k * sum_j ((p_j - p_i) - (c_j - c_i))       (paper sec. VI)
#      plus an optional anchor pulling the formation's centre to the message's x / y;
#   3. speed saturation min_speed <= |u| <= max_speed, and a hold band (|own error| < hold: u = 0) so measurement
#      noise does not make a parked rover jitter;
#   4. keep clear: u is projected so it never points into a neighbour faster than the barrier below allows, and
#      what was removed comes back as a slide around that neighbour (towards the target's side, or to the right
#      when the neighbour is straight in the way: head-on swaps resolve like people passing in a corridor);
#   5. single integrator -> unicycle through a look-ahead point l ahead of the axle:
#      v = cos(th) ux + sin(th) uy,  w = (-sin(th) ux + cos(th) uy) / l;
#   6. the safety layer (Robotarium-style barrier certificate, decentralised, each rover taking half of each pair's
#      budget): with h_ij = |p_i - p_j|^2 - Ds^2, every command keeps  -2 (p_i - p_j).pdot_i <= (gamma / 2) h_ij.
#      The body centre moves along its heading only (pdot_i = v e), so each constraint bounds v alone; the QP
#      "closest safe command" is then exact: clamp v into the interval all constraints allow, keep w (turning in
#      place does not move the centre). No command brings two centres closer than Ds, whatever steps 1-4 asked,
#      as long as the true heading is within heading_margin of the estimate (the constraint holds for all of them);
#   7. wheel speeds from wheel radius and track width, scaled down together (same curvature) to the motor limit;
#      scaling v and w together keeps every barrier constraint that held (their bounds are >= 0 when h >= 0).
from math import atan2, cos, pi, sin, sqrt

from micropython import const

# Formation kinds, in msg.KINDS order. Private consts (no dict entries on the chip); rover.py keeps its own copies.
_LINE = const(0)
_RENDEZVOUS = const(1)
_TRIANGLE = const(2)
_STOP = const(3)

# Fields of the command list a Controller fills.
_C_UX = const(0)  # single-integrator velocity of the look-ahead point, cm/s
_C_UY = const(1)
_C_V = const(2)  # forward speed, cm/s
_C_W = const(3)  # turn rate, rad/s (counter-clockwise)
_C_LEFT = const(4)  # wheel speeds, rad/s (positive drives forward)
_C_RIGHT = const(5)

TWO_PI = 2.0 * pi


def wrap(a):
    """Angle in (-pi, pi]."""
    while a > pi:
        a -= TWO_PI
    while a <= -pi:
        a += TWO_PI
    return a


# -- 1. formation offsets --------------------------------------------------------------------------------------------
def offsets(kind, n, spacing_cm, side_cm, ring_cm, out_x, out_y):
    """Offsets c_k (cm) of n members, centred on their mean, in the formation's own frame (theta = 0).

    line: along +y, spacing_cm apart, in the order of ids (the paper's vertical line);
    triangle: a regular n-gon of side side_cm, first corner towards +y, counter-clockwise (n = 3: the triangle);
    rendezvous: the tightest ring the safety layer allows, a regular n-gon of side ring_cm (the paper's "all c_j
    equal" leaves the final shape to the safety layer, and three rovers can then jam in a line 2 Ds long).
    """
    if kind == _LINE or n < 3:
        step = spacing_cm if kind == _LINE else (side_cm if kind == _TRIANGLE else ring_cm)
        for k in range(n):
            out_x[k] = 0.0
            out_y[k] = (k - (n - 1) * 0.5) * step
        return
    side = side_cm if kind == _TRIANGLE else ring_cm
    radius = side / (2.0 * sin(pi / n))
    for k in range(n):
        a = 0.5 * pi + TWO_PI * k / n
        out_x[k] = radius * cos(a)
        out_y[k] = radius * sin(a)


def orient(kind, theta, px, py, bx, by, m, out_x, out_y):
    """Offsets of the m present members, turned to the formation's orientation.

    bx, by: their offsets in the formation frame; px, py: their positions. theta (rad) given: rotate by it (line:
    0 = along +y). theta None: a line keeps its direction (+y) and takes whichever end fits the rovers better; a
    triangle or ring takes the rotation, and reflection, that best fits where the rovers are (2-D Procrustes), so
    no rover crosses the formation to reach its corner. Offsets are re-centred on the present members. out_x, out_y
    may be bx, by themselves (the rover orients in place: two fewer lists in the chip's heap).
    """
    mx = 0.0
    my = 0.0
    cx = 0.0
    cy = 0.0
    for j in range(m):
        mx += px[j]
        my += py[j]
        cx += bx[j]
        cy += by[j]
    mx /= m
    my /= m
    cx /= m
    cy /= m
    flip = 1.0
    if theta is not None and kind != _RENDEZVOUS:
        c = cos(theta)
        s = sin(theta)
    elif kind == _LINE:
        dot = 0.0
        for j in range(m):
            dot += (bx[j] - cx) * (px[j] - mx) + (by[j] - cy) * (py[j] - my)
        c = 1.0 if dot >= 0.0 else -1.0
        s = 0.0
    else:
        # Least-squares rotation of c onto q = p - mean(p): angle atan2(sum c x q, sum c . q); and the same for
        # the mirror image (x -> -x). Keep whichever explains more of q.
        a1 = 0.0
        b1 = 0.0
        a2 = 0.0
        b2 = 0.0
        for j in range(m):
            ux = bx[j] - cx
            uy = by[j] - cy
            qx = px[j] - mx
            qy = py[j] - my
            a1 += ux * qx + uy * qy
            b1 += ux * qy - uy * qx
            a2 += -ux * qx + uy * qy
            b2 += -ux * qy - uy * qx
        if a2 * a2 + b2 * b2 > a1 * a1 + b1 * b1:
            flip = -1.0
            a1 = a2
            b1 = b2
        norm = sqrt(a1 * a1 + b1 * b1)
        if norm > 0.0:
            c = a1 / norm
            s = b1 / norm
        else:
            c = 1.0
            s = 0.0
    for j in range(m):
        ux = (bx[j] - cx) * flip
        uy = by[j] - cy
        out_x[j] = c * ux - s * uy
        out_y[j] = s * ux + c * uy


# -- 2. consensus ----------------------------------------------------------------------------------------------------
def consensus(i, px, py, cx, cy, m, gain):
    """u_i = k * sum_j ((p_j - p_i) - (c_j - c_i)) over the m present members (paper sec. VI), cm/s."""
    ux = 0.0
    uy = 0.0
    for j in range(m):
        if j != i:
            ux += (px[j] - px[i]) - (cx[j] - cx[i])
            uy += (py[j] - py[i]) - (cy[j] - cy[i])
    return gain * ux, gain * uy


def centre(px, py, cx, cy, m):
    """Where the formation's centre is now: mean_j (p_j - c_j)."""
    x = 0.0
    y = 0.0
    for j in range(m):
        x += px[j] - cx[j]
        y += py[j] - cy[j]
    return x / m, y / m


# -- 3. saturation ---------------------------------------------------------------------------------------------------
def limit(ux, uy, vmax):
    """u scaled down to at most vmax (cm/s), direction kept."""
    n2 = ux * ux + uy * uy
    if n2 > vmax * vmax:
        f = vmax / sqrt(n2)
        return ux * f, uy * f
    return ux, uy


def at_least(ux, uy, vmin):
    """u scaled up to at least vmin (cm/s): the linear law's exponential tail would take seconds over the last
    centimetres; outside the hold band the rover keeps a walking pace."""
    n2 = ux * ux + uy * uy
    if 0.0 < n2 < vmin * vmin:
        f = vmin / sqrt(n2)
        return ux * f, uy * f
    return ux, uy


# -- 4. keep clear ---------------------------------------------------------------------------------------------------
def keep_clear(x, y, ux, uy, tx, ty, qx, qy, nq, safety_cm, gamma, slide_gain, side, pass_cm=0.0):
    """u shaped around the other rovers (qx, qy)[:nq], before the unicycle mapping.

    For each neighbour the single-integrator barrier -2 (p - q_j).u <= (gamma / 2) (|p - q_j|^2 - Ds^2) is enforced
    by projection (one neighbour after the other), so u never points into a neighbour the rover could not then
    drive around; what was removed is given back as a slide along the neighbour, on the side of the target
    (tx, ty) - or to the right when the neighbour stands straight in the way, so two rovers meeting head-on pass
    each other like people in a corridor. A neighbour the rover must get past (the target lies beyond it) is kept
    pass_cm farther than Ds: at Ds itself the certificate (safe_speed, with its heading margin) lets a rover that
    faces sideways creep at ~2 cm/s, and two rovers swapping ends of a line would hover there for seconds. This
    shapes the path; the guarantee is safe_speed().
    side: the side chosen last time (1 left, -1 right, 0 none), kept until the target is clearly on the other
    side, so measurement noise cannot make the rover dither. Returns (ux, uy, side).
    """
    ddx = tx - x
    ddy = ty - y
    dist_t = sqrt(ddx * ddx + ddy * ddy)
    ds2 = safety_cm * safety_cm
    wide = safety_cm + pass_cm
    wide2 = wide * wide
    for j in range(nq):
        dx = x - qx[j]
        dy = y - qy[j]
        d2 = dx * dx + dy * dy
        if d2 <= 0.0:
            continue
        d = sqrt(d2)
        beyond = dist_t > d
        # a = -2 d, b = gamma / 2 h: the constraint a.u <= b
        excess = -2.0 * (dx * ux + dy * uy) - 0.5 * gamma * (d2 - (wide2 if beyond else ds2))
        if excess <= 0.0:
            continue
        f = excess / (4.0 * d2)
        ux += f * 2.0 * dx
        uy += f * 2.0 * dy
        if not beyond:
            continue  # the target is on this side of the neighbour: stop short of it, no need to go round
        removed = excess / (2.0 * d)  # speed taken away towards the neighbour
        ox = -dx / d  # unit vector towards the neighbour
        oy = -dy / d
        cross = (ox * ddy - oy * ddx) / dist_t
        if cross > 0.17:  # target more than ~10 degrees to the left of the neighbour: go round on the left
            side = 1
        elif cross < -0.17 or side == 0:  # to the right, or straight behind it with no earlier choice: keep right
            side = -1
        k = slide_gain * removed * side
        ux -= k * oy
        uy += k * ox
    return ux, uy, side


# -- 5. unicycle -----------------------------------------------------------------------------------------------------
def unicycle(ux, uy, theta, lookahead_cm):
    """Single-integrator velocity of the look-ahead point -> (v cm/s, w rad/s) of the unicycle."""
    c = cos(theta)
    s = sin(theta)
    return c * ux + s * uy, (-s * ux + c * uy) / lookahead_cm


# -- 6. safety -------------------------------------------------------------------------------------------------------
def _reach(c, cos_m, sin_m):
    # cos of the angle between the motion and a neighbour, made worse by up to the heading margin m:
    # cos(max(0, angle - m)), from c = cos(angle).
    if c >= cos_m:
        return 1.0
    return c * cos_m + sqrt(1.0 - c * c) * sin_m


def safe_speed(v, x, y, theta, qx, qy, nq, safety_cm, gamma, margin_rad=0.0, escape_cm_s=10.0):
    """Forward speed v clamped so that for every other rover j (decentralised barrier certificate):

    -2 (p - q_j) . e v <= (gamma / 2) (|p - q_j|^2 - Ds^2),  e = (cos theta, sin theta),
    for every heading within margin_rad of theta: a heading learnt from positions can be a few degrees off, and the
    certificate must hold for the rover's real heading. When measurement noise has put a neighbour inside Ds (h < 0)
    the certificate asks the rover to back off, judged on the estimated heading alone (with the margin, a neighbour
    abeam would forbid both directions and freeze both rovers); that demand is capped at escape_cm_s, since with the
    neighbour nearly abeam it would otherwise be any speed at all. Returns 0 when the constraints contradict each
    other.
    """
    ex = cos(theta)
    ey = sin(theta)
    cos_m = cos(margin_rad)
    sin_m = sin(margin_rad)
    lo = -1e9
    hi = 1e9
    ds2 = safety_cm * safety_cm
    for j in range(nq):
        dx = qx[j] - x  # towards the neighbour
        dy = qy[j] - y
        d2 = dx * dx + dy * dy
        if d2 <= 0.0:
            continue
        d = sqrt(d2)
        c = (dx * ex + dy * ey) / d
        if c > 1.0:
            c = 1.0
        elif c < -1.0:
            c = -1.0
        b = 0.5 * gamma * (d2 - ds2)
        if b >= 0.0:
            ahead = _reach(c, cos_m, sin_m)  # driving forwards closes in at up to v * ahead
            behind = _reach(-c, cos_m, sin_m)  # driving backwards, at up to -v * behind
        else:
            # Already inside Ds (noise, latency): trust the estimate, or a neighbour abeam would freeze both rovers
            # (with the margin, forwards and backwards would both count as approaching).
            ahead = c
            behind = -c
        if ahead > 1e-9:
            bound = b / (2.0 * d * ahead)
            if bound < hi:
                hi = bound
        if behind > 1e-9:
            bound = -b / (2.0 * d * behind)
            if bound > lo:
                lo = bound
    if hi < -escape_cm_s:
        hi = -escape_cm_s
    if lo > escape_cm_s:
        lo = escape_cm_s
    if lo > hi:
        return 0.0
    if v > hi:
        return hi
    if v < lo:
        return lo
    return v


# -- 7. wheels -------------------------------------------------------------------------------------------------------
def wheels(v, w, radius_cm, track_cm, max_rad_s):
    """(v, w) -> (left, right) wheel speeds, rad/s, both scaled by the same factor to |wheel| <= max_rad_s."""
    half = 0.5 * track_cm * w
    left = (v - half) / radius_cm
    right = (v + half) / radius_cm
    big = abs(left)
    if abs(right) > big:
        big = abs(right)
    if big > max_rad_s:
        f = max_rad_s / big
        left *= f
        right *= f
    return left, right


def body_motion(left, right, radius_cm, track_cm):
    """Wheel speeds (rad/s) -> (v cm/s, w rad/s): the inverse of wheels() below saturation."""
    return 0.5 * (left + right) * radius_cm, (right - left) * radius_cm / track_cm


# -- heading -----------------------------------------------------------------------------------------------------------
_RELEARN = 1.2  # spread (rad) past which an estimate is not worth checking anything against
_HISTORY = const(32)  # control steps of commanded turn kept (0.64 s at 20 ms): how old a pose's heading may be fused
_STEP_TURN_MAX = 3.2  # rad a step's record is clipped to (its ints stay small: 32 x 3.2e6 urad < 2**30)


class Heading:
    """The rover's heading, fused from three sources so that no single one is trusted blindly:

    * odometry: between fixes the commanded turn rate is integrated (the rover knows its wheel commands);
    * the pose's heading when it carries one, blended in by its spread against the estimate's (scalar Kalman);
      a pose heading farther than gate + spread from the estimate is an outlier (a tracker's glare, a flipped
      marker) and is set aside; when `recover` of them in a row agree with each other, they are the truth and the
      estimate jumps to them. A rover that commanded reverse motion in the last 0.5 s also accepts a pose heading
      opposite to its estimate as its own reversed: a tracker without heading markers reports the direction of
      motion, which is the opposite of the body's heading while it backs up;
    * the direction of motion from successive positions, SIGNED by the direction it commanded: when the rover has
      moved fix_cm in one direction (forward or backward) since the last fix, the chord's direction plus half the
      turn made along it (an arc's chord points along the heading at its middle), reversed when it drove
      backwards; blended in like a pose heading, with a spread of its own (0.5 cm of position noise over a 6 cm
      chord is ~5 degrees).

    Both measurements are as old as their pose (capture, tracking, broker, Wi-Fi: 50 ms on a wire, 100-250 ms over a
    poor link, seconds in a backlog), and a rover turning at 3 rad/s turns 15-40 degrees meanwhile. So a pose is
    fused at its age: the estimate is wound back by the turn commanded since the pose was captured (a ring of the
    last _HISTORY steps' turns, preallocated), the pose fused there, and the estimate wound forward again. A pose
    older than the ring reaches back leaves the estimate alone (the rover does not drive on such a pose anyway).

    spread (rad) bounds how wrong theta may be: small after a fix, growing by turn_error of every radian turned since
    (wheels that slip or motors that differ make dead reckoning drift while turning in place). The safety layer
    widens its heading margin to the spread, and the rover re-learns its heading when it is large.
    """

    def __init__(self, fix_cm, turn_error=0.15, pose_spread=0.05, gate=0.35, recover=6):
        self.fix_cm = fix_cm
        self.turn_error = turn_error
        self.pose_spread = pose_spread
        self.gate = gate
        self.recover = recover
        self.theta = 0.0
        self.known = False
        self.spread = 4.0
        self.rejected = 0  # pose headings set aside in a row
        self._outlier = 0.0  # the last of them
        self._back_s = 9.0  # time since reverse motion was last commanded
        self._ax = 0.0
        self._ay = 0.0
        self._anchored = False
        self._sign = 0
        self._turned = 0.0
        self._chord_rejected = 0
        self._chord_outlier = 0.0
        # The turn commanded in each of the last _HISTORY steps and how long each lasted: ints (urad, ms), so
        # recording a step allocates nothing on any MicroPython build.
        self._turn_urad = [0] * _HISTORY
        self._step_ms = [0] * _HISTORY
        self._next = 0  # ring slot of the next step
        self._steps = 0  # steps recorded, at most _HISTORY

    def reset(self):
        self.known = False
        self.spread = 4.0
        self.rejected = 0
        self._anchored = False
        self._sign = 0
        self._turned = 0.0
        self._chord_rejected = 0

    def _fuse(self, z, spread):
        """Blend a heading measurement z (rad) of the given spread into the estimate; False if it is an outlier."""
        if not self.known or self.spread > _RELEARN:
            self.theta = wrap(z)  # nothing to check it against
            self.spread = spread
            self.known = True
            return True
        d = wrap(z - self.theta)
        gate = self.gate + self.spread
        if d > gate or d < -gate:
            return False
        s2 = self.spread * self.spread
        k = s2 / (s2 + spread * spread)
        self.theta = wrap(self.theta + k * d)
        self.spread = sqrt(k) * spread  # = 1 / sqrt(1 / spread_old^2 + 1 / spread^2)
        return True

    def turned_since(self, age_ms):
        """The turn commanded (rad) over the last age_ms before the latest moved(); None when the recorded steps do not
        reach back that far. Before its first recorded step the rover stood still (the motors are off from boot)."""
        done_ms = 0
        urad = 0
        k = self._next
        for _ in range(self._steps):
            if done_ms >= age_ms:
                break
            k = k - 1 if k > 0 else _HISTORY - 1
            dt = self._step_ms[k]
            if done_ms + dt > age_ms:  # the capture fell inside this step: the part of its turn made since
                return urad * 1e-6 + self._turn_urad[k] * 1e-6 * (age_ms - done_ms) / dt
            done_ms += dt
            urad += self._turn_urad[k]
        if done_ms < age_ms and self._steps == _HISTORY:
            return None
        return urad * 1e-6

    def measured(self, x, y, theta, age_ms=0):
        """An own pose: position (cm), the pose's heading (rad) or None, and its age (ms: how long before the latest
        moved() it was captured). Fused at that age: wound back, fused, wound forward (see the class)."""
        back = self.turned_since(age_ms)
        if back is None:
            return
        if self.known:
            self.theta = wrap(self.theta - back)
        self._measured(x, y, theta)
        if self.known:
            self.theta = wrap(self.theta + back)

    def _measured(self, x, y, theta):
        if theta is not None:
            z = theta
            if self.known and self._back_s < 0.5:
                a = wrap(theta - self.theta)
                b = wrap(theta + pi - self.theta)
                if b * b < a * a:
                    z = theta + pi  # the direction of motion of a rover that backs up
            if self._fuse(z, self.pose_spread):
                self.rejected = 0
            else:
                if self.rejected > 0 and abs(wrap(z - self._outlier)) <= self.gate:
                    self.rejected += 1
                else:
                    self.rejected = 1
                self._outlier = z
                if self.rejected >= self.recover:  # they persist: they are right, the estimate is not
                    self.theta = wrap(z)
                    self.spread = self.pose_spread
                    self.rejected = 0
        self._chord(x, y)

    def _chord(self, x, y):
        if not self._anchored or self._sign == 0:
            self._ax = x
            self._ay = y
            self._anchored = True
            self._turned = 0.0
            return
        dx = x - self._ax
        dy = y - self._ay
        if dx * dx + dy * dy < self.fix_cm * self.fix_cm:
            return
        z = atan2(dy, dx) + 0.5 * self._turned
        if self._sign < 0:
            z += pi
        spread = 0.15 + self.turn_error * 0.5 * abs(self._turned)
        if self._fuse(z, spread):
            self._chord_rejected = 0
            self.rejected = 0  # its own motion confirms the estimate: earlier pose outliers were outliers
        else:
            if self._chord_rejected > 0 and abs(wrap(z - self._chord_outlier)) <= self.gate + spread:
                self._chord_rejected += 1
            else:
                self._chord_rejected = 1
            self._chord_outlier = z
            if self._chord_rejected >= 2:  # two chords in a row say otherwise: the rover moves that way
                self.theta = wrap(z)
                self.spread = spread
                self._chord_rejected = 0
        self._ax = x
        self._ay = y
        self._turned = 0.0

    def moved(self, v, w, dt_s, moving_cm_s):
        """The command (v cm/s, w rad/s) that was applied for dt_s seconds."""
        sign = 0
        if v > moving_cm_s:
            sign = 1
        elif v < -moving_cm_s:
            sign = -1
        if sign != self._sign:
            self._anchored = False  # a new chord starts at the next pose
            self._sign = sign
        if sign < 0:
            self._back_s = 0.0
        elif self._back_s < 9.0:
            self._back_s += dt_s
        turn = w * dt_s
        self._turned += turn
        k = self._next
        self._turn_urad[k] = int(1e6 * max(-_STEP_TURN_MAX, min(_STEP_TURN_MAX, turn)))
        self._step_ms[k] = int(1000.0 * dt_s + 0.5) if dt_s < 60.0 else 60000
        self._next = k + 1 if k + 1 < _HISTORY else 0
        if self._steps < _HISTORY:
            self._steps += 1
        if self.known:
            self.theta = wrap(self.theta + turn)
            self.spread += self.turn_error * abs(turn)


# -- the whole step --------------------------------------------------------------------------------------------------
class Controller:
    """Steps 2-7 for one rover; parameters in cm, s, rad, named (keyword-only: fourteen numbers in a row would be
    read by position). Call command() with the present members' positions and oriented offsets, the other rovers'
    positions, and a known heading."""

    def __init__(
        self,
        *,
        gain_per_s,
        anchor_gain_per_s,
        max_speed_cm_s,
        min_speed_cm_s,
        hold_cm,
        safety_cm,
        barrier_gain_per_s,
        slide_gain,
        pass_cm,
        heading_margin_rad,
        lookahead_cm,
        wheel_radius_cm,
        track_cm,
        max_wheel_rad_s,
    ):
        self.gain = gain_per_s
        self.anchor_gain = anchor_gain_per_s
        self.max_speed = max_speed_cm_s
        self.min_speed = min_speed_cm_s
        self.hold = hold_cm
        self.safety = safety_cm
        self.gamma = barrier_gain_per_s
        self.slide_gain = slide_gain
        self.pass_cm = pass_cm
        self.margin = heading_margin_rad
        self.side = 0
        self.lookahead = lookahead_cm
        self.radius = wheel_radius_cm
        self.track = track_cm
        self.max_wheel = max_wheel_rad_s

    def command(self, i, px, py, cx, cy, m, anchor_x, anchor_y, qx, qy, nq, theta, spread, out):
        """Fill out[_C_UX..C_RIGHT] for member i of the m present ones. anchor_x/_y: cm or None; theta: the heading
        estimate, spread: how far off it may be (rad)."""
        x = px[i]
        y = py[i]
        ux, uy = consensus(i, px, py, cx, cy, m, self.gain)
        if anchor_x is not None or anchor_y is not None:
            fx, fy = centre(px, py, cx, cy, m)
            if anchor_x is not None:
                ux += self.anchor_gain * (anchor_x - fx)
            if anchor_y is not None:
                uy += self.anchor_gain * (anchor_y - fy)
        # The gain acts on the sum over m - 1 neighbours: the rover's own error is u / (k m).
        scale = self.gain * m if m > 1 else self.anchor_gain
        if scale <= 0.0 or ux * ux + uy * uy < (scale * self.hold) * (scale * self.hold):
            ux = 0.0
            uy = 0.0
        else:
            tx = x + ux / scale
            ty = y + uy / scale
            ux, uy = limit(ux, uy, self.max_speed)
            ux, uy = at_least(ux, uy, self.min_speed)
            ux, uy, self.side = keep_clear(
                x, y, ux, uy, tx, ty, qx, qy, nq, self.safety, self.gamma, self.slide_gain, self.side, self.pass_cm
            )
            ux, uy = limit(ux, uy, self.max_speed)
        v, w = unicycle(ux, uy, theta, self.lookahead)
        margin = self.margin if self.margin > spread else spread
        v = safe_speed(v, x, y, theta, qx, qy, nq, self.safety, self.gamma, margin)
        left, right = wheels(v, w, self.radius, self.track, self.max_wheel)
        out[_C_UX] = ux
        out[_C_UY] = uy
        out[_C_V], out[_C_W] = body_motion(left, right, self.radius, self.track)
        out[_C_LEFT] = left
        out[_C_RIGHT] = right
