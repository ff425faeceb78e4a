"""zenoh sessions on loopback only, scouting off, always closed."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import JoystickMessage, dump, parse
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.transport.session import config_from_file, config_from_spec, keys, open_session
from tests.net import free_port


def test_default_spec_is_loopback_without_multicast() -> None:
    spec = TransportSpec()
    assert spec.multicast_scouting is False
    assert spec.listen == ["tcp/127.0.0.1:7447"]
    assert keys("sawyer")["joystick"] == "legws/sawyer/joystick"


def test_the_default_transport_has_no_multicast_and_no_gossip() -> None:
    """A peer of the default transport learns of no one but its endpoints."""
    config = config_from_spec(TransportSpec())
    assert config.get_json("scouting/multicast/enabled") == "false"
    assert config.get_json("scouting/gossip/enabled") == "false"
    assert config.get_json("listen/endpoints") == '["tcp/127.0.0.1:7447"]'


def test_two_peers_exchange_a_joystick_message_on_loopback() -> None:
    port = free_port()
    listen = TransportSpec(listen=[f"tcp/127.0.0.1:{port}"])
    dial = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    received: list[JoystickMessage] = []
    got = threading.Event()
    msg = JoystickMessage.model_validate(
        {"schema": 1, "seq": 1, "stamp": 0.0, "axes": [0.0, 0.6, 0.0]}
    )
    key = keys("test_robot")["joystick"]
    with open_session(config_from_spec(listen)) as daemon:

        def on_sample(sample: object) -> None:
            received.append(parse(JoystickMessage, sample.payload.to_bytes(), key))  # type: ignore[attr-defined]
            got.set()

        daemon.declare_subscriber(key, on_sample)
        with open_session(config_from_spec(dial)) as publisher:
            for _ in range(40):  # the peers may need a moment to connect
                publisher.put(key, dump(msg))
                if got.wait(0.1):
                    break
    assert received
    assert received[0] == msg


def test_bad_config_files_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        config_from_file(tmp_path / "missing.json5")
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(InputError) as info:
        config_from_file(bad)
    assert str(info.value).startswith(f"{bad}: invalid zenoh configuration")
    assert "\n" not in str(info.value)
