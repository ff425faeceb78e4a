"""Input device mappings: the shipped ones load, bad ones give one line naming file and field."""

from __future__ import annotations

import copy
import re
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from evdev import ecodes

from legws_daemon.errors import InputError
from legws_daemon.formats.input_mapping import (
    ENABLE_REQUIRED,
    load_mapping,
    load_mapping_named,
    mapping_names,
    mappings_dir,
    resolve_code,
    shipped_mappings,
)
from legws_daemon.formats.validation import ManyInputsError
from tests.formats.helpers import toml_dumps

INPUT = Path(__file__).parents[2] / "hw_profiles" / "input"


def xbox_data() -> dict[str, Any]:
    return tomllib.loads((INPUT / "xbox.toml").read_text(encoding="utf-8"))


def test_the_shipped_mappings_load() -> None:
    assert mapping_names() == ["hid_joystick", "playstation", "spacemouse", "xbox"]
    assert mappings_dir() == INPUT
    mappings = dict(shipped_mappings())
    xbox = mappings["xbox"]
    assert xbox.device.kind == "gamepad"
    assert [b.code for b in xbox.buttons.enable] == ["BTN_TL"]
    assert [b.code for b in xbox.buttons.confirm] == ["BTN_SOUTH"]
    assert [b.code for b in xbox.buttons.cancel] == ["BTN_EAST"]
    assert {(a.code, a.drives, a.invert) for a in xbox.axis} >= {
        ("ABS_Y", "x", True),
        ("ABS_X", "y", True),
        ("ABS_RY", "z", True),
        ("ABS_RX", "rz", True),  # the right stick turns the gripper about z
    }
    assert [b.code for b in xbox.buttons.gripper] == ["BTN_NORTH"]
    assert [b.code for b in xbox.buttons.speed] == ["BTN_WEST"]
    assert [a.index for a in xbox.axis if a.turns] == [2, 0]  # rz, rx
    puck = mappings["spacemouse"]
    assert [b.code for b in puck.buttons.enable] == ["BTN_0"]  # the left button, held
    assert [b.code for b in puck.buttons.confirm] == ["BTN_1"] and puck.buttons.cancel == ()
    moves = {"REL_X", "REL_Y", "REL_Z", "ABS_X", "ABS_Y", "ABS_Z"}
    assert {a.code for a in puck.axis if not a.turns} == moves
    assert {a.code for a in puck.axis if a.turns} == {
        "REL_RX", "REL_RY", "REL_RZ", "ABS_RX", "ABS_RY", "ABS_RZ"
    }  # fmt: skip
    assert [b.code for b in puck.buttons.gripper] == ["BTN_2"]
    assert all(a.full_scale == 350 and a.hold_time == 0.1 for a in puck.axis if a.relative)
    assert all((a.min, a.max) == (-350, 350) for a in puck.axis if not a.relative)
    hid = mappings["hid_joystick"]
    assert [b.code for b in hid.buttons.enable] == ["BTN_TRIGGER"]
    for mapping in mappings.values():
        assert mapping.device.match or mapping.device.ids


def test_recognition_by_name_or_id() -> None:
    xbox = dict(shipped_mappings())["xbox"].device
    assert xbox.recognises("Microsoft X-Box One S pad", 0, 0)
    assert xbox.recognises("Some pad", 0x045E, 0x028E)
    assert not xbox.recognises("Some pad", 0x045E, 0x0001)
    puck = dict(shipped_mappings())["spacemouse"].device
    assert puck.recognises("3Dconnexion SpaceNavigator", 0, 0)
    assert puck.recognises("anything", 0x256F, 0x1234)  # a 3Dconnexion vendor id: any product
    assert not puck.recognises("Logitech USB Receiver", 0x046D, 0xC52B)


def test_names_and_paths() -> None:
    name, mapping = load_mapping_named("spacemouse")
    assert name == "spacemouse"
    assert load_mapping_named(INPUT / "spacemouse.toml") == (name, mapping)
    with pytest.raises(InputError) as info:
        load_mapping_named("ps5")
    assert str(info.value) == (
        "mapping: unknown input mapping 'ps5'; known: hid_joystick, playstation, spacemouse, "
        "xbox (or a .toml path)"
    )
    with pytest.raises(InputError, match=r"nope\.toml: no such file"):
        load_mapping_named("nope.toml")


def test_the_mappings_folder_follows_legws_profiles(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "input").mkdir()
    (tmp_path / "input" / "mine.toml").write_text(toml_dumps(xbox_data()), encoding="utf-8")
    monkeypatch.setenv("LEGWS_PROFILES", str(tmp_path))
    assert mapping_names() == ["mine"]
    assert load_mapping_named("mine")[1].device.name == "Xbox-style gamepad"


def test_code_names() -> None:
    assert resolve_code("ABS_Y", ecodes.EV_ABS) == (ecodes.EV_ABS, ecodes.ABS_Y)
    assert resolve_code("BTN_A", ecodes.EV_KEY) == resolve_code("BTN_SOUTH", ecodes.EV_KEY)
    assert resolve_code("REL_X", ecodes.EV_ABS, ecodes.EV_REL) == (ecodes.EV_REL, ecodes.REL_X)
    with pytest.raises(ValueError, match=r"did you mean BTN_SOUTH"):
        resolve_code("BTN_SOTH", ecodes.EV_KEY)


Edit = Callable[[dict[str, Any]], None]


def _set(path: tuple[str | int, ...], value: Any) -> Edit:
    def edit(doc: dict[str, Any]) -> None:
        target: Any = doc
        for part in path[:-1]:
            target = target[part]
        target[path[-1]] = value

    return edit


def _drop(path: tuple[str | int, ...]) -> Edit:
    def edit(doc: dict[str, Any]) -> None:
        target: Any = doc
        for part in path[:-1]:
            target = target[part]
        del target[path[-1]]

    return edit


BAD: list[tuple[str, Edit, str | None, str]] = [
    # (id, edit, field, a needle of the message)
    ("unknown code", _set(("axis", 0, "code"), "ABS_Q"), "axis[0].code", "unknown evdev code"),
    ("button as axis", _set(("axis", 0, "code"), "BTN_A"), "axis[0].code", "is not an absolute"),
    ("lowercase code", _set(("axis", 0, "code"), "abs_y"), "axis[0].code", "did you mean ABS_Y"),
    ("limit code", _set(("axis", 1, "code"), "ABS_MAX"), "axis[1].code", "unknown evdev code"),
    (
        "base axis",
        _set(("axis", 0, "drives"), "w"),
        "axis[0].drives",
        "'x', 'y', 'z', 'rx', 'ry' or 'rz'",
    ),
    ("deadzone 1", _set(("axis", 0, "deadzone"), 1.0), "axis[0].deadzone", "less than 1"),
    ("deadzone < 0", _set(("axis", 0, "deadzone"), -0.1), "axis[0].deadzone", "greater than"),
    ("deadzone text", _set(("axis", 0, "deadzone"), "0.1"), "axis[0].deadzone", "valid number"),
    ("curve name", _set(("axis", 0, "curve"), "steep"), "axis[0].curve", "linear, quadratic"),
    ("curve exponent", _set(("axis", 0, "curve"), 7), "axis[0].curve", "exponent in [0.25, 5]"),
    ("curve bool", _set(("axis", 0, "curve"), True), "axis[0].curve", "got True"),
    ("scale 0", _set(("axis", 0, "scale"), 0.0), "axis[0].scale", "greater than 0"),
    ("invert text", _set(("axis", 0, "invert"), "yes"), "axis[0].invert", "valid boolean"),
    ("rel, no scale", _set(("axis", 0, "code"), "REL_Y"), "axis[0].full_scale", "required"),
    ("min only", _set(("axis", 0, "min"), -10), "axis[0].max", "both min and max"),
    (
        "min >= max",
        _set(("axis", 0), {"code": "ABS_Y", "drives": "x", "min": 5, "max": 5}),
        "axis[0].max",
        "greater than min (5), got 5",
    ),
    ("hold on abs", _set(("axis", 0, "hold"), 0.2), "axis[0].hold", "only for a relative"),
    ("unknown key", _set(("axis", 0, "gain"), 2.0), "axis[0].gain", "Extra inputs"),
    ("twice an axis", _set(("axis", 1, "code"), "ABS_Y"), "axis[1].code", "is also axis[0].code"),
    ("no axes", _set(("axis",), []), "axis", "at least 1 item"),
    ("no enable", _drop(("buttons", "enable")), "buttons.enable", 'or "none"'),
    ("no buttons", _drop(("buttons",)), "buttons.enable", "the hold-to-run button"),
    ("empty enable", _set(("buttons", "enable"), []), "buttons.enable", "an empty list"),
    ("NONE", _set(("buttons", "enable"), "NONE"), "buttons.enable", "unknown evdev code"),
    ("confirm none", _set(("buttons", "confirm"), "none"), "buttons.confirm", "only as the"),
    ("enable number", _set(("buttons", "enable"), 3), "buttons.enable", "got 3"),
    ("bad button", _set(("buttons", "cancel"), "BTN_SOUT"), "buttons.cancel", "BTN_SOUTH"),
    (
        "bad in list",
        _set(("buttons", "cancel"), ["BTN_EAST", "BTN_NOPE"]),
        "buttons.cancel[1]",
        "unknown evdev code 'BTN_NOPE'",
    ),
    ("axis code button", _set(("buttons", "cancel"), "ABS_Z"), "buttons.cancel", "threshold"),
    (
        "rel as button",
        _set(("buttons", "cancel"), "REL_X"),
        "buttons.cancel",
        "is not a button (BTN_* or KEY_*) or an absolute axis",
    ),
    (
        "duplicate button",
        _set(("buttons", "confirm"), "BTN_TL"),
        "buttons.confirm",
        "BTN_TL is also buttons.enable",
    ),
    (
        "duplicate alias",
        _set(("buttons", "cancel"), "BTN_A"),
        "buttons.cancel",
        "BTN_A is also buttons.confirm",
    ),
    (
        "duplicate in list",
        _set(("buttons", "enable"), ["BTN_TL", "BTN_TL"]),
        "buttons.enable[1]",
        "is also buttons.enable[0]",
    ),
    (
        "button is an axis",
        _set(("buttons", "cancel"), {"code": "ABS_Y", "threshold": 0.5}),
        "buttons.cancel",
        "ABS_Y is also axis[0].code",
    ),
    (
        "threshold 1",
        _set(("buttons", "cancel"), {"code": "ABS_Z", "threshold": 1.0}),
        "buttons.cancel[0].threshold",
        "less than 1",
    ),
    (
        "threshold on a key",
        _set(("buttons", "cancel"), {"code": "BTN_EAST", "threshold": 0.5}),
        "buttons.cancel[0].threshold",
        "only for an axis used as a button",
    ),
    ("no match", _set(("device", "match"), []), None, ""),  # ids remain: fine
    ("nothing to match", _set(("device",), {"name": "x"}), "device.match", "match"),
    ("vendor", _set(("device", "ids"), [{"vendor": 70000}]), "device.ids[0].vendor", "65535"),
    ("kind", _set(("device", "kind"), "wheel"), "device.kind", "'gamepad'"),
    ("name", _set(("device", "name"), ""), "device.name", "at least 1"),
    ("schema", _set(("schema_version",), 2), "schema_version", "Input should be 1"),
    ("top-level key", _set(("robot",), "x"), "robot", "Extra inputs"),
]


@pytest.mark.parametrize(("edit", "field", "needle"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_mappings_name_file_and_field(
    tmp_path: Path, edit: Edit, field: str | None, needle: str
) -> None:
    doc = copy.deepcopy(xbox_data())
    edit(doc)
    path = tmp_path / "pad.toml"
    path.write_text(toml_dumps(doc), encoding="utf-8")
    if field is None:
        load_mapping(path)
        return
    with pytest.raises(InputError) as info:
        load_mapping(path)
    message = str(info.value)
    # (no line for a table the file leaves out: "no buttons")
    assert re.match(rf"{re.escape(str(path))}(:[0-9]+)?: {re.escape(field)}: ", message), message
    assert needle in message
    assert "\n" not in message
    assert not isinstance(info.value, ManyInputsError), message  # one error, not a union's list


def test_the_enable_declaration_message() -> None:
    assert '"none"' in ENABLE_REQUIRED
    assert "hold-to-run" in ENABLE_REQUIRED


def test_good_variants(tmp_path: Path) -> None:
    doc = xbox_data()
    doc["buttons"]["enable"] = ["BTN_TL", "BTN_TR", {"code": "ABS_RZ", "threshold": 0.4}]
    doc["axis"][0]["curve"] = 1.5
    doc["axis"].append({"code": "ABS_Z", "drives": "z", "rest": "min", "invert": True})
    doc["axis"].append({"code": "REL_WHEEL", "drives": "z", "full_scale": 5, "hold": 0.3})
    path = tmp_path / "pad.toml"
    path.write_text(toml_dumps(doc), encoding="utf-8")
    mapping = load_mapping(path)
    assert [b.code for b in mapping.buttons.enable] == ["BTN_TL", "BTN_TR", "ABS_RZ"]
    assert mapping.buttons.enable[2].cutoff == 0.4
    assert mapping.axis[0].exponent == 1.5
    assert mapping.axis[-1].hold_time == 0.3
    doc["buttons"] = {"enable": "none"}
    path.write_text(toml_dumps(doc), encoding="utf-8")
    mapping = load_mapping(path)
    assert mapping.buttons.enable == mapping.buttons.confirm == mapping.buttons.cancel == ()


def test_toml_syntax_and_non_finite_numbers(tmp_path: Path) -> None:
    path = tmp_path / "pad.toml"
    path.write_text("schema_version = 1\n[device\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"pad\.toml: invalid TOML"):
        load_mapping(path)
    doc = xbox_data()
    doc["axis"][0]["scale"] = float("nan")
    path.write_text(toml_dumps(doc), encoding="utf-8")
    with pytest.raises(InputError, match=r"pad\.toml:[0-9]+: axis\[0\]\.scale: expected a finite"):
        load_mapping(path)
