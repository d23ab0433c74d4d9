"""The Wi-Fi link model of the closed loop (edge.sim.link): its settings, delay distribution, seeding, bursty loss,
in-order delivery, outages stretched by TCP's backoff, and the association lost in a long outage."""

from __future__ import annotations

import math
from dataclasses import replace
from statistics import NormalDist

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.errors import ConfigError
from edge.sim.link import PRESETS, TAIL_SHARE, LinkModel, LinkSettings, Retransmit

TYPICAL = PRESETS["typical"]


# -- settings ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("typical", TYPICAL),
        ("wire", LinkSettings()),
        ("Poor, loss=3%", replace(PRESETS["poor"], loss_pct=3.0)),
        (
            "latency=10ms,jitter=5ms,tail=0.15s,loss=2%,burst=30ms,outages=0.05/s,outage=300ms-2s,drop=8.5s,rejoin=1.5s",
            LinkSettings(10.0, 5.0, 150.0, 2.0, 30.0, 3.0, 0.3, 2.0, 8.5, 1.5),
        ),
        (
            "latency=8ms,jitter=2ms,outage=1s",
            LinkSettings(latency_ms=8.0, jitter_ms=2.0, outage_min_s=1.0, outage_max_s=1.0),
        ),
        ("good,outages=0", replace(PRESETS["good"], outages_per_min=0.0)),
    ],
)
def test_link_settings_parse_presets_and_items(text: str, expected: LinkSettings) -> None:
    assert LinkSettings.parse(text) == expected


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("great", "unknown preset"),
        ("latency=10", "expected a number with its unit, e.g. latency=10ms"),
        ("loss=2", "e.g. loss=2%"),
        ("loss=60%", "loss=60%: must be 0-50 %"),
        ("speed=3ms", "key one of latency, jitter"),
        ("latency", "unknown preset"),
        ("typical,latency", "expected key=value"),
        ("outage=2s-1s", "shortest first"),
        ("outage=fast", "expected a duration or a range"),
        ("latency=10ms,jitter=10ms,tail=15ms", "tail=15ms: must be 0 (none) or above latency + jitter (20 ms)"),
        ("jitter=5ms", "0 when latency is 0"),
        ("outages=2/h", "e.g. outages=2/min"),
    ],
)
def test_bad_link_settings_name_the_item(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match="link") as err:
        LinkSettings.parse(text)
    assert message in str(err.value)


tenths = st.integers(0, 5000).map(lambda k: k / 10)


@settings(max_examples=200, deadline=None)
@given(
    latency=tenths,
    jitter=tenths,
    tail_above=st.one_of(st.just(None), st.integers(1, 3000).map(lambda k: k / 10)),
    loss=st.integers(0, 500).map(lambda k: k / 10),
    burst=st.integers(1, 10000).map(lambda k: k / 10),
    rate=st.integers(0, 600).map(lambda k: k / 10),
    outage=st.tuples(st.integers(1, 6000), st.integers(0, 6000)).map(lambda p: (p[0] / 100, (p[0] + p[1]) / 100)),
    drop=st.integers(1, 3600).map(lambda k: k / 10),
    rejoin=st.integers(0, 6000).map(lambda k: k / 10),
)
def test_link_settings_round_trip_through_their_string(
    latency: float,
    jitter: float,
    tail_above: float | None,
    loss: float,
    burst: float,
    rate: float,
    outage: tuple[float, float],
    drop: float,
    rejoin: float,
) -> None:
    jitter = jitter if latency > 0 else 0.0
    tail = 0.0 if tail_above is None else round(10 * (latency + jitter + tail_above)) / 10
    s = LinkSettings(latency, jitter, tail, loss, burst, rate, outage[0], outage[1], drop, rejoin)
    assert LinkSettings.parse(str(s)) == s


# -- the delay of a frame on the air ------------------------------------------------------------------------------
def test_air_delay_has_the_median_the_90th_percentile_and_a_truncated_heavy_tail() -> None:
    model = LinkModel(TYPICAL, 0)
    rng = np.random.default_rng(1)
    d_ms = 1000.0 * np.array([model.air_delay_s(a, b) for a, b in rng.random((200_000, 2))])
    assert np.median(d_ms) == pytest.approx(10.0, rel=0.04)
    body_p90 = np.percentile(d_ms, 90)
    assert 20.0 <= body_p90 <= 20.0 * 1.1  # the tail's share lifts it a little above latency + jitter
    assert d_ms.max() <= 150.0 and d_ms.max() > 140.0
    # heavy: a log-normal with that median and 90th percentile leaves 0.05 % of frames beyond 60 ms, the tail
    # (density ~ 1/x^2 on 20-150 ms) ten times as many
    sigma = math.log(2.0) / NormalDist().inv_cdf(0.9)
    body = (1 - TAIL_SHARE) * (1 - NormalDist().cdf(math.log(6.0) / sigma))
    tail = TAIL_SHARE * (1 / 60 - 1 / 150) / (1 / 20 - 1 / 150)
    assert tail > 9 * body
    assert np.mean(d_ms > 60.0) == pytest.approx(body + tail, rel=0.1)


def test_a_wire_delivers_at_once_and_keeps_nothing_back() -> None:
    model = LinkModel(LinkSettings(), 5)
    down, _ = model.connection()
    sent = np.arange(0.0, 100.0, 0.01)
    assert [down.deliver(t, "pose") for t in sent] == list(sent)
    assert model.outages(100.0) == [] and all(model.state(t) == "good" for t in sent)


# -- seeding ------------------------------------------------------------------------------------------------------
def deliveries(model: LinkModel, sent: np.ndarray, flow: str = "ips/v1/rovers/red/pose") -> list[float | None]:
    down, _ = model.connection()
    return [down.deliver(float(t), flow) for t in sent]


@pytest.mark.slow
def test_the_same_seed_gives_the_same_link_and_another_seed_another() -> None:
    sent = np.arange(0.0, 120.0, 1 / 90)
    poor = PRESETS["poor"]
    a, b, c = (deliveries(LinkModel(poor, seed), sent) for seed in ((7, 0), (7, 0), (7, 1)))
    assert a == b
    assert a != c
    assert LinkModel(poor, (7, 0)).outages(120.0) == LinkModel(poor, (7, 0)).outages(120.0)
    assert LinkModel(poor, (7, 0)).outages(120.0) != LinkModel(poor, (7, 1)).outages(120.0)


def test_a_poses_delay_does_not_depend_on_other_traffic_between_them() -> None:
    quiet = LinkSettings(latency_ms=10.0, jitter_ms=10.0, tail_ms=150.0)  # no loss: no retransmission to share
    sent = np.arange(0.0, 60.0, 1.0)  # a second apart: no pose waits behind another
    alone = deliveries(LinkModel(quiet, 3), sent)
    down, _ = LinkModel(quiet, 3).connection()
    mixed = []
    for t in sent:
        down.deliver(float(t) - 0.5, "ping")
        mixed.append(down.deliver(float(t), "ips/v1/rovers/red/pose"))
    assert mixed == alone


# -- loss, order, outages -----------------------------------------------------------------------------------------
@pytest.mark.slow
def test_bursty_loss_is_bad_the_given_share_of_the_time_in_spells_of_the_given_length() -> None:
    model = LinkModel(LinkSettings(loss_pct=5.0, burst_ms=40.0), 11)
    t = np.arange(0.0, 4000.0, 0.002)
    bad = np.array([model.state(float(x)) == "bad" for x in t])
    assert bad.mean() == pytest.approx(0.05, rel=0.1)
    starts = np.flatnonzero(np.diff(bad.astype(int)) == 1)
    assert bad.sum() * 0.002 / len(starts) == pytest.approx(0.040, rel=0.1)  # mean spell


@pytest.mark.slow
def test_a_lost_segment_is_sent_again_and_what_follows_waits_for_it() -> None:
    model = LinkModel(LinkSettings(latency_ms=5.0, loss_pct=5.0, burst_ms=40.0), 2)  # every frame 5 ms on the air
    down, _ = model.connection()
    sent = np.arange(0.0, 600.0, 1 / 90)
    due = np.array([down.deliver(float(t), "pose") for t in sent], dtype=float)
    assert not np.isnan(due).any()  # a live connection loses nothing
    delay = due - sent
    bad = np.array([model.state(float(t)) == "bad" for t in sent])
    assert bad.mean() == pytest.approx(0.05, rel=0.3)
    for t, d in zip(sent[bad], due[bad], strict=True):  # lost: through only once the bad spell is over
        spell_end = next(x for x in np.arange(t, t + 60.0, 0.0005) if model.state(float(x)) == "good")
        assert d - 0.005 >= spell_end - 0.0005
    on_time = np.isclose(delay, 0.005)
    assert 0.75 < on_time.mean() < 0.95 - bad.mean()  # and some of those sent while it was good waited behind them
    assert np.all(np.diff(due) >= 0)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    gaps=st.lists(st.floats(0.0, 0.2), min_size=1, max_size=300),
    flows=st.lists(st.sampled_from(["ips/v1/rovers/red/pose", "ips/v1/rovers/blue/pose", "ping", "close"]), min_size=1),
    preset=st.sampled_from(["good", "typical", "poor"]),
)
def test_a_tcp_stream_delivers_in_order_never_early(
    seed: int, gaps: list[float], flows: list[str], preset: str
) -> None:
    model = LinkModel(LinkSettings.parse(preset + ",outages=20/min,drop=1.5s"), seed)
    down, up = model.connection()
    for stream in (down, up):
        last = -math.inf
        t = 0.0
        for k, gap in enumerate(gaps):
            t += gap
            due = stream.deliver(t, flows[k % len(flows)])
            if due is None:
                assert model._channel.drop_between(t, t + 1000.0) is not None  # only the association loses one
                continue
            assert due >= t
            assert due >= last
            last = due


@pytest.mark.slow
def test_nothing_crosses_an_outage_and_tcp_backoff_stretches_it() -> None:
    s = LinkSettings(outages_per_min=20.0, outage_min_s=0.3, outage_max_s=2.0)  # no air delay: due = sent through
    model = LinkModel(s, 4)
    sent = np.arange(0.0, 300.0, 1 / 90)
    due = np.array(deliveries(model, sent), dtype=float)
    outages = model.outages(300.0)
    assert len(outages) > 40
    timers = model.retransmit["down"]
    checked = 0
    for o in outages:
        assert not np.any((due > o.start_s) & (due < o.end_s))  # nothing arrives during it
        inside = (sent >= o.start_s) & (sent < o.end_s)
        first = int(np.argmax(inside))
        if not inside.any() or due[first - 1] > o.start_s:
            continue  # still waiting for the backlog of the one before
        checked += 1
        first_sent = float(sent[first])
        # the first segment caught in it goes through at its first retransmission after the outage (and after the
        # next, if that one has begun by then) ...
        attempt = next(a for a in timers.attempts(first_sent) if a >= o.end_s and model.state(a) == "good")
        assert due[inside][0] == pytest.approx(attempt)
        # ... and the backlog behind it at once
        assert np.all(due[inside] == due[inside][0])
        if model.state(next(a for a in timers.attempts(first_sent) if a >= o.end_s)) == "good":
            stretched = due[inside][0] - first_sent  # backoff doubles: at most twice the outage and one timer
            assert o.end_s - first_sent <= stretched < 2 * (o.end_s - first_sent) + timers.first_s + timers.rto_s
    assert checked > 30


def test_retransmissions_back_off_to_the_cap() -> None:
    r = Retransmit(first_s=0.04, rto_s=0.22, rto_max_s=1.0)
    gaps = np.diff(r.attempts(10.0))
    assert gaps[:4] == pytest.approx([0.04, 0.22, 0.44, 0.88])
    assert np.all(gaps[4:] == pytest.approx(1.0))


def test_an_outage_longer_than_the_drop_time_loses_the_association_and_whats_in_flight() -> None:
    s = LinkSettings(latency_ms=5.0, outages_per_min=6.0, outage_min_s=3.0, outage_max_s=3.0, drop_s=1.0, rejoin_s=2.0)
    model = LinkModel(s, 9)
    outages = model.outages(600.0)
    o = next(  # one with time to spare on either side
        o
        for before, o, after in zip(outages, outages[1:], outages[2:], strict=False)
        if before.rejoin_at_s < o.start_s - 1.0 and after.start_s > o.rejoin_at_s + 1.0
    )
    assert o.dropped and o.rejoin_at_s == pytest.approx(o.end_s + 2.0)
    assert model.associated(o.start_s + 0.99)
    assert not model.associated(o.start_s + 1.0)
    assert not model.associated(o.end_s + 1.99)
    assert model.associated(o.rejoin_at_s)
    down, up = model.connection()
    assert down.deliver(o.start_s - 0.001, "pose") is not None  # through before the outage
    assert down.deliver(o.start_s + 0.1, "pose") is None  # caught in it: the connection goes first
    assert up.deliver(o.start_s + 0.5, "status") is None
    assert down.lost == 1 and up.lost == 1
    later, _ = model.connection()  # the firmware's new connection after it
    assert later.deliver(o.rejoin_at_s + 0.1, "pose") == pytest.approx(o.rejoin_at_s + 0.105)


def test_short_outages_keep_the_association() -> None:
    model = LinkModel(PRESETS["poor"], 1)
    outages = model.outages(600.0)
    assert outages and not any(o.dropped for o in outages)
    assert all(0.3 <= o.duration_s <= 2.0 for o in outages)
    assert all(model.associated(t) for t in np.arange(0.0, 600.0, 0.05))
    # outages come at the given rate (Poisson): 3 a minute
    assert len(outages) == pytest.approx(30, abs=3 * math.sqrt(30))
