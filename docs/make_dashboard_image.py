#!/usr/bin/env python3
"""Make ``docs/img/dashboard.png``: ``edge-ips start --source sim`` with its embedded broker, a triangle formation
commanded from the page with the token, and a screenshot of the page in Debian's headless chromium.

    .venv/bin/python docs/make_dashboard_image.py
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "docs" / "img" / "dashboard.png"
TOKEN = "docs-screenshot-token"
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from _common import CHROMIUM, CHROMIUM_ARGS  # noqa: E402  (after the sys.path lines above)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> None:
    from playwright.sync_api import sync_playwright

    http_port, mqtt_port = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    env.update(
        EDGE_IPS_DASHBOARD__TOKEN=TOKEN,
        EDGE_IPS_BROKER__EMBEDDED_HOST="127.0.0.1",
        EDGE_IPS_BROKER__EMBEDDED_PORT=str(mqtt_port),
        PYTHONPATH=str(REPO),
    )
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "edge.cli", "start", "--source", "sim", "--http-port", str(http_port)]
        edge = subprocess.Popen(cmd, cwd=tmp, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            url = f"http://127.0.0.1:{http_port}/"
            for _ in range(300):
                try:
                    with urllib.request.urlopen(url + "healthz", timeout=2):
                        break
                except (urllib.error.URLError, OSError):
                    time.sleep(0.2)
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.goto(f"{url}?token={TOKEN}")  # the page keeps it for the session (and the buttons send it)
                page.wait_for_function("() => state.rovers.size === 3", timeout=60_000)
                page.fill("#side", "120")
                page.click("button[data-kind=triangle]")
                page.wait_for_function("() => (state.formation || {}).kind === 'triangle'", timeout=60_000)
                page.wait_for_timeout(3000)  # trails grow
                page.screenshot(path=str(OUT), full_page=True)
                browser.close()
        finally:
            edge.send_signal(signal.SIGTERM)
            edge.wait(30)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
