"""The operator file (interfaces.md): the example reads, every bad field is one line."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.core.operator import OperatorModel
from legws_daemon.errors import InputError
from legws_daemon.formats.operator_file import load_operator

EXAMPLE: dict[str, Any] = {
    "schema": 1, "name": "alice", "speed": 0.92, "sigma": 0.031, "rho": 0.83,
    "bias_deg": -4.1, "steering": "free", "segments": 20, "ticks": 3120,
    "intervals": {"speed": [0.9, 0.94], "sigma": [0.029, 0.033], "rho": [0.8, 0.86],
                  "bias_deg": [-6.0, -2.2]},
    "certify_with": {"speed": 0.9, "sigma": 0.033, "rho": 0.86, "bias_deg": -6.0,
                     "steering": "free"},
}  # fmt: skip


def _write(tmp_path: Path, data: Any) -> Path:
    path = tmp_path / "alice.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def test_the_interfaces_example_reads_and_writes_back(tmp_path: Path) -> None:
    f = load_operator(_write(tmp_path, EXAMPLE))
    assert f.name == "alice" and f.segments == 20 and f.ticks == 3120
    assert f.certify_with == OperatorModel(0.9, 0.033, 0.86, -6.0, "free")
    assert f.fitted == OperatorModel(0.92, 0.031, 0.83, -4.1, "free")
    out = tmp_path / "again.json"
    f.write(out)
    assert json.loads(out.read_text()) == EXAMPLE


def _with(path: tuple[str, ...], value: Any) -> dict[str, Any]:
    data = copy.deepcopy(EXAMPLE)
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is None:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (("schema",), 2, "schema"),
        (("name",), "al ice", "name"),
        (("rho",), 1.5, "rho"),
        (("speed",), None, "speed"),
        (("steering",), "joystick", "steering"),
        (("certify_with", "speed"), 0.0, "certify_with.speed"),
        (("certify_with", "bias_deg"), 90.0, "certify_with.bias_deg"),
        (("intervals", "sigma"), [0.04, 0.03], "intervals.sigma"),
        (("intervals", "rho"), [0.8], "intervals.rho"),
        (("segments",), 0, "segments"),
        (("sigma",), "0.03", "sigma"),
    ],
)
def test_a_bad_field_is_one_line_naming_file_and_field(
    tmp_path: Path, path: tuple[str, ...], value: Any, field: str
) -> None:
    file = _write(tmp_path, _with(path, value))
    with pytest.raises(InputError) as err:
        load_operator(file)
    # a missing top-level key has no line; intervals.rho[1] is the missing second number
    assert re.match(rf"{re.escape(str(file))}(:[0-9]+)?: {re.escape(field)}", str(err.value))
    assert "\n" not in str(err.value)
