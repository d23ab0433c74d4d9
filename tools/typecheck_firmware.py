#!/usr/bin/env python3
"""Type-check firmware/esp8266 against the MicroPython ESP8266 stubs (not CPython's typeshed).

The stub packages (micropython-esp8266-stubs, micropython-stdlib-stubs) install their .pyi files at the top of
site-packages, where mypy does not look for plain modules, and stdlib names (time, math, json) must come from the
MicroPython versions. So this copies the ESP8266 stubs into a temporary MYPYPATH, points mypy's typeshed at
micropython-stdlib-stubs, silences errors inside the stubs themselves, and checks the firmware.

    python tools/typecheck_firmware.py        # exit code 0 when the firmware type-checks
"""

from __future__ import annotations

import importlib.metadata as md
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIRMWARE = ROOT / "firmware" / "esp8266"


def _copy_stubs(dist_name: str, dest: Path, keep: str = "") -> list[str]:
    dist = md.distribution(dist_name)
    modules = []
    for f in dist.files or []:
        name = str(f)
        if not name.endswith(".pyi") or (keep and not name.startswith(keep)):
            continue
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(str(dist.locate_file(f))), target)
        module = name[: -len(".pyi")].replace("/", ".").removesuffix(".__init__")
        modules.append(module)
    return modules


def main() -> int:
    typeshed = Path(str(md.distribution("micropython-stdlib-stubs").locate_file("stdlib"))).parent
    with tempfile.TemporaryDirectory() as tmp:
        stubs = Path(tmp) / "stubs"
        modules = _copy_stubs("micropython-esp8266-stubs", stubs)
        modules += _copy_stubs("micropython-stdlib-stubs", stubs, keep="_mpy_shed/")
        config = Path(tmp) / "mypy.ini"
        config.write_text(
            "[mypy]\n"
            "python_version = 3.11\n"
            f"mypy_path = {stubs}\n"
            f"custom_typeshed_dir = {typeshed}\n"
            "no_site_packages = True\n"
            "check_untyped_defs = True\n"
            "warn_unused_ignores = True\n"
            "cache_dir = /dev/null\n"
            f"\n[mypy-{','.join(sorted(set(modules)))}]\nignore_errors = True\n"
        )
        files = sorted(str(p) for p in FIRMWARE.glob("*.py"))
        cmd = [sys.executable, "-m", "mypy", "--config-file", str(config), *files]
        return subprocess.run(cmd, cwd=ROOT).returncode


if __name__ == "__main__":
    sys.exit(main())
