"""Hardware profiles: the shipped ones load, bad ones give one line naming file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.profile import load_profile

PROFILES = Path(__file__).parents[2] / "hw_profiles"


@pytest.mark.parametrize("name", ["sim", "sawyer"])
def test_shipped_profiles_load(name: str) -> None:
    p = load_profile(PROFILES / f"{name}.toml")
    assert p.name == name
    assert p.transport.multicast_scouting is False
    assert all("127.0.0.1" in e for e in p.transport.listen)
    assert p.control.deadman_timeout == 0.25


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (('adapter = "sim"', 'adapter = "ur5"'), "adapter"),
        (("rate_hz = 20.0", "rate_hz = 0.0"), "control.rate_hz"),
        (("rate_hz = 20.0", 'rate_hz = "fast"'), "control.rate_hz"),
        (("deadman_timeout = 0.25", "deadman_timeout = 0.01"), "control.deadman_timeout"),
        (("x = [0.20, 0.95]", "x = [0.95, 0.20]"), "workspace.x"),
        (('listen = ["tcp/127.0.0.1:7447"]', 'listen = ["127.0.0.1"]'), "transport.listen[0]"),
        (("realtime = true", 'realtime = "yes"'), "sim.realtime"),
        (("realtime = true", "realtime = true\nwarp = 3"), "sim.warp"),
        (("v_max = 0.05", "v_max = 50.0"), "control.v_max"),
    ],
)
def test_bad_profiles_name_file_and_field(
    tmp_path: Path, edit: tuple[str, str], field: str
) -> None:
    text = (PROFILES / "sim.toml").read_text()
    assert edit[0] in text
    path = tmp_path / "p.toml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(InputError) as info:
        load_profile(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {field}")
    assert "\n" not in message
