# Driver: one poll of link.py over a backlog with a PINGRESP in the middle (what arrives after an outage that TCP
# rode out: the poses queued during it, and the answer to a ping sent during it), against the scripted broker of
# fakenet.py, under CPython and inside MicroPython alike. main() prints, for each poll, how many messages it handed
# over.
import json

import config
import fakenet
import link
from umqtt import simple


def main(path, before, after):
    clock = fakenet.Clock()
    broker = fakenet.Broker(clock)
    saved = (link.time, simple.socket)
    link.time = clock
    simple.socket = fakenet.SocketModule(broker)
    got = []
    try:
        lk = link.Link(config.load(path), lambda topic, payload: got.append(payload), None, lambda *a: None)
        lk.poll(clock.now)  # connects and subscribes
        for k in range(before + after):
            if k == before:
                broker.send(b"\xd0\x00", 0)
            topic = b"ips/v1/rovers/blue/pose"
            broker.send(fakenet.publish_packet(topic, b'{"k":' + str(k).encode() + b"}"), 0)
        clock.tick()
        counts = []
        while True:
            n = len(got)
            lk.poll(clock.now)
            counts.append(len(got) - n)
            if counts[-1] == 0:
                break
        out = {"per_poll": counts, "up": lk.up}
    finally:
        link.time, simple.socket = saved
    print(json.dumps(out))
    return out
