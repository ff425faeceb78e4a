"""Input device mappings (``hw_profiles/input/*.toml``): which evdev device, which codes steer.

A mapping tells ``legws joystick evdev`` how to recognise a device (a gamepad, a 3Dconnexion
SpaceMouse, a HID joystick) and how its evdev event codes become a deflection in the robot
base frame and the buttons of a joystick message. Validated on load like every file: unknown
keys are refused and every error is one line naming the file and the field. Example::

    schema_version = 1

    [device]
    name = "Xbox-style gamepad"          # for people (1 to 64 characters)
    kind = "gamepad"                     # optional: "gamepad" | "spacemouse" | "joystick"
    match = ["xbox", "x-box"]            # case-insensitive substrings of the evdev name
    ids = [{ vendor = 0x045e, product = 0x028e }]   # and/or USB ids (product optional)

    [[axis]]                             # one table per evdev axis
    code = "ABS_Y"                       # ABS_* (absolute) or REL_* (relative) code name
    drives = "x"                         # base-frame axis "x", "y", "z"; a turn "rx", "ry", "rz"
    invert = true                        # stick up reports negative ABS_Y: up = +x
    deadzone = 0.15                      # fraction of the range around rest: output 0
    curve = "quadratic"                  # "linear", "quadratic", "cubic" or an exponent
    scale = 1.0                          # gain after the curve (the sum is clipped)

    [buttons]
    enable = "BTN_TL"                    # hold-to-run; a list: any of them; or "none"
    confirm = "BTN_SOUTH"                # optional, a code or a list
    cancel = "BTN_EAST"                  # optional, a code or a list
    gripper = "BTN_NORTH"                # optional: each press opens or closes the gripper
    speed = "BTN_WEST"                   # optional: each press steps the speed 1, 0.5, 0.25

``[device]``: a device is recognised when its name contains one of ``match`` (compared
case-insensitively) or its vendor (and product, if given) is one of ``ids``; at least one of
the two lists must be non-empty. A recognised device is used only if it also has every
enable button and at least one of the mapped axes (see
:mod:`legws_daemon.joystick.evdev_state`), so the keyboard node many pads create beside
their main node is not taken.

``[[axis]]``: one entry per evdev axis; two codes may drive the same base axis (a d-pad and
a stick): their contributions are summed, each base axis is clipped to [-1, 1] and then the
deflection to norm 1. ``drives = "rx"``, ``"ry"`` or ``"rz"``: the axis turns the EE about
that base-frame axis (the message's ``rotation``, clipped the same way; the EE turns at the
profile's ``w_teleop`` times it). The raw value is normalised to [-1, 1] first:

- ``ABS_*`` (absolute: sticks, d-pads, triggers; a SpaceMouse on some kernels): the range
  is ``min``/``max`` if given (both or neither), else the device's own (its absinfo) when
  the device is open; an axis with neither is inactive. ``rest = "center"`` (default, a
  stick: the middle of the range is 0) or ``"min"`` (a trigger: 0 at ``min``, 1 at
  ``max``). An absolute axis keeps its last reported value.
- ``REL_*`` (relative: a SpaceMouse under most kernels reports its displacement as EV_REL
  events, and only while it is displaced): ``full_scale`` is required (the raw value of
  full deflection, e.g. 350), ``hold`` (s, default 0.1) is how long a value stays valid:
  the kernel drops zero-valued relative events, so an axis with no event for longer than
  ``hold`` is back at rest.

Then ``deadzone`` (a fraction in [0, 1): a normalised magnitude up to it is exactly 0), the
response ``curve`` (``linear`` = exponent 1, ``quadratic`` = 2, ``cubic`` = 3, or an
exponent in [0.25, 5]; applied after the deadzone with rescaling, so the output is
continuous, monotone, 0 at the deadzone's edge and 1 at full deflection), ``scale`` (in
(0, 10]) and ``invert``.

``[buttons]``: each role takes a button code name (``BTN_*`` or ``KEY_*``), a trigger axis
used as a button (``{ code = "ABS_Z", threshold = 0.5 }``: pressed at or above that fraction
of its range; ``min``/``max`` as for axes), or a list of these (any of them pressed counts).
``enable`` (hold-to-run) must be declared: without it held the publisher sends zero
deflection and no confirm or cancel, with ``enable: false``; ``enable = "none"`` says
explicitly that the device has no such button (every message then says ``enable: true``
and the stream itself is the dead-man signal). ``confirm`` and ``cancel`` are optional, and
so are ``gripper`` (each press toggles the gripper asked for: ``buttons.gripper``) and
``speed`` (each press steps the speed scale by which deflection and rotation are multiplied:
:mod:`legws_daemon.joystick.hand`). A code may appear only once in the whole file (as an
axis or in one button role).
"""

from __future__ import annotations

import difflib
import os
from functools import cache
from pathlib import Path
from typing import Annotated, Any, Literal

from evdev import ecodes
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    StrictBool,
    StrictInt,
    model_validator,
)

from legws_daemon.errors import InputError
from legws_daemon.formats.profile import profiles_dir
from legws_daemon.formats.validation import (
    did_you_mean,
    field_error,
    field_path,
    printable,
    read_toml_with_lines,
    validate,
)

#: The base-frame axes, in the order of a joystick message's ``axes``.
BASE_AXES: tuple[str, str, str] = ("x", "y", "z")
#: The turns about them, in the order of a joystick message's ``rotation``.
TURN_AXES: tuple[str, str, str] = ("rx", "ry", "rz")
#: Named response curves and their exponents.
CURVES: dict[str, float] = {"linear": 1.0, "quadratic": 2.0, "cubic": 3.0}
#: How long a relative axis's value lasts without a new event, s (see ``hold``).
DEFAULT_HOLD = 0.1

EV_ABS: int = ecodes.EV_ABS
EV_REL: int = ecodes.EV_REL
EV_KEY: int = ecodes.EV_KEY
_PREFIXES: dict[str, int] = {"ABS_": EV_ABS, "REL_": EV_REL, "KEY_": EV_KEY, "BTN_": EV_KEY}
_TABLES: dict[int, dict[int, Any]] = {EV_ABS: ecodes.ABS, EV_REL: ecodes.REL, EV_KEY: ecodes.keys}
_KIND_WORDS = {EV_ABS: "an absolute axis (ABS_*)", EV_REL: "a relative axis (REL_*)"}
_KIND_WORDS[EV_KEY] = "a button (BTN_* or KEY_*)"

Ratio = Annotated[float, Strict(), Field(ge=0.0, lt=1.0, allow_inf_nan=False)]
Gain = Annotated[float, Strict(), Field(gt=0.0, le=10.0, allow_inf_nan=False)]
Threshold = Annotated[float, Strict(), Field(gt=0.0, lt=1.0, allow_inf_nan=False)]
HoldTime = Annotated[float, Strict(), Field(gt=0.0, le=1.0, allow_inf_nan=False)]
Raw = Annotated[int, Strict(), Field(ge=-(2**31), le=2**31 - 1)]
UsbNumber = Annotated[int, Strict(), Field(ge=0, le=0xFFFF)]
Text = Annotated[str, Field(min_length=1, max_length=64)]


def _is_limit(name: str) -> bool:
    return name.endswith(("_MAX", "_CNT"))


def _names_of(etype: int) -> list[str]:
    return sorted(n for n, c in ecodes.ecodes.items() if _type_of(n) == etype and not _is_limit(n))


def _type_of(name: str) -> int | None:
    return next((t for p, t in _PREFIXES.items() if name.startswith(p)), None)


@cache
def resolve_code(name: str, *allowed: int) -> tuple[int, int]:
    """``"ABS_Y"`` -> ``(EV_ABS, 1)``: the event type and code of an evdev code name.

    Raises ``ValueError`` (a validator's error) for an unknown name or one of a type not in
    ``allowed``, suggesting close names.
    """
    wanted = " or ".join(_KIND_WORDS[t] for t in allowed)
    etype = _type_of(name)
    code = ecodes.ecodes.get(name)
    if etype is None or etype not in allowed or code is None or _is_limit(name):
        if etype is not None and etype not in allowed and code is not None:
            raise ValueError(f"{name} is not {wanted}")
        close = difflib.get_close_matches(name.upper(), [n for t in allowed for n in _names_of(t)])
        hint = f" (did you mean {', '.join(close[:3])}?)" if close else ""
        raise ValueError(f"unknown evdev code {printable(name)!r}, expected {wanted}{hint}")
    if code not in _TABLES[etype]:
        raise ValueError(f"unknown evdev code {name!r}, expected {wanted}")
    return etype, code


def _axis_code(name: str) -> str:
    try:
        resolve_code(name, EV_ABS, EV_REL)
    except ValueError as err:
        raise field_error((), str(err)) from None  # the message quotes the name already
    return name


def _curve(value: Any) -> Any:
    """A curve's name, or an exponent in [0.25, 5]."""
    if isinstance(value, str) and value in CURVES:
        return value
    if isinstance(value, int | float) and not isinstance(value, bool) and 0.25 <= value <= 5:
        return float(value)
    raise field_error(
        (), f"expected {', '.join(CURVES)} or an exponent in [0.25, 5], got {value!r}"
    )


AxisCode = Annotated[str, AfterValidator(_axis_code)]
Curve = Annotated[str | float, BeforeValidator(_curve)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class UsbId(_Model):
    """A USB (or Bluetooth) vendor id, and optionally the product id."""

    vendor: UsbNumber
    product: UsbNumber | None = None

    def matches(self, vendor: int, product: int) -> bool:
        return vendor == self.vendor and self.product in (None, product)


class DeviceSpec(_Model):
    name: Text
    kind: Literal["gamepad", "spacemouse", "joystick"] | None = None
    #: case-insensitive substrings of the evdev device name
    match: list[Text] = []
    ids: list[UsbId] = []

    @model_validator(mode="after")
    def _recognisable(self) -> DeviceSpec:
        if not self.match and not self.ids:
            raise field_error(("match",), "give match (name substrings) or ids, or both")
        return self

    def recognises(self, name: str, vendor: int, product: int) -> bool:
        """Whether an evdev device of this name and ids is this kind of device."""
        folded = name.casefold()
        return any(m.casefold() in folded for m in self.match) or any(
            i.matches(vendor, product) for i in self.ids
        )


def _check_range(lo: int | None, hi: int | None) -> None:
    if (lo is None) != (hi is None):
        raise field_error(("min" if lo is None else "max",), "give both min and max, or neither")
    if lo is not None and hi is not None and not lo < hi:
        raise field_error(("max",), f"must be greater than min ({lo}), got {hi}")


class AxisSpec(_Model):
    """One evdev axis driving one base-frame axis (see the module docstring)."""

    code: AxisCode
    drives: Literal["x", "y", "z", "rx", "ry", "rz"]
    scale: Gain = 1.0
    invert: StrictBool = False
    deadzone: Ratio = 0.0
    curve: Curve = "linear"
    min: Raw | None = None
    max: Raw | None = None
    rest: Literal["center", "min"] | None = None
    full_scale: Annotated[StrictInt, Field(gt=0, le=2**31 - 1)] | None = None
    hold: HoldTime | None = None

    @model_validator(mode="after")
    def _by_type(self) -> AxisSpec:
        if self.relative:
            if self.full_scale is None:
                raise field_error(
                    ("full_scale",),
                    f"required for a relative axis ({self.code}): the raw value of full "
                    "deflection, e.g. 350 for a SpaceMouse",
                )
            for key in ("min", "max", "rest"):
                if getattr(self, key) is not None:
                    raise field_error((key,), f"only for an absolute axis, not {self.code}")
        else:
            for key in ("full_scale", "hold"):
                if getattr(self, key) is not None:
                    raise field_error((key,), f"only for a relative axis, not {self.code}")
            _check_range(self.min, self.max)
        return self

    @property
    def etype(self) -> int:
        return resolve_code(self.code, EV_ABS, EV_REL)[0]

    @property
    def number(self) -> int:
        return resolve_code(self.code, EV_ABS, EV_REL)[1]

    @property
    def relative(self) -> bool:
        return self.code.startswith("REL_")

    @property
    def turns(self) -> bool:
        """Whether the axis turns the EE (``rotation``) rather than moving it (``axes``)."""
        return self.drives in TURN_AXES

    @property
    def index(self) -> int:
        """The base-frame axis as an index into ``axes`` (or ``rotation``, for a turn)."""
        return TURN_AXES.index(self.drives) if self.turns else BASE_AXES.index(self.drives)

    @property
    def exponent(self) -> float:
        return CURVES[self.curve] if isinstance(self.curve, str) else float(self.curve)

    @property
    def hold_time(self) -> float:
        return self.hold if self.hold is not None else DEFAULT_HOLD


class ButtonRef(_Model):
    """One button: an EV_KEY code, or an absolute axis pressed at ``threshold`` of its range."""

    code: Text
    threshold: Threshold | None = None
    min: Raw | None = None
    max: Raw | None = None

    @model_validator(mode="after")
    def _by_type(self) -> ButtonRef:
        try:
            etype, _ = resolve_code(self.code, EV_KEY, EV_ABS)
        except ValueError as err:
            raise field_error(("code",), str(err)) from None
        if etype == EV_KEY:
            for key in ("threshold", "min", "max"):
                if getattr(self, key) is not None:
                    raise field_error((key,), f"only for an axis used as a button, not {self.code}")
        else:
            _check_range(self.min, self.max)
        return self

    @property
    def etype(self) -> int:
        return resolve_code(self.code, EV_KEY, EV_ABS)[0]

    @property
    def number(self) -> int:
        return resolve_code(self.code, EV_KEY, EV_ABS)[1]

    @property
    def cutoff(self) -> float:
        """The pressed threshold of an axis button, a fraction of its range (default 0.5)."""
        return self.threshold if self.threshold is not None else 0.5


ENABLE_REQUIRED = (
    'required: the hold-to-run button (e.g. "BTN_TL"), a list of them (any one held '
    'enables), or "none" (the device has none: every message is enabled)'
)
_ROLES = ("enable", "confirm", "cancel", "gripper", "speed")


def _button_list(value: Any, role: str) -> list[Any]:
    """A role's value as a list of ``ButtonRef`` inputs; plain code names checked here so
    the error points at the value the file has (``buttons.enable``, ``buttons.cancel[1]``)."""
    items = value if isinstance(value, list) else [value]
    if isinstance(value, list) and not value:
        raise field_error((role,), 'an empty list; leave the key out (or, for enable, "none")')
    out: list[Any] = []
    for i, item in enumerate(items):
        loc: tuple[str | int, ...] = (role, i) if isinstance(value, list) else (role,)
        if isinstance(item, str):
            if item == "none":
                raise field_error(loc, '"none" only as the whole value of enable')
            try:
                etype, _ = resolve_code(item, EV_KEY, EV_ABS)
            except ValueError as err:
                raise field_error(loc, str(err)) from None
            if etype == EV_ABS:
                raise field_error(
                    loc,
                    f'an axis as a button needs a threshold: {{ code = "{item}", '
                    "threshold = 0.5 }",
                )
            out.append({"code": item})
        elif isinstance(item, dict):
            out.append(item)
        else:
            raise field_error(loc, f"expected a button code name or table, got {item!r}")
    return out


class ButtonsSpec(_Model):
    """The buttons of each role, normalised to tuples; ``enable = ()`` is the file's
    ``enable = "none"`` (the key itself is required)."""

    enable: tuple[ButtonRef, ...]
    confirm: tuple[ButtonRef, ...] = ()
    cancel: tuple[ButtonRef, ...] = ()
    gripper: tuple[ButtonRef, ...] = ()
    speed: tuple[ButtonRef, ...] = ()

    @model_validator(mode="before")
    @classmethod
    def _normalise(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        if "enable" not in data:
            raise field_error(("enable",), ENABLE_REQUIRED)
        out = dict(data)
        for role in _ROLES:
            if role == "enable" and data[role] == "none":
                out[role] = ()
            elif role in data:
                out[role] = _button_list(data[role], role)
        return out

    @property
    def hold_to_run(self) -> bool:
        """Whether the device has an enable button (``False``: ``enable = "none"``)."""
        return bool(self.enable)

    def refs(self) -> list[tuple[tuple[str | int, ...], ButtonRef]]:
        """Every button with its location in the file, e.g. ``(("cancel", 1), ref)``; a role
        with one button has no index."""
        out: list[tuple[tuple[str | int, ...], ButtonRef]] = []
        for role in _ROLES:
            group: tuple[ButtonRef, ...] = getattr(self, role)
            for i, ref in enumerate(group):
                out.append(((role, i) if len(group) > 1 else (role,), ref))
        return out


class InputMapping(_Model):
    """A validated device mapping file (see the module docstring)."""

    schema_version: Literal[1]
    device: DeviceSpec
    axis: Annotated[list[AxisSpec], Field(min_length=1, max_length=64)]
    buttons: ButtonsSpec

    @model_validator(mode="before")
    @classmethod
    def _enable_declared(cls, data: Any) -> Any:
        if isinstance(data, dict) and "buttons" not in data:
            raise field_error(("buttons", "enable"), ENABLE_REQUIRED)
        return data

    @model_validator(mode="after")
    def _codes_once(self) -> InputMapping:
        uses: list[tuple[tuple[str | int, ...], tuple[int, int], str]] = [
            (("axis", i, "code"), (a.etype, a.number), a.code) for i, a in enumerate(self.axis)
        ]
        uses += [(("buttons", *loc), (r.etype, r.number), r.code) for loc, r in self.buttons.refs()]
        seen: dict[tuple[int, int], tuple[str | int, ...]] = {}
        for loc, key, name in uses:
            if key in seen:
                raise field_error(
                    loc, f"{name} is also {field_path(seen[key])}; use each code once"
                )
            seen[key] = loc
        return self


def load_mapping(path: Path) -> InputMapping:
    """Read and validate a mapping file; errors name the file, the line and the field
    (every one of them)."""
    data, where = read_toml_with_lines(path, "input mapping")
    return validate(InputMapping, data, str(path), where)


def mappings_dir() -> Path:
    """The folder of the shipped mappings: ``hw_profiles/input/`` (or ``$LEGWS_PROFILES/input``)."""
    return profiles_dir() / "input"


def mapping_names() -> list[str]:
    """The names of the shipped mappings, sorted (the order auto-selection tries them in)."""
    return sorted(p.stem for p in mappings_dir().glob("*.toml"))


def load_mapping_named(name_or_path: str | Path) -> tuple[str, InputMapping]:
    """A mapping by name (``xbox`` -> ``hw_profiles/input/xbox.toml``) or from a path, and
    its name (the file's stem). An unknown name lists the known ones (``did you mean``
    a close one)."""
    text = str(name_or_path)
    if text.endswith(".toml") or os.sep in text:
        return Path(text).stem, load_mapping(Path(text))
    path = mappings_dir() / f"{text}.toml"
    if not path.is_file():
        names = mapping_names()
        guess = did_you_mean(text, names)
        hint = f"; did you mean {guess!r}?" if guess is not None else ";"
        known = ", ".join(names) or "(none)"
        raise InputError(
            f"unknown input mapping {printable(text)!r}{hint} known: {known} (or a .toml path)",
            field="mapping",
        )
    return text, load_mapping(path)


def shipped_mappings() -> list[tuple[str, InputMapping]]:
    """Every shipped mapping with its name, in :func:`mapping_names` order."""
    return [(name, load_mapping(mappings_dir() / f"{name}.toml")) for name in mapping_names()]
