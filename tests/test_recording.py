"""The recording on a disk that fills up, files that cannot grow, restarts, and files that end mid-line.

The full disk is a real one: a 64 KiB tmpfs mounted in a mount namespace of the child process's own (``unshare``);
the file size limit is RLIMIT_FSIZE in a child process. See tests/support/recording.py.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from edge.recording import Recorder, read_recording, recording_files
from tests.conftest import REPO
from tests.support.recording import FSIZE_BYTES, tiny_tmpfs_command


def _child(command: list[str]) -> dict[str, Any]:
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    return json.loads(done.stdout)


@pytest.mark.slow
def test_a_full_disk_pauses_the_recording_with_one_warning_and_it_resumes_when_space_returns(tmp_path: Path) -> None:
    mount = tmp_path / "disk"
    mount.mkdir()
    got = _child(tiny_tmpfs_command(mount, sys.executable, "-m", "tests.support.recording", "disk-full", str(mount)))
    full, after = got["full"], got["after"]
    assert full["paused"] and 0 < full["written"] < 400 and full["written"] + full["dropped"] == 400
    assert not after["paused"] and after["written"] > full["written"]
    assert after["written"] + after["dropped"] == 450  # every line is either in a file or counted as dropped
    assert got["lines_in_files"] == after["written"] and got["all_end_whole"]  # counted = on disk, none torn
    ks = got["ks"]
    assert ks == sorted(ks) and ks[: full["written"]] == list(range(full["written"]))  # the first ones, whole
    assert ks[-1] == 449  # after space came back
    warnings = [m for m in got["log"] if m.startswith("WARNING")]
    assert len(warnings) == 1 and "recording paused: cannot write to" in warnings[0]
    assert "No space left on device" in warnings[0]
    assert any(m.startswith(f"INFO recording resumed in {mount}; {full['dropped']} lines dropped") for m in got["log"])


@pytest.mark.slow
def test_a_file_that_cannot_grow_is_closed_and_the_next_one_started(tmp_path: Path) -> None:
    got = _child([sys.executable, "-m", "tests.support.recording", "fsize", str(tmp_path)])
    assert got["after"] == {"written": 300, "dropped": 0, "paused": False}
    assert got["files"] > 1 and got["largest_file_bytes"] <= FSIZE_BYTES and got["all_end_whole"]
    assert got["lines_in_files"] == 300 and got["ks"] == list(range(300))
    assert not [m for m in got["log"] if m.startswith("WARNING")]


def _run_recorder(directory: Path, lines: int, start_k: int) -> Recorder:
    recorder = Recorder(directory, max_bytes=10_000, max_files=4).start()
    for k in range(start_k, start_k + lines):
        recorder.record("ips/v1/test", json.dumps({"k": k, "pad": "x" * 400}).encode(), False)
    recorder.close()
    return recorder


def test_retention_counts_the_files_of_earlier_runs(tmp_path: Path) -> None:
    older = [tmp_path / "published-20250101T000000Z-0001.jsonl", tmp_path / "published-20250101T000000Z-0002.jsonl"]
    for path in older:  # left by an earlier version of the recorder
        path.write_bytes(b'{"t":0,"topic":"old","retain":false,"payload":{}}\n')
    foreign = [tmp_path / "notes.jsonl", tmp_path / "published-notes.jsonl"]
    for path in foreign:
        path.write_text("not a recording\n")
    kept: list[list[str]] = []
    for run in range(3):  # three restarts, each writing about 10 files' worth
        _run_recorder(tmp_path, 200, run * 200)
        kept.append([p.name for p in recording_files(tmp_path)])
    assert all(len(names) == 4 for names in kept)
    assert not any(path.exists() for path in older) and all(path.exists() for path in foreign)
    sequences = [int(name.split("-")[1]) for name in kept[-1]]
    assert sequences == sorted(sequences) and sequences[-1] > 20  # numbered on across the restarts
    ks = [line["payload"]["k"] for line in read_recording(tmp_path)]
    assert ks == sorted(ks) and ks[-1] == 599  # the newest lines are the ones kept


def test_the_order_holds_when_the_clock_goes_back(tmp_path: Path) -> None:
    # a board without a real-time clock may start with an older time than the files it left
    (tmp_path / "published-000007-20300101T000000Z.jsonl").write_bytes(b'{"t":0,"topic":"a","retain":false}\n')
    _run_recorder(tmp_path, 5, 0)
    names = [p.name for p in recording_files(tmp_path)]
    assert names[0].startswith("published-000007-") and names[-1].startswith("published-000008-")


def test_read_recording_skips_a_torn_last_line_and_says_so(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    recorder = _run_recorder(tmp_path, 3, 0)
    path = recording_files(tmp_path)[-1]
    torn = b'{"t":1.0,"topic":"ips/v1/rovers/red/pose","retain":false,"payload":{"v":1,"x":12'
    with path.open("ab") as fh:
        fh.write(torn)
    with caplog.at_level(logging.WARNING, logger="edge.recording"):
        lines = list(read_recording(tmp_path))
    assert [line["payload"]["k"] for line in lines] == [0, 1, 2] and recorder.lines_written == 3
    said = f"{path} ends in a torn line ({len(torn)} bytes: the recorder stopped while writing it); skipped"
    assert said in caplog.text


def test_read_recording_skips_a_line_that_is_not_a_record_and_names_it(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "published-000001-20260101T000000Z.jsonl"
    path.write_bytes(b'{"t":1,"topic":"a","retain":false,"payload":1}\n[1, 2]\n{"t":2,"topic":"b","retain":false}\n')
    with caplog.at_level(logging.WARNING, logger="edge.recording"):
        topics = [line["topic"] for line in read_recording(tmp_path)]
    assert topics == ["a", "b"] and f"{path}:2 is not a JSON record; skipped" in caplog.text


def test_closing_writes_everything_queued_and_twice_is_harmless(tmp_path: Path) -> None:
    recorder = _run_recorder(tmp_path, 50, 0)
    recorder.close()
    assert recorder.lines_written == 50 == sum(p.read_bytes().count(b"\n") for p in recording_files(tmp_path))
