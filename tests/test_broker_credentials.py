"""Secrets on disk: 0600 from the first byte, replaced atomically; the state directory's logins; broker-config."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from edge.broker import ensure_credentials, read_credentials, rover_login, verify_mosquitto_hash
from edge.broker.credentials import credentials_path
from edge.cli import main
from edge.config import default_state_dir
from edge.config_load import load_config
from edge.errors import BrokerError, ConfigError
from edge.flashing import provisioned_config
from edge.private_files import write_private


def test_a_private_file_is_never_wider_than_0600_even_with_umask_0(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    modes: list[int] = []
    real_open = os.open

    def watched_open(path: Any, flags: int, mode: int = 0o777, **kw: Any) -> int:
        fd = real_open(path, flags, mode, **kw)
        modes.append(stat.S_IMODE(os.fstat(fd).st_mode))  # the file as it exists before any byte is written
        return fd

    monkeypatch.setattr(os, "open", watched_open)
    old = os.umask(0)
    try:
        target = write_private(tmp_path / "secret.toml", "password = 'x'\n")
    finally:
        os.umask(old)
    assert modes == [0o600]
    assert stat.S_IMODE(target.stat().st_mode) == 0o600 and target.read_text() == "password = 'x'\n"


def test_a_private_file_is_replaced_whole_or_not_at_all(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = write_private(tmp_path / "credentials.toml", "old\n")
    monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(28, "No space left on device")))
    with pytest.raises(OSError, match="No space"):
        write_private(target, "new\n")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["credentials.toml"]  # no temporary left behind


def test_state_directory_logins_are_made_once_and_grow_with_the_rovers(tmp_path: Path) -> None:
    first = ensure_credentials(tmp_path / "state", ["red", "green"])
    path = credentials_path(tmp_path / "state")
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "state").stat().st_mode) == 0o700
    again = ensure_credentials(tmp_path / "state", ["red", "green"])
    assert again == first
    grown = ensure_credentials(tmp_path / "state", ["red", "green", "blue"])
    assert grown.edge == first.edge and grown.rovers["red"] == first.rovers["red"] and "blue" in grown.rovers
    assert read_credentials(path) == grown
    assert rover_login(tmp_path / "state", "blue") == grown.rovers["blue"]
    assert rover_login(tmp_path / "state", "pink") is None and rover_login(tmp_path / "nowhere", "red") is None
    assert len({login.password for login in grown.logins()}) == 5 and all(len(x.password) == 24 for x in grown.logins())


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("not toml [", "not a broker credentials file"),
        ("[rovers.red]\nusername = 'red'\npassword = 'x'\n", r"\[edge\]: expected a table"),
        ("[edge]\nusername = 'edge'\npassword = ''\n", "non-empty strings"),
        ("[edge]\nusername='edge'\npassword='p'\n[rovers.red]\nusername='blue'\npassword='x'\n", "the rover id"),
        ("[edge]\nusername='Edge!'\npassword='p'\n", "'Edge!'"),
    ],
)
def test_a_broken_credentials_file_is_one_line_naming_it(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "broker-credentials.toml"
    path.write_text(text)
    with pytest.raises(BrokerError, match=message) as caught:
        read_credentials(path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_the_hash_verifies_only_its_own_password() -> None:
    from edge.broker import mosquitto_hash

    hashed = mosquitto_hash("right")
    assert verify_mosquitto_hash("right", hashed) and not verify_mosquitto_hash("wrong", hashed)
    assert not verify_mosquitto_hash("right", "$6$not$pbkdf2") and not verify_mosquitto_hash("right", "")


@pytest.mark.parametrize(
    ("env", "expected"),
    [
        ({"STATE_DIRECTORY": "/var/lib/edge-ips"}, "/var/lib/edge-ips"),
        ({"STATE_DIRECTORY": "/var/lib/a:/var/lib/b", "XDG_STATE_HOME": "/x"}, "/var/lib/a"),
        ({"XDG_STATE_HOME": "/home/u/.state", "HOME": "/home/u"}, "/home/u/.state/edge-ips"),
        ({"HOME": "/home/u"}, "/home/u/.local/state/edge-ips"),
    ],
)
def test_the_state_directory_follows_systemd_then_xdg(env: dict[str, str], expected: str) -> None:
    assert default_state_dir(env) == Path(expected)
    assert load_config(None, env).config.edge.state_dir == Path(expected)


def test_a_state_directory_in_the_file_is_relative_to_it(tmp_path: Path) -> None:
    (tmp_path / "edge-ips.toml").write_text('[edge]\nstate_dir = "state"\n')
    loaded = load_config(tmp_path / "edge-ips.toml", {"STATE_DIRECTORY": "/elsewhere"})
    assert loaded.config.edge.state_dir == tmp_path / "state"


def test_provisioning_takes_the_rovers_login_unless_a_password_is_given() -> None:
    from edge.broker import Login

    env = {"EDGE_IPS_WIFI_SSID": "lab", "EDGE_IPS_WIFI_PASSWORD": "w"}
    stored = {"red": Login("red", "from-the-state-dir")}
    config = provisioned_config("red", env, None, stored.get)
    assert (config["broker"]["user"], config["broker"]["password"]) == ("red", "from-the-state-dir")
    given = provisioned_config("red", {**env, "EDGE_IPS_MQTT_PASSWORD": "typed"}, None, stored.get)
    assert given["broker"]["password"] == "typed"
    with pytest.raises(ConfigError, match="EDGE_IPS_MQTT_PASSWORD"):
        provisioned_config("green", env, None, stored.get)  # no login stored, none given, nobody to ask


def test_broker_config_tls_writes_keys_0600_and_says_how_the_edge_connects(tmp_path: Path) -> None:
    out = tmp_path / "mq"
    result = CliRunner().invoke(
        main, ["broker-config", "--out", str(out), "--rovers", "red", "--tls", "--tls-name", "pi.lab"], env={}
    )
    assert result.exit_code == 0, result.output
    for name, mode in [("passwd", 0o600), ("credentials.toml", 0o600), ("server.key", 0o600),
                       ("client.key", 0o600), ("ca.crt", 0o644), ("mosquitto.conf", 0o644)]:  # fmt: skip
        assert stat.S_IMODE((out / name).stat().st_mode) == mode, name
    assert "broker.url = mqtt://edge@localhost:1884" in result.output
    conf = (out / "mosquitto.conf").read_text()
    assert "listener 8883 0.0.0.0" in conf and "require_certificate true" in conf
    from cryptography import x509

    server = x509.load_pem_x509_certificate((out / "server.crt").read_bytes())
    names = server.extensions.get_extension_for_class(x509.SubjectAlternativeName).value.get_values_for_type(
        x509.DNSName
    )
    assert names == ["pi.lab"]
    again = CliRunner().invoke(main, ["broker-config", "--out", str(out), "--rovers", "red", "--tls"], env={})
    assert again.exit_code == 2 and "already exist" in again.output
