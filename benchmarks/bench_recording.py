#!/usr/bin/env python3
"""Recording on a disk that fills up, and retention across restarts, with the real ``edge-ips start --record``.

    .venv/bin/python benchmarks/bench_recording.py            # ~2 min

* **Disk full**: a 256 KiB tmpfs mounted in a mount namespace of its own (``unshare --map-root-user --mount``, no
  root needed), most of it taken by a filler file. ``edge-ips start --source sim --record`` runs on it until
  ``/metrics`` says the recording paused, keeps running ``--full-s`` seconds, then the filler is deleted and it runs
  until the recording has resumed and written ``--after-lines`` more lines; then SIGTERM. Reported: the lines the
  recorder counted against the whole lines in the files, lines dropped, torn lines, the log's warnings about it,
  tracebacks, exit code.
* **Retention**: three runs one after the other on the same directory (``recording.max_bytes`` 10 kB,
  ``recording.max_files`` 5), two files of an earlier version's naming there at the start. After each run: the files
  kept, their numbers, and the newest line.

Counts, not times: valid on a loaded machine.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import platform
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from edge.recording import read_recording, recording_files  # noqa: E402  (after the sys.path line above)

TMPFS_BYTES = 256 * 1024
FILLER_BYTES = 200 * 1024


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Edge:
    """``edge-ips start --source sim --record DIR`` in a child process (embedded broker on a free port)."""

    def __init__(self, record_dir: Path, log_path: Path, **env: str) -> None:
        self.port = free_port()
        self.log_path = log_path
        base = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
        base.update(
            PYTHONPATH=str(REPO),
            EDGE_IPS_BROKER__EMBEDDED_PORT="0",
            EDGE_IPS_BROKER__EMBEDDED_HOST="127.0.0.1",
            **env,
        )
        args = ["start", "--source", "sim", "--record", str(record_dir), "--http-port", str(self.port)]
        with log_path.open("w") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "edge.cli", *args],
                cwd=log_path.parent,
                env=base,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        self.wait_for(lambda m: m.get("edge_ips_uptime_seconds", 0.0) > 0.0, "start")

    def metrics(self) -> dict[str, float]:
        try:
            conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
            conn.request("GET", "/metrics")
            text = conn.getresponse().read().decode()
            conn.close()
        except OSError:
            return {}
        return {m.group(1): float(m.group(2)) for m in re.finditer(r"^(edge_ips_\w+) (\S+)$", text, re.M)}

    def wait_for(self, condition: Any, what: str, guard_s: float = 180.0) -> dict[str, float]:
        deadline = time.monotonic() + guard_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise SystemExit(f"edge-ips start ended while waiting for {what}:\n{self.log_path.read_text()}")
            metrics = self.metrics()
            if metrics and condition(metrics):
                return metrics
            time.sleep(0.25)
        raise SystemExit(f"no {what} within {guard_s:g} s:\n{self.log_path.read_text()[-3000:]}")

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return -9

    def flushed(self) -> tuple[int, int]:
        """(lines, dropped) from the recorder's last log line."""
        match = re.search(r"recording flushed: (\d+) lines in .* \((\d+) dropped\)", self.log_path.read_text())
        return (int(match.group(1)), int(match.group(2))) if match else (-1, -1)


def files_summary(directory: Path) -> dict[str, Any]:
    files = recording_files(directory)
    data = [p.read_bytes() for p in files]
    return {
        "files": len(files),
        "whole_lines": sum(d.count(b"\n") for d in data),
        "torn_endings": sum(1 for d in data if d and not d.endswith(b"\n")),
        "names": [p.name for p in files],
    }


def disk_full_inside(directory: Path, full_s: float, after_lines: int) -> dict[str, Any]:
    """Runs inside the mount namespace, ``directory`` being the tiny tmpfs."""
    (directory / "filler.bin").write_bytes(b"\0" * FILLER_BYTES)
    record_dir = directory / "rec"
    with tempfile.TemporaryDirectory(prefix="bench-recording-") as tmp:
        edge = Edge(record_dir, Path(tmp) / "edge.log")
        paused = edge.wait_for(lambda m: m.get("edge_ips_recording_paused") == 1.0, "a full disk")
        time.sleep(full_s)  # the benchmark's own pacing: how long the disk stays full
        still = edge.metrics()
        (directory / "filler.bin").unlink()
        resumed = edge.wait_for(
            lambda m: (
                m.get("edge_ips_recording_paused") == 0.0
                and m.get("edge_ips_recording_lines_total", 0.0)
                >= still["edge_ips_recording_lines_total"] + after_lines
            ),
            "the recording to resume",
        )
        code = edge.stop()
        lines, dropped = edge.flushed()
        log = edge.log_path.read_text()
    return {
        "lines_when_paused": paused["edge_ips_recording_lines_total"],
        "dropped_while_full": still["edge_ips_recording_dropped_total"],
        "lines_after_resuming": resumed["edge_ips_recording_lines_total"],
        "lines_counted": lines,
        "dropped": dropped,
        **files_summary(record_dir),
        "paused_warnings": log.count("recording paused"),
        "resumed_lines": log.count("recording resumed"),
        "recording_log_lines": sum(1 for ln in log.splitlines() if " edge.recording: " in ln),
        "tracebacks": log.count("Traceback"),
        "exit_code": code,
        "readable_lines": sum(1 for _ in read_recording(record_dir)),
    }


def disk_full(full_s: float, after_lines: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench-recording-disk-") as tmp:
        script = f'mount -t tmpfs -o size={TMPFS_BYTES} tmpfs "$1" && shift && exec "$@"'
        me = [sys.executable, __file__, "--inside", tmp, "--full-s", str(full_s), "--after-lines", str(after_lines)]
        done = subprocess.run(
            ["unshare", "--map-root-user", "--mount", "sh", "-c", script, "sh", tmp, *me],
            capture_output=True,
            text=True,
            timeout=900,
        )
        if done.returncode != 0:
            raise SystemExit(f"disk-full run failed:\n{done.stderr[-3000:]}")
        return json.loads(done.stdout.strip().splitlines()[-1])


def retention(runs: int, run_lines: int) -> list[dict[str, Any]]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-recording-retention-") as tmp:
        record_dir = Path(tmp) / "rec"
        record_dir.mkdir()
        for name in ("published-20250101T000000Z-0001.jsonl", "published-20250101T000000Z-0002.jsonl"):
            (record_dir / name).write_bytes(b'{"t":0,"topic":"earlier","retain":false,"payload":{}}\n')
        for run in range(runs):
            edge = Edge(
                record_dir,
                Path(tmp) / f"edge-{run}.log",
                EDGE_IPS_RECORDING__MAX_BYTES="10000",
                EDGE_IPS_RECORDING__MAX_FILES="5",
            )
            edge.wait_for(lambda m: m.get("edge_ips_recording_lines_total", 0.0) >= run_lines, "recorded lines")
            code = edge.stop()
            lines, dropped = edge.flushed()
            summary = files_summary(record_dir)
            last = list(read_recording(record_dir))[-1]
            rows.append(
                {
                    "run": run + 1,
                    "lines_this_run": lines,
                    "dropped": dropped,
                    "exit_code": code,
                    "files": summary["files"],
                    "first": summary["names"][0],
                    "last": summary["names"][-1],
                    "bytes": sum(p.stat().st_size for p in recording_files(record_dir)),
                    "newest_line": f"{last['topic']} {last['payload'].get('state', '')}".strip(),
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full-s", type=float, default=10.0, help="seconds the disk stays full")
    parser.add_argument("--after-lines", type=int, default=300, help="lines written after space came back")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--run-lines", type=int, default=600, help="lines each retention run records")
    parser.add_argument("--inside", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inside is not None:
        print(json.dumps(disk_full_inside(args.inside, args.full_s, args.after_lines)))
        return

    full = disk_full(args.full_s, args.after_lines)
    kept = retention(args.runs, args.run_lines)
    print(
        f"machine: {platform.node()} ({os.cpu_count()} cores {platform.machine()}), Python "
        f"{platform.python_version()}, {time.strftime('%Y-%m-%d')}"
    )
    print(f"\nDisk full: {TMPFS_BYTES // 1024} KiB tmpfs, {FILLER_BYTES // 1024} KiB of it taken until deleted")
    print("| what | figure |\n| --- | --- |")
    rows = [
        ("lines counted when the recording paused", f"{full['lines_when_paused']:g}"),
        (f"lines dropped while the disk was full ({args.full_s:g} s)", f"{full['dropped_while_full']:g}"),
        (
            "lines counted by the recorder at the end / whole lines in the files",
            f"{full['lines_counted']} / {full['whole_lines']}",
        ),
        ("lines read back by read_recording", full["readable_lines"]),
        ("lines dropped in all", full["dropped"]),
        ("files ending in a torn line", full["torn_endings"]),
        (
            "warnings 'recording paused' / lines 'recording resumed'",
            f"{full['paused_warnings']} / {full['resumed_lines']}",
        ),
        ("log lines from the recorder in all", full["recording_log_lines"]),
        ("tracebacks in the log; exit code after SIGTERM", f"{full['tracebacks']}; {full['exit_code']}"),
    ]
    for what, figure in rows:
        print(f"| {what} | {figure} |")
    print(f"\nRetention: {args.runs} runs of `edge-ips start --record`, max_bytes 10 kB, max_files 5")
    print("| run | lines recorded | dropped | exit | files kept | oldest kept | newest | bytes | last line |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in kept:
        print(
            f"| {r['run']} | {r['lines_this_run']} | {r['dropped']} | {r['exit_code']} | {r['files']} | "
            f"`{r['first']}` | `{r['last']}` | {r['bytes']} | {r['newest_line']} |"
        )


if __name__ == "__main__":
    main()
