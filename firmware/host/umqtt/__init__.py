# The umqtt package as MicroPython v1.28.0 freezes it into ESP8266_GENERIC (boards/ESP8266_GENERIC/manifest_2MiB.py:
# require("umqtt.simple")), for host tests and the closed-loop simulation; the board uses its own frozen copy.
#   simple.py: micropython-lib micropython/umqtt.simple/umqtt/simple.py, umqtt.simple 1.7.0, at commit
#              8380c7bb8f9e5e5260e9539156742925e00366b2 (the lib/micropython-lib submodule of MicroPython v1.28.0),
#              byte for byte; sha256 0792c0bd6d9219c8180a9ee7dae3d7c15fafe53e0605fa30839b1033fa4a189c, checked by
#              tests/test_firmware_stall.py. MIT licence, "Copyright (c) 2013, 2014 micropython-lib contributors":
#              the full text is in ./LICENSE.
# Under CPython its `socket` global is swapped for firmware/host/mpsocket.py (MicroPython sockets have read/write).
