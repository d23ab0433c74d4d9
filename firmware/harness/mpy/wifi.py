# Driver: link.py's Wi-Fi and broker retries across the wrap of the ticks (time.ticks_ms() wraps at 2**30 ms, tick
# differences at 2**29 ms, 6.2 days), against the scripted broker of fakenet.py, under CPython and inside MicroPython
# alike. The rover boots at ticks start_ms (the chip's ticks count from power-on and go on through a soft reset),
# joins the Wi-Fi, stays connected for `hops` hops of hop_ms, loses the access point for a moment, then for `hops`
# hops of hop_ms. Prints and returns how long each connect took: at boot, after the moment, after the long outage.
#
# The hops: the chip polls every period_ms; here the clock jumps hop_ms (< 2**29) between polls, with a pose arriving
# before each and the ping answered, so each poll finds the link as a poll every 20 ms would. What ages is only what
# no poll renews while connected: the time of the last Wi-Fi try.
import json

import config
import fakenet
import link
from umqtt import simple

_PERIOD_MS = 20
_PATIENCE = 750  # polls (15 s) before a retry counts as never made


def _ignore(*args):
    pass


def _poll_until(lk, clock, done):
    """Poll every period until done() (returns the ms it took) or the patience runs out (None)."""
    t0 = clock.now
    for _ in range(_PATIENCE):
        clock.sleep_ms(_PERIOD_MS)
        lk.poll(clock.ticks_ms())
        if done():
            return clock.now - t0
    return None


def _hop(lk, clock, hop_ms):
    clock.now += hop_ms - 1
    clock.tick()
    lk.poll(clock.ticks_ms())


def main(path, start_ms, hop_ms, hops):
    clock = fakenet.Clock(start_ms)
    broker = fakenet.Broker(clock)
    saved = (link.time, simple.socket)
    link.time = clock
    simple.socket = fakenet.SocketModule(broker)
    try:
        lk = link.Link(config.load(path), _ignore, None, _ignore)
        wlan = lk.wlan
        wlan.drop()  # not associated yet at boot: the first poll starts the Wi-Fi
        first_up_ms = _poll_until(lk, clock, lambda: lk.up)
        stayed_up = first_up_ms is not None
        for _ in range(hops if stayed_up else 0):
            broker.publish(b"ips/v1/rovers/blue/pose", b"{}")  # the edge's poses keep coming
            _hop(lk, clock, hop_ms)
            stayed_up = stayed_up and lk.up
        calls = wlan.connect_calls
        wlan.drop()  # the access point goes away for a moment
        retry_ms = _poll_until(lk, clock, lambda: wlan.connect_calls > calls)
        back_ms = None if retry_ms is None else _poll_until(lk, clock, lambda: lk.up)
        wlan.reachable = False  # and then for as long again (the lab closed for a week)
        wlan.drop()
        for _ in range(hops):
            _hop(lk, clock, hop_ms)
        wlan.reachable = True
        after_outage_ms = _poll_until(lk, clock, lambda: lk.up)
        out = {
            "first_up_ms": first_up_ms,
            "stayed_up": stayed_up,
            "retry_ms": retry_ms,
            "back_ms": back_ms,
            "after_outage_ms": after_outage_ms,
            "connections": broker.connections,
        }
    finally:
        link.time, simple.socket = saved
    print(json.dumps(out))
    return out
