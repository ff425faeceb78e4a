"""Hardware profiles: the shipped ones load, bad ones give one line naming file and field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.profile import endpoint_problem, load_profile, with_arm

PROFILES = Path(__file__).parents[2] / "hw_profiles"


@pytest.mark.parametrize("name", ["sim", "sawyer", "panda_sim", "panda"])
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
        (('adapter = "sim"', 'adapter = "sim"\narm = "baxter"'), "arm"),
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
    assert message.startswith(f"{path}:{_line_of(text, edit)}: {field}: "), message
    assert "\n" not in message


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp/127.0.0.1:7447",
        "tls/localhost:7447",
        "udp/192.168.1.20:1",
        "quic/robot-pc.lab.example:65535",
        "tcp/[::1]:7447",
        "tcp/[fe80::1]:7447",
    ],
)
def test_good_endpoints(endpoint: str) -> None:
    assert endpoint_problem(endpoint) is None


@pytest.mark.parametrize(
    ("endpoint", "why"),
    [
        ("tcp/127.0.0.1:99999", "port 99999 is not in 1..65535"),
        ("tcp/127.0.0.1:0", "port 0 is not in 1..65535"),
        ("tcp/127.0.0.300:7447", "127.0.0.300 is not an IP address"),
        ("tcp/[1::2::3]:7447", "[1::2::3] is not an IP address"),
        ("tcp/-robot:7447", "'-robot' is not a host name"),
        ("tcp/a..b:7447", "'a..b' is not a host name"),
        ("http/127.0.0.1:7447", "expected PROTOCOL/HOST:PORT"),
        ("tcp/127.0.0.1", "expected PROTOCOL/HOST:PORT"),
        ("tcp/127.0.0.1:7447 ", "expected PROTOCOL/HOST:PORT"),
        ("tcp/a b:7447", "expected PROTOCOL/HOST:PORT"),
    ],
)
def test_bad_endpoints_say_what_is_wrong(tmp_path: Path, endpoint: str, why: str) -> None:
    problem = endpoint_problem(endpoint)
    assert problem is not None and why in problem
    text = (PROFILES / "sim.toml").read_text()
    path = tmp_path / "p.toml"
    path.write_text(text.replace('listen = ["tcp/127.0.0.1:7447"]', f"listen = [{endpoint!r}]"))
    with pytest.raises(InputError, match=r"transport\.listen\[0\]") as info:
        load_profile(path)
    assert why in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("edit", "field", "why"),
    [
        (("ee_speed_cap = 0.2", "ee_speed_cap = 0.05"), "bridge.ee_speed_cap", "top speed"),
        (("command_rate_hz = 60.0", "command_rate_hz = 10.0"), "bridge.command_rate_hz", "rate"),
        (("max_ttl = 0.2", "max_ttl = 0.05"), "bridge.max_ttl", "two control periods"),
        (("joint_speed_cap = 0.8", "joint_speed_cap = 5.0"), "bridge.joint_speed_cap", ""),
        (("workspace_margin = 0.02", "workspace_margin = -0.1"), "bridge.workspace_margin", ""),
    ],
)
def test_bridge_limits_agree_with_the_control_table(
    tmp_path: Path, edit: tuple[str, str], field: str, why: str
) -> None:
    """The bridge's own limits must leave the daemon's commands alone: a cap below the
    daemon's top speed, a rate below the control rate or a command life shorter than two
    periods would cut every command; each is one line naming the field."""
    text = (PROFILES / "sawyer.toml").read_text()
    assert edit[0] in text
    path = tmp_path / "p.toml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(InputError) as info:
        load_profile(path)
    message = str(info.value)
    assert message.startswith(f"{path}:{_line_of(text, edit)}: {field}: "), message
    assert why in message
    assert "\n" not in message


def _line_of(text: str, edit: tuple[str, str]) -> int:
    """The line the edit's last line is on once made (where the error must point)."""
    edited = text.replace(edit[0], edit[1], 1)
    return edited[: edited.index(edit[1]) + len(edit[1])].count("\n") + 1


OPERATOR_FILE = {
    "schema": 1, "name": "alice", "speed": 0.92, "sigma": 0.031, "rho": 0.83, "bias_deg": -4.1,
    "steering": "free", "segments": 20, "ticks": 3120,
    "intervals": {"speed": [0.9, 0.94], "sigma": [0.029, 0.033], "rho": [0.8, 0.86],
                  "bias_deg": [-6.0, -2.2]},
    "certify_with": {"speed": 0.9, "sigma": 0.033, "rho": 0.86, "bias_deg": -6.0,
                     "steering": "free"},
}  # fmt: skip


def _with_operator(tmp_path: Path, value: str) -> Path:
    text = (PROFILES / "sim.toml").read_text()
    path = tmp_path / "bench" / "alice.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(text.replace("[control]\n", f'[control]\noperator = "{value}"\n', 1))
    return path


def test_the_operator_key_is_relative_to_the_profiles_folder_and_read_on_load(
    tmp_path: Path,
) -> None:
    profile = _with_operator(tmp_path, "people/alice.json")
    (profile.parent / "people").mkdir()
    (profile.parent / "people" / "alice.json").write_text(json.dumps(OPERATOR_FILE))
    p = load_profile(profile)
    assert p.control.operator == str((profile.parent / "people" / "alice.json").absolute())
    assert load_profile(PROFILES / "sim.toml").control.operator is None


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (None, "control.operator: "),  # no such file
        ('{"schema": 1}', "control.operator: "),
        ("rho", "control.operator: "),  # a number out of its range
    ],
)
def test_a_bad_operator_file_is_one_line_naming_the_profile_the_file_and_the_field(
    tmp_path: Path, content: str | None, says: str
) -> None:
    profile = _with_operator(tmp_path, "alice.json")
    target = profile.parent / "alice.json"
    if content == "rho":
        bad = {**OPERATOR_FILE, "rho": 1.5}
        target.write_text(json.dumps(bad))
    elif content is not None:
        target.write_text(content)
    with pytest.raises(InputError) as info:
        load_profile(profile)
    message = str(info.value)
    line = profile.read_text().splitlines().index('operator = "alice.json"') + 1
    assert message.startswith(f"{profile}:{line}: {says}"), message
    assert str(target) in message
    assert "\n" not in message
    if content == "rho":
        assert "rho" in message.split(str(target))[-1]


def test_the_arm_is_the_profiles_own_and_the_sawyer_adapter_drives_only_the_sawyer(
    tmp_path: Path,
) -> None:
    assert load_profile(PROFILES / "sim.toml").arm == "sawyer"  # absent: the default arm
    assert load_profile(PROFILES / "panda_sim.toml").arm == "panda"
    text = (PROFILES / "sawyer.toml").read_text()
    path = tmp_path / "p.toml"
    path.write_text(text.replace('adapter = "sawyer"', 'adapter = "sawyer"\narm = "ur5e"', 1))
    with pytest.raises(InputError, match="arm: the sawyer adapter drives the Sawyer only"):
        load_profile(path)
    spec = load_profile(PROFILES / "sim.toml")
    assert with_arm(spec, "kinova3").arm == "kinova3" and spec.arm == "sawyer"
    with pytest.raises(InputError, match="--robot: arm: expected one of: sawyer, kinova3"):
        with_arm(spec, "baxter")


def test_the_bridge_adapter_drives_any_arm_and_older_profiles_still_load(tmp_path: Path) -> None:
    """``adapter = "bridge"`` on every registered arm; the link's table is ``[link]``, and the
    ``[sawyer]`` of older profiles reads the same (both at once: one is left over)."""
    panda = load_profile(PROFILES / "panda.toml")
    assert (panda.adapter, panda.arm, panda.robot) == ("bridge", "panda", "panda")
    text = (PROFILES / "sawyer.toml").read_text()
    path = tmp_path / "p.toml"
    for arm_name in ("ur5e", "kinova3"):
        path.write_text(
            text.replace('adapter = "sawyer"', f'adapter = "bridge"\narm = "{arm_name}"')
        )
        assert load_profile(path).arm == arm_name
    old = text.replace("[link]", "[sawyer]").replace("bridge_timeout = 3.0", "bridge_timeout = 2.5")
    path.write_text(old)
    assert load_profile(path).link.bridge_timeout == 2.5
    path.write_text(old.replace("[sawyer]", "[sawyer]\nheartbeat_timeout = 0.4\n[link]", 1))
    with pytest.raises(InputError, match=r"p\.toml"):
        load_profile(path)
