#!/usr/bin/env python3
"""One entry point for a fresh machine: installs from the lock file on first use, then runs the job.

    python3 run.py start [OPTIONS]     edge-ips start (simulated camera and embedded broker unless configured)
    python3 run.py test [PYTEST-ARGS]  the whole test suite, on every core (pytest -n auto; -n 0 for one process)
    python3 run.py edge-ips ARGS...    any other edge-ips command

Needs only Python 3.11+ and pip. uv is bootstrapped into ./.tools with pip when it is not on PATH; the project's
environment is ./.venv, synchronised with uv.lock (never re-resolved). `test` also installs the Debian packages
the tests talk to (mosquitto, mosquitto-clients, chromium) when they are missing, with apt-get.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
TOOLS = ROOT / ".tools"
VENV = ROOT / ".venv"
DEBIAN_FOR_TESTS = {
    "/usr/sbin/mosquitto": "mosquitto",
    "/usr/bin/mosquitto_sub": "mosquitto-clients",
    "/usr/bin/chromium": "chromium",
    "/usr/bin/systemd-analyze": "systemd",  # checks deploy/edge-ips.service
    "/usr/bin/openssl": "openssl",  # test certificates for the MQTT TLS test
}


def say(message: str) -> None:
    print(f"[run.py] {message}", file=sys.stderr, flush=True)


def find_uv() -> list[str]:
    found = shutil.which("uv")
    if found:
        return [found]
    local = TOOLS / "bin" / "uv"
    if not local.exists():
        say("uv not found: installing it into ./.tools with pip (one time)")
        subprocess.run(
            [sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--target", TOOLS, "uv"],
            check=True,
        )
    return [str(local)]


def sync(dev: bool) -> None:
    cmd = [*find_uv(), "sync", "--frozen", "--quiet"]
    if not dev:
        cmd += ["--no-dev", "--inexact"]
    env = dict(os.environ, UV_PROJECT_ENVIRONMENT=str(VENV))
    if subprocess.run(cmd, cwd=ROOT, env=env).returncode != 0:
        sys.exit("[run.py] installing from uv.lock failed (see above)")


def ensure_debian_packages() -> None:
    missing = sorted({pkg for path, pkg in DEBIAN_FOR_TESTS.items() if not Path(path).exists()})
    if not missing:
        return
    apt = shutil.which("apt-get")
    prefix: list[str] = [] if os.geteuid() == 0 else ["sudo", "-n"]
    if apt is None or (prefix and shutil.which("sudo") is None):
        sys.exit(
            f"[run.py] the tests need the Debian packages {', '.join(missing)}; install them "
            "(apt-get install -y " + " ".join(missing) + ") and run again"
        )
    say(f"installing Debian packages for the tests: {', '.join(missing)}")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    subprocess.run([*prefix, apt, "update", "-qq"], check=True, env=env, stdout=subprocess.DEVNULL)
    subprocess.run(
        [*prefix, apt, "install", "-y", "-qq", "--no-install-recommends", *missing],
        check=True,
        env=env,
        stdout=subprocess.DEVNULL,
    )


def main(argv: list[str]) -> int:
    if not argv or argv[0] in {"-h", "--help"}:
        print(__doc__)
        return 0
    job, rest = argv[0], argv[1:]
    if job == "test":
        sync(dev=True)
        ensure_debian_packages()
        # every core (pytest-xdist); the real-time tests on one worker, one at a time (tests/conftest.py)
        pytest = [str(VENV / "bin" / "python"), "-m", "pytest", "-n", "auto"]
        return subprocess.run([*pytest, *rest], cwd=ROOT).returncode
    if job == "start":
        sync(dev=False)
        return subprocess.run([str(VENV / "bin" / "edge-ips"), "start", *rest]).returncode
    if job == "edge-ips":
        sync(dev=False)
        return subprocess.run([str(VENV / "bin" / "edge-ips"), *rest]).returncode
    print(__doc__)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
