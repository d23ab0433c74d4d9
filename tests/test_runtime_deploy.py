"""The systemd unit in deploy/: valid for systemd, and it runs `edge-ips start` the way docs/deploy.md says."""

from __future__ import annotations

import configparser
import subprocess
from pathlib import Path

from tests.conftest import REPO

UNIT = REPO / "deploy" / "edge-ips.service"


def _unit() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(UNIT.read_text())
    return parser


def test_unit_runs_start_with_a_clean_stop_and_no_restart_loop_on_bad_configuration() -> None:
    service = _unit()["Service"]
    assert service["ExecStart"].endswith("edge-ips start --config /etc/edge-ips/config.toml")
    assert service["KillSignal"] == "SIGTERM"
    assert service["RestartPreventExitStatus"] == "2"  # the CLI's exit code for a user-fixable error
    assert service["SupplementaryGroups"] == "video"
    assert "/var/lib/edge-ips" in service["ReadWritePaths"]


def test_systemd_accepts_the_unit(tmp_path: Path) -> None:
    # the same unit with ExecStart pointing at this checkout's edge-ips (systemd checks that it is executable)
    text = UNIT.read_text().replace("/opt/edge-ips/.venv/bin/edge-ips", str(REPO / ".venv" / "bin" / "edge-ips"))
    unit = tmp_path / "edge-ips.service"
    unit.write_text(text)
    result = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stderr.strip() == "", result.stderr
