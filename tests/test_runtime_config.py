"""The appliance configuration: TOML file, environment overrides, errors that name the key and the file."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from edge.config import EdgeConfig, parse_broker_url
from edge.config_load import find_config, load_config, with_overrides
from edge.config_text import STARTER, masked, to_toml, write_starter
from edge.errors import ConfigError


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "edge-ips.toml"
    path.write_text(text)
    return path


def test_no_file_means_simulated_camera_and_embedded_broker() -> None:
    loaded = load_config(None, {})
    assert loaded.config.camera.source == "sim"
    assert loaded.config.broker.url == "embedded"
    assert [r.id for r in loaded.config.rovers] == ["red", "green", "blue"]
    assert loaded.config.http.port == 8080


def test_starter_file_is_valid_and_names_a_real_camera(tmp_path: Path) -> None:
    path = write_starter(tmp_path / "edge-ips.toml")
    config = load_config(path, {}).config
    assert config.camera.source == "/dev/video0"
    assert config.calibration.path == tmp_path / "calibration.json"  # relative to the file, not the cwd
    with pytest.raises(ConfigError, match="already exists"):
        write_starter(path)


@pytest.mark.parametrize(
    ("env", "key", "expected"),
    [
        ({"EDGE_IPS_BROKER__URL": "mqtt://pi.local:1884"}, ("broker", "url"), "mqtt://pi.local:1884"),
        ({"EDGE_IPS_CAMERA__FPS": "25"}, ("camera", "fps"), 25.0),
        ({"EDGE_IPS_CAMERA__LOOP": "true"}, ("camera", "loop"), True),
        ({"EDGE_IPS_EDGE__ID": "lab-2"}, ("edge", "id"), "lab-2"),
        ({"EDGE_IPS_HTTP__PORT": "9090"}, ("http", "port"), 9090),
        ({"EDGE_IPS_BROKER__EMBEDDED_PORT": "11883"}, ("broker", "embedded_port"), 11883),
        ({"OTHER_VAR": "x", "EDGE_IPS_CONFIG": "/nowhere"}, ("camera", "source"), "sim"),
        ({"EDGE_IPS_WIFI_SSID": "lab", "EDGE_IPS_MQTT_PASSWORD": "x"}, ("camera", "source"), "sim"),  # the flasher's
    ],
)
def test_environment_overrides_one_key(env: dict[str, str], key: tuple[str, str], expected: object) -> None:
    config = load_config(None, env).config
    assert getattr(getattr(config, key[0]), key[1]) == expected


def test_environment_overrides_the_file(tmp_path: Path) -> None:
    path = _write(tmp_path, '[camera]\nsource = "/dev/video2"\nfps = 15\n')
    loaded = load_config(path, {"EDGE_IPS_CAMERA__FPS": "30"})
    assert loaded.config.camera.source == "/dev/video2"
    assert loaded.config.camera.fps == 30.0
    assert loaded.env_keys == ("EDGE_IPS_CAMERA__FPS",)


def test_rovers_from_environment_as_json() -> None:
    env = {"EDGE_IPS_ROVERS": '[{"id": "r1", "color_bgr": [0, 0, 255]}, {"id": "r2", "color_bgr": [0, 255, 0]}]'}
    assert [r.id for r in load_config(None, env).config.rovers] == ["r1", "r2"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("text", "env", "message"),
    [
        ("[camera]\nfps = -3\n", {}, r"edge-ips.toml: camera.fps: Input should be greater than 0"),
        ("[camera]\nsorce = 'sim'\n", {}, r"edge-ips.toml: camera.sorce: unknown key"),
        ("[broker]\nurl = 'http://x'\n", {}, r"edge-ips.toml: broker.url: 'http://x' is not a broker URL"),
        ("[broker]\nurl = 'mqtt://h:99999'\n", {}, r"broker.url: .*port"),
        ("[[rovers]]\nid = 'Red'\ncolor_bgr = [0, 0, 0]\n", {}, r"edge-ips.toml: rovers.0.id"),
        (
            "[[rovers]]\nid='a'\ncolor_bgr=[0,0,0]\n[[rovers]]\nid='a'\ncolor_bgr=[1,1,1]\n",
            {},
            "rovers: a named more than once",
        ),
        ("[edge]\nid = 'x y'\n", {}, r"edge-ips.toml: edge.id"),
        ("[tracker]\nmethod = 'magic'\n", {}, r"edge-ips.toml: tracker.method: Input should be 'centroid'"),
        ("[tracker]\nmethd = 'centroid'\n", {}, r"edge-ips.toml: tracker.methd: unknown key"),
        ("[tracker]\nrovers = []\n", {}, r"edge-ips.toml: tracker: the rovers are configured in \[\[rovers\]\]"),
        ("[camera\nsource = 1\n", {}, r"edge-ips.toml: invalid TOML: .*line 1"),
        ("", {"EDGE_IPS_CAMERA__FPS": "fast"}, r"^environment variable EDGE_IPS_CAMERA__FPS: camera.fps"),
        ("", {"EDGE_IPS_CAMRA__SOURCE": "sim"}, r"^environment variable EDGE_IPS_CAMRA__SOURCE: camra: unknown key"),
        ("", {"EDGE_IPS_BROKER__": "x"}, r"environment variable EDGE_IPS_BROKER__: expected EDGE_IPS_<SECTION>__<KEY>"),
        ("camera = 3\n", {"EDGE_IPS_CAMERA__FPS": "3"}, r"camera is not a table"),
    ],
)
def test_bad_configuration_names_the_file_or_variable_and_the_key(
    tmp_path: Path, text: str, env: dict[str, str], message: str
) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=message):
        load_config(path, env)


def test_missing_explicit_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope.toml: configuration file not found"):
        find_config(tmp_path / "nope.toml", {})
    with pytest.raises(ConfigError, match=r"named by EDGE_IPS_CONFIG"):
        find_config(None, {"EDGE_IPS_CONFIG": str(tmp_path / "gone.toml")})


def test_default_lookup_finds_the_file_in_the_working_directory(tmp_path: Path) -> None:
    path = _write(tmp_path, "")
    assert find_config(None, {}, cwd=tmp_path) == path


@pytest.mark.parametrize(
    ("url", "embedded", "host", "port", "tls", "user", "password"),
    [
        ("embedded", True, "0.0.0.0", 1883, False, None, None),
        ("mqtt://broker", False, "broker", 1883, False, None, None),
        ("mqtt://10.0.0.2:1884", False, "10.0.0.2", 1884, False, None, None),
        ("mqtts://broker.lab", False, "broker.lab", 8883, True, None, None),
        ("mqtt://edge:s%40cret@pi:1883", False, "pi", 1883, False, "edge", "s@cret"),
    ],
)
def test_broker_urls(
    url: str, embedded: bool, host: str, port: int, tls: bool, user: str | None, password: str | None
) -> None:
    target = parse_broker_url(url)
    assert (target.embedded, target.host, target.port, target.tls) == (embedded, host, port, tls)
    assert (target.username, target.password) == (user, password)
    assert "cret" not in target.display()


@pytest.mark.parametrize("url", ["tcp://x:1", "mqtt://", "mqtt://h:port", "mqtt://h/topic", "localhost:1883"])
def test_bad_broker_urls_are_refused(url: str) -> None:
    with pytest.raises(ValueError, match=r"broker URL|port|path"):
        parse_broker_url(url)


def test_show_masks_every_secret_and_round_trips_as_toml() -> None:
    config = with_overrides(
        EdgeConfig(), **{"broker.url": "mqtt://edge:topsecret@pi:1883", "broker.password": "alsosecret"}
    )
    text = to_toml(masked(config))
    assert "topsecret" not in text and "alsosecret" not in text
    assert "********" in text
    data = tomllib.loads(text)
    assert data["broker"]["url"] == "mqtt://edge:********@pi:1883"
    assert [r["id"] for r in data["rovers"]] == ["red", "green", "blue"]
    assert data["camera"]["fps"] == 30.0


def test_command_line_overrides_are_validated() -> None:
    with pytest.raises(ConfigError, match=r"command line: http.port"):
        with_overrides(EdgeConfig(), **{"http.port": 70000})


def test_tracker_settings_pass_through_to_the_pipeline(tmp_path: Path) -> None:
    from edge.tracker_config import TrackerConfig

    config = load_config(_write(tmp_path, "[tracker]\nmethod = 'meanshift'\nlost_after_frames = 5\n"), {}).config
    settings = TrackerConfig.of(config.tracker, config.rovers)
    assert (settings.method, settings.lost_after_frames, len(settings.rovers)) == ("meanshift", 5, 3)


def test_starter_text_mentions_every_section() -> None:
    data = tomllib.loads(STARTER)
    assert set(data) == set(EdgeConfig.model_fields)
