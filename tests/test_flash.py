"""tools/flash.py: the bundle it would copy, the commands it would run, and its one-line errors.

No board here: ``--bundle`` and ``--dry-run`` show what a flash does; the error paths run the real tools against
ports that do not exist or are not boards. The "board answers with something else" path drives the library with a
stand-in for the board's replies.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from edge import flashing
from edge.errors import FlashError
from firmware.harness.runner import micropython_image, mpy_driver, run_micropython, stall_config
from tests.conftest import REPO

TOOL = [sys.executable, str(REPO / "tools" / "flash.py")]
SECRETS = {"EDGE_IPS_WIFI_SSID": "lab-net", "EDGE_IPS_WIFI_PASSWORD": "wifi-pw", "EDGE_IPS_MQTT_PASSWORD": "mqtt-pw"}


def flash_tool(*args: str, env: dict[str, str] | None = None, **kw: object) -> subprocess.CompletedProcess[str]:
    base = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return subprocess.run(
        [*TOOL, *args], env={**base, **(env or {})}, capture_output=True, text=True, stdin=subprocess.DEVNULL, **kw
    )  # type: ignore[call-overload]


@pytest.mark.slow
def test_bundle_holds_the_romfs_image_boot_py_main_py_and_the_provisioned_config(tmp_path: Path) -> None:
    out = tmp_path / "bundle"
    result = flash_tool(
        "--rover", "green", "--bundle", str(out), env={**SECRETS, "EDGE_IPS_BROKER_HOST": "10.0.0.7:1884"}
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(flashing.BUNDLE)
    image = (out / "rom.img").read_bytes()
    assert image[:3] == b"\xd2\xcd\x31"  # a ROMFS filesystem, what `mpremote romfs deploy` writes
    for module in flashing.COMPILED:  # each module's .mpy (mpy v6, compiled in the firmware dir: "msg.py")
        name = f"{module}.mpy".encode()
        assert name in image and image.find(b"M\x06", image.index(name)) > 0
        assert f"{module}.py".encode() in image
    assert (out / "main.py").read_text() == (REPO / "firmware" / "esp8266" / "main.py").read_text()
    assert (out / "boot.py").read_text() == flashing.boot_source(json.loads((out / "config.json").read_text()))
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
@pytest.mark.parametrize("args", [[], ["--firmware", "FW", "--erase"], ["--firmware", "FW"]])
def test_dry_run_prints_the_commands_in_order_without_touching_a_board(tmp_path: Path, args: list[str]) -> None:
    fw = micropython_image(tmp_path / "ESP8266_GENERIC.bin")
    args = [str(fw) if a == "FW" else a for a in args]
    result = flash_tool("--port", "/dev/ttyUSB9", "--rover", "red", "--dry-run", *args)  # no such port: not needed
    assert result.returncode == 0, result.stderr
    lines = [ln for ln in result.stdout.splitlines() if not ln.startswith("#")]
    stop, rest = lines[0], lines[1:]
    assert stop.startswith(f"{sys.executable} -m mpremote connect /dev/ttyUSB9 exec") and stop.endswith("+ reset")
    assert "main.off" in stop  # the running rover is stopped before anything else
    if "--erase" in args:
        assert "erase-flash" in rest[0]
        rest = rest[1:]
    if "--firmware" in args:
        write = rest.pop(0)
        assert "write-flash --flash-size detect --flash-mode dout 0" in write and str(fw) in write
        assert "--baud 460800" in write
    assert not any("esptool" in ln for ln in rest)
    copy, check = rest
    assert copy.startswith(f"{sys.executable} -m mpremote connect /dev/ttyUSB9 romfs deploy BUNDLE/rom.img +")
    cps = re.findall(r"fs cp BUNDLE/(\S+) :(\S+)", copy)
    assert cps == [(n, n) for n in flashing.BUNDLE[1:]] and cps[-1][0] == "main.py"  # main.py last
    assert copy.endswith("+ reset")
    assert "exec" in check and "edge-ips-fw" in check and check.endswith("+ reset")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("image", "message"),
    [
        ({"version": "1.24.1", "romfs": False}, "MicroPython 1.24.1 without ROMFS; the rover needs MicroPython 1.28.0"),
        ({"romfs": False}, "MicroPython 1.28.0 without ROMFS; the rover needs"),
        (
            {"version": "1.29.0"},
            "MicroPython 1.29.0; the rover needs MicroPython 1.28.0 ESP8266_GENERIC FLASH_2M_ROMFS",
        ),
        ({"banner": False}, "an ESP8266 image, but not MicroPython"),
        ({"checksum_ok": False}, "not an ESP8266 firmware image"),
        ({"text": True}, "not an ESP8266 firmware image (esptool: "),
    ],
)
def test_a_wrong_micropython_image_is_refused_with_the_one_to_get(
    tmp_path: Path, image: dict[str, Any], message: str
) -> None:
    fw = tmp_path / "firmware.bin"
    if image.pop("text", False):
        fw.write_text("<html>404 Not Found</html>")
    else:
        micropython_image(fw, **image)
    result = flash_tool("--rover", "red", "--port", "/dev/null", "--firmware", str(fw), "--erase", env=SECRETS)
    assert result.returncode == 2, result.stderr
    line = result.stderr.strip().splitlines()[-1]
    assert message in line and flashing.IMAGE.file in line
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_the_image_the_rover_needs_passes_the_check(tmp_path: Path) -> None:
    assert flashing.check_image(micropython_image(tmp_path / "fw.bin")) == "MicroPython 1.28.0 (2026-04-06, ROMFS)"


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
    errors = [ln for ln in result.stderr.strip().splitlines() if not ln.startswith("warning: ")]
    assert len(errors) == 1 and message in errors[0], result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_motor_pins_on_boot_strapping_gpios_are_warned_about(tmp_path: Path) -> None:
    result = flash_tool("--rover", "red", "--bundle", str(tmp_path / "b"), env=SECRETS)
    assert result.returncode == 0, result.stderr
    warnings = result.stderr.strip().splitlines()
    assert warnings == [  # the NodeMCU motor shield's direction inputs: D3 and D4
        "warning: motors.left.dir on GPIO 0: must be high at reset (low: serial bootloader)",
        "warning: motors.right.dir on GPIO 2: must be high at reset",
    ]


@pytest.mark.slow
def test_a_broker_given_by_name_is_warned_about(tmp_path: Path) -> None:
    # lwIP's DNS lookup is the one wait the firmware cannot bound: an address avoids it.
    env = {**SECRETS, "EDGE_IPS_BROKER_HOST": "edge.local:1883"}
    result = flash_tool("--rover", "red", "--bundle", str(tmp_path / "b"), env=env)
    assert result.returncode == 0, result.stderr
    named = [line for line in result.stderr.splitlines() if "broker.host" in line]
    assert named == [
        "warning: broker.host 'edge.local' is a name: the rover looks it up without a timeout of its own (motors off "
        "meanwhile); give the broker's address (EDGE_IPS_BROKER_HOST=A.B.C.D) so that no wait is unbounded"
    ]
    by_address = flash_tool(
        "--rover", "red", "--bundle", str(tmp_path / "c"), env={**SECRETS, "EDGE_IPS_BROKER_HOST": "10.0.0.2"}
    )
    assert by_address.returncode == 0 and "broker.host" not in by_address.stderr


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
    """A board's replies, scripted: the stop step answers ``stop`` (after ``cut`` sessions cut by a reset), the
    version check answers ``answer``."""

    def __init__(self, answer: str, stop: str = "edge-ips-board 1.28.0 True", cut: int = 0) -> None:
        self.answer = answer
        self.stop = stop
        self.cut = cut
        self.ran: list[list[str]] = []

    def __call__(self, cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
        self.ran.append(list(cmd))
        text = " ".join(cmd)
        if "main.off" in text and "os.rename" in text:
            if self.cut:
                self.cut -= 1
                return subprocess.CompletedProcess(list(cmd), 1, "", "TransportError: could not enter raw repl")
            return subprocess.CompletedProcess(list(cmd), 0, self.stop + "\n", "")
        out = self.answer if "exec" in cmd and "edge-ips-fw" in text else ""
        return subprocess.CompletedProcess(list(cmd), 0, out, "")


def _bundle(tmp_path: Path) -> Path:
    bundle = tmp_path / "b"
    flashing.write_bundle(bundle, flashing.provisioned_config("blue", SECRETS, None))
    return bundle


@pytest.mark.slow
def test_flash_checks_that_the_board_answers_with_the_firmware_it_was_given(tmp_path: Path) -> None:
    bundle = _bundle(tmp_path)
    good = _Board(flashing.expected_answer() + "\n")
    flashing.flash("/dev/ttyUSB0", bundle, None, False, run=good, echo=lambda s: None)
    assert [c[c.index("connect") + 2] for c in good.ran] == ["exec", "romfs", "exec"]
    with pytest.raises(FlashError, match="did not answer as edge-ips firmware"):
        flashing.flash("/dev/ttyUSB0", bundle, None, False, run=_Board("MicroPython v1.24\n>>>"), echo=print)


@pytest.mark.slow
def test_the_stop_step_is_retried_when_a_reset_cuts_it(tmp_path: Path) -> None:
    # An older firmware's machine.WDT resets the board a few seconds after mpremote's Ctrl-C stopped its loop.
    bundle = _bundle(tmp_path)
    board = _Board(flashing.expected_answer(), cut=flashing.ATTEMPTS - 1)
    flashing.flash("/dev/ttyUSB0", bundle, None, False, run=board, echo=lambda s: None)
    assert len(board.ran) == flashing.ATTEMPTS + 2
    with pytest.raises(FlashError, match=r"did not answer \(mpremote: TransportError"):
        flashing.flash("/dev/ttyUSB0", bundle, None, False, run=_Board("", cut=99), echo=lambda s: None)


@pytest.mark.slow
def test_a_board_that_does_not_answer_is_fine_when_new_micropython_is_written(tmp_path: Path) -> None:
    bundle = _bundle(tmp_path)
    fw = micropython_image(tmp_path / "fw.bin")
    board = _Board(flashing.expected_answer(), cut=99)  # a blank board: no MicroPython to talk to
    esptool: list[list[str]] = []

    def run(cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
        if "esptool" in cmd and "image-info" not in cmd:
            esptool.append(list(cmd))
            return subprocess.CompletedProcess(list(cmd), 0, "", "")
        if "image-info" in cmd:
            return subprocess.run(list(cmd), capture_output=True, text=True)
        return board(cmd)

    flashing.flash("/dev/ttyUSB0", bundle, fw, True, run=run, echo=lambda s: None)
    assert [c[c.index("--port") + 2] for c in esptool] == ["erase-flash", "--baud"]


@pytest.mark.slow
@pytest.mark.parametrize("interpreter", ["cpython", "micropython"])
def test_boot_py_stops_the_pwm_a_soft_reset_left_running_on_the_motor_pins(interpreter: str, tmp_path: Path) -> None:
    # A soft reset (Ctrl-D) frees the Python heap but not esppwm.c's channels: the wheels keep turning into boot.py.
    # The flash bundle's boot.py must leave both PWM pins low and without a channel, whatever duty ran (at full
    # duty no period clears the pin, so it must be driven low after the channel ends), and start no pulse elsewhere.
    cfg = stall_config()
    left, right = (cfg["motors"][side]["pwm"] for side in ("left", "right"))
    other = 14  # a PWM channel on a pin that is not a motor's is not boot.py's business
    running = [[left, 1023], [right, 600], [other, 300]]
    boot = flashing.boot_source(cfg)
    if interpreter == "cpython":
        (tmp_path / "boot.py").write_text(boot)
        got = json.loads(json.dumps(mpy_driver("softreset").main(str(tmp_path / "boot.py"), running)))
    else:
        out = run_micropython(f"softreset.main('/input/data/boot.py', {running!r})", {"boot.py": boot.encode()}, True)
        got = json.loads(out.splitlines()[-1])
    assert got["before"] == sorted(running)
    assert got["after"] == sorted([[left, 0], [right, 0], [other, 300]])
