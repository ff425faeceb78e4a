"""Every bad input of ``legws certify`` exits 2 with one ``legws: error:`` line, no traceback.

The line names the offending file and the field (interfaces.md: "A bad file ... exits 2
with a one-line message naming the field, and prints no traceback").
"""

from __future__ import annotations

import json
import os
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tests.cli.helpers import EXAMPLE_GOALSET, LEGWS, Result, assert_bad_input, run_script

Mutation = Callable[[dict[str, Any]], None]
Cli = Callable[..., Result]
WriteJson = Callable[[str, Any], Path]


def _walk(doc: Any, path: tuple[str | int, ...]) -> Any:
    for key in path:
        doc = doc[key]
    return doc


def put(*path: str | int, value: Any) -> Mutation:
    """Set ``doc[path] = value``."""

    def mutate(doc: dict[str, Any]) -> None:
        _walk(doc, path[:-1])[path[-1]] = value

    return mutate


def drop(*path: str | int) -> Mutation:
    """Delete ``doc[path]``."""

    def mutate(doc: dict[str, Any]) -> None:
        del _walk(doc, path[:-1])[path[-1]]

    return mutate


X0_POSITION = EXAMPLE_GOALSET["x0"]["position"]

# (mutation of the example goal set, substrings the error line must contain besides the file)
BAD_GOALSETS = [
    pytest.param(drop("x0"), ["x0", "required"], id="missing-x0"),
    pytest.param(drop("goals"), ["goals", "required"], id="missing-goals"),
    pytest.param(drop("x0", "position"), ["x0.position"], id="x0-missing-position"),
    pytest.param(drop("goals", 1, "position"), ["goals[1].position"], id="goal-missing-position"),
    pytest.param(drop("goals", 0, "name"), ["goals[0].name"], id="goal-missing-name"),
    pytest.param(
        drop("goals", 1, "quaternion"), ["goals[1].quaternion"], id="goal-missing-quaternion"
    ),
    pytest.param(
        put("goals", 1, "position", value=["0.5", 0.0, 0.04]),
        ["goals[1].position", "'0.5'"],
        id="position-string-not-coerced",
    ),
    pytest.param(
        put("goals", 1, "position", value="0.5, 0.0, 0.04"),
        ["goals[1].position"],
        id="position-is-a-string",
    ),
    pytest.param(
        put("goals", 1, "position", value=[0.5, 0.0]), ["goals[1].position"], id="position-2-nums"
    ),
    pytest.param(
        put("goals", 1, "position", value=[0.5, 0.0, 0.04, 1.0]),
        ["goals[1].position"],
        id="position-4-nums",
    ),
    pytest.param(
        put("goals", 1, "position", value=[True, 0.0, 0.04]),
        ["goals[1].position[0]"],
        id="position-bool",
    ),
    pytest.param(put("params", "beta", value=True), ["params.beta"], id="param-bool"),
    pytest.param(
        put("goals", 0, "symmetry", value=True), ["goals[0].symmetry"], id="symmetry-bool"
    ),
    pytest.param(
        put("goals", 0, "symmetry", value=2.5), ["goals[0].symmetry"], id="symmetry-fraction"
    ),
    pytest.param(
        put("goals", 1, "symmetry", value=-1), ["goals[1].symmetry"], id="symmetry-negative"
    ),
    pytest.param(put("goals", value=[]), ["goals", "at least 2"], id="zero-goals"),
    pytest.param(drop("goals", 1), ["goals", "at least 2"], id="one-goal"),
    pytest.param(put("goals", value={"mug": {}}), ["goals"], id="goals-not-a-list"),
    pytest.param(put("goals", 1, "name", value="mug"), ["goals", "mug"], id="duplicate-names"),
    pytest.param(put("goals", 1, "name", value=""), ["goals[1].name"], id="empty-name"),
    pytest.param(
        put("goals", 1, "position", value=list(X0_POSITION)),
        ["goals[1].position", "x0"],
        id="goal-at-x0",
    ),
    pytest.param(
        put("goals", 1, "quaternion", value=[0, 0, 0, 0]),
        ["goals[1].quaternion", "norm"],
        id="zero-quaternion",
    ),
    pytest.param(
        put("x0", "quaternion", value=[0.0, 0.0, 0.0, 0.0]),
        ["x0.quaternion"],
        id="x0-zero-quaternion",
    ),
    pytest.param(
        put("goals", 0, "quaternion", value=[0, 1, 0]),
        ["goals[0].quaternion"],
        id="quaternion-3-nums",
    ),
    pytest.param(
        put("params", "cost", value="foo"), ["params.cost", "foo", "dragan, ratio"], id="cost-form"
    ),
    pytest.param(put("params", "cost", value=1), ["params.cost"], id="cost-number"),
    pytest.param(put("params", "betta", value=5), ["params.betta"], id="params-typo"),
    pytest.param(put("params", value=[5]), ["params"], id="params-not-an-object"),
    pytest.param(put("params", "sigma", value=-0.03), ["params.sigma"], id="sigma-negative"),
    pytest.param(put("params", "sigma", value=0), ["params.sigma"], id="sigma-zero"),
    pytest.param(put("params", "beta", value=-1), ["params.beta"], id="beta-negative"),
    pytest.param(put("params", "v_max", value=0.0), ["params.v_max"], id="v_max-zero"),
    pytest.param(put("params", "dt", value=-0.05), ["params.dt"], id="dt-negative"),
    pytest.param(
        put("params", "rotation_weight", value=-0.04),
        ["params.rotation_weight"],
        id="rotation-weight-negative",
    ),
    pytest.param(put("params", "alpha", value=0), ["params.alpha"], id="alpha-zero"),
    pytest.param(put("params", "alpha", value=1), ["params.alpha"], id="alpha-one"),
    pytest.param(put("params", "alpha", value=1.5), ["params.alpha"], id="alpha-above-one"),
    pytest.param(put("params", "alpha", value=-0.05), ["params.alpha"], id="alpha-negative"),
    pytest.param(
        put("params", "horizon_fraction", value=0.0),
        ["params.horizon_fraction"],
        id="horizon-fraction-zero",
    ),
    pytest.param(
        put("params", "horizon_fraction", value=1.01),
        ["params.horizon_fraction"],
        id="horizon-fraction-above-one",
    ),
    pytest.param(put("params", "p_thresh", value=1), ["params.p_thresh"], id="p_thresh-one"),
]


@pytest.mark.parametrize(("mutation", "needles"), BAD_GOALSETS)
def test_bad_goal_set_field(
    cli: Cli,
    write_json: WriteJson,
    example: dict[str, Any],
    mutation: Mutation,
    needles: list[str],
) -> None:
    mutation(example)
    path = write_json("bad.json", example)
    assert_bad_input(cli("certify", path, "--json"), str(path), *needles)


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        pytest.param(json.dumps(EXAMPLE_GOALSET)[:-40], ["invalid JSON", "line 1"], id="truncated"),
        pytest.param("", ["invalid JSON"], id="empty"),
        pytest.param("[1, 2, 3]", ["(top level)"], id="a-list"),
        pytest.param('"goals"', ["(top level)"], id="a-string"),
        pytest.param("null", ["(top level)"], id="null"),
        pytest.param("{'x0': 1}", ["invalid JSON"], id="single-quotes"),
    ],
)
def test_bad_json_document(cli: Cli, write_json: WriteJson, text: str, needles: list[str]) -> None:
    path = write_json("bad.json", text)
    assert_bad_input(cli("certify", path), str(path), *needles)


@pytest.mark.parametrize(
    ("where", "constant"),
    [
        pytest.param(("goals", 1, "position", 0), float("nan"), id="NaN-position"),
        pytest.param(("goals", 0, "position", 2), float("inf"), id="Infinity-position"),
        pytest.param(("x0", "position", 2), float("-inf"), id="-Infinity-x0"),
        pytest.param(("params", "sigma"), float("nan"), id="NaN-sigma"),
        pytest.param(("goals", 0, "quaternion", 0), float("nan"), id="NaN-quaternion"),
    ],
)
def test_nan_and_infinity_rejected(
    cli: Cli,
    write_json: WriteJson,
    example: dict[str, Any],
    where: tuple[str | int, ...],
    constant: float,
) -> None:
    put(*where, value=constant)(example)
    path = write_json("nan.json", example)  # json.dumps writes NaN / Infinity / -Infinity
    assert any(t in path.read_text() for t in ("NaN", "Infinity"))
    line = assert_bad_input(cli("certify", path, "--json"), str(path))
    assert "NaN" in line or "Infinity" in line or "finite" in line


def test_nan_message_names_the_field(
    cli: Cli, write_json: WriteJson, example: dict[str, Any]
) -> None:
    put("goals", 1, "position", 0, value=float("nan"))(example)
    path = write_json("nan.json", example)
    assert_bad_input(cli("certify", path, "--json"), str(path), "goals[1].position")


def test_missing_file(cli: Cli, tmp_path: Path) -> None:
    path = tmp_path / "nope.json"
    assert_bad_input(cli("certify", path, "--json"), str(path), "no such file")


def test_directory_instead_of_file(cli: Cli, tmp_path: Path) -> None:
    assert_bad_input(cli("certify", tmp_path), str(tmp_path), "directory")


def test_not_utf8(cli: Cli, tmp_path: Path) -> None:
    path = tmp_path / "latin1.json"
    path.write_bytes(b'{"x0": "\xe9\xff"}')
    assert_bad_input(cli("certify", path), str(path), "UTF-8")


def test_extra_fields_are_fine(cli: Cli, write_json: WriteJson, example: dict[str, Any]) -> None:
    """interfaces.md: extra fields are fine (only params rejects unknown keys)."""
    example["comment"] = "made by hand"
    example["goals"][0]["label"] = "white mug"
    result = cli("certify", write_json("extra.json", example), "--json")
    assert result.code == 0, result.err
    assert result.err == ""


# --- command-line usage -------------------------------------------------------------


def test_neither_goals_nor_scene(cli: Cli) -> None:
    assert_bad_input(cli("certify", "--json"), "GOALS_FILE", "--scene")


def test_both_goals_and_scene(cli: Cli, goals_file: Path) -> None:
    assert_bad_input(cli("certify", goals_file, "--scene", "desk"), "GOALS_FILE", "--scene")


def test_layout_without_scene(cli: Cli, goals_file: Path, write_json: WriteJson) -> None:
    layout = write_json("layout.json", {"white_mug": {"x": 0.6, "y": 0.2}})
    assert_bad_input(cli("certify", goals_file, "--layout", layout), "--layout", "--scene")


def test_unknown_scene_lists_known(cli: Cli) -> None:
    line = assert_bad_input(cli("certify", "--scene", "office"), "scene", "'office'")
    for name in ("desk", "breakfast_easy", "cluttered"):
        assert name in line


def test_scene_path_that_does_not_exist(cli: Cli, tmp_path: Path) -> None:
    path = tmp_path / "office.toml"
    assert_bad_input(cli("certify", "--scene", path), str(path), "no such file")


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        pytest.param(["--monte-carlo", "0"], ["--monte-carlo", "0"], id="monte-carlo-0"),
        pytest.param(["--monte-carlo", "-3"], ["--monte-carlo"], id="monte-carlo-negative"),
        pytest.param(["--monte-carlo", "many"], ["--monte-carlo"], id="monte-carlo-word"),
        pytest.param(["--cost", "foo"], ["--cost", "foo", "dragan"], id="cost-foo"),
        pytest.param(["--seed", "x"], ["--seed"], id="seed-word"),
        pytest.param(["--bogus"], ["--bogus"], id="unknown-option"),
    ],
)
def test_bad_options(cli: Cli, goals_file: Path, argv: list[str], needles: list[str]) -> None:
    assert_bad_input(cli("certify", goals_file, *argv), *needles)


def test_unknown_command(cli: Cli) -> None:
    assert_bad_input(cli("certfy"), "certfy")


def test_export_to_missing_directory(cli: Cli, goals_file: Path, tmp_path: Path) -> None:
    target = tmp_path / "no" / "such" / "dir" / "goals.json"
    assert_bad_input(cli("certify", goals_file, "--export-goals", target), str(target))
    assert not target.exists()


# --- layout files for --scene -------------------------------------------------------

BAD_LAYOUTS = [
    pytest.param({"banana": {"x": 0.6, "y": 0.2}}, ["banana", "unknown"], id="unknown-object"),
    pytest.param(
        {"tape_dispenser": {"x": 0.6, "y": 0.2}}, ["tape_dispenser", "fixed"], id="fixed-object"
    ),
    pytest.param({"white_mug": {"x": "0.6", "y": 0.2}}, ["white_mug.x"], id="x-string"),
    pytest.param({"white_mug": {"x": None, "y": 0.2}}, ["white_mug.x"], id="x-null"),
    pytest.param({"white_mug": {"x": False, "y": 0.2}}, ["white_mug.x"], id="x-bool"),
    pytest.param({"white_mug": {"y": 0.2}}, ["white_mug.x", "required"], id="x-missing"),
    pytest.param({"white_mug": {"x": 0.6, "y": 0.2, "z": 0.1}}, ["white_mug.z"], id="extra-key"),
    pytest.param({"white_mug": [0.6, 0.2, 0.0]}, ["white_mug"], id="pose-not-an-object"),
    pytest.param([["white_mug", 0.6, 0.2]], ["(top level)"], id="a-list"),
    pytest.param(
        {"white_mug": {"x": 0.72, "y": -0.05}},
        ["infeasible", "white_mug", "black_stapler"],
        id="two-objects-same-place",
    ),
    pytest.param(
        {"white_mug": {"x": 1.5, "y": 0.2}}, ["infeasible", "white_mug", "outside"], id="off-bounds"
    ),
    pytest.param(
        {"white_mug": {"x": 0.56, "y": 0.0}},
        ["infeasible", "white_mug", "EE home"],
        id="under-the-gripper",
    ),
    pytest.param(
        {"white_mug": {"x": 0.79, "y": -0.32}},
        ["infeasible", "white_mug", "tape_dispenser"],
        id="on-a-fixed-object",
    ),
    pytest.param('{"white_mug": {"x": NaN, "y": 0.2}}', ["NaN"], id="NaN"),
    pytest.param('{"white_mug": {"x": 0.6, "y": 0.2}', ["invalid JSON"], id="truncated"),
]


@pytest.mark.parametrize(("layout", "needles"), BAD_LAYOUTS)
def test_bad_layout(cli: Cli, write_json: WriteJson, layout: Any, needles: list[str]) -> None:
    path = write_json("layout.json", layout)
    result = cli("certify", "--scene", "desk", "--layout", path, "--json")
    assert_bad_input(result, str(path), *needles)


def test_missing_layout_file(cli: Cli, tmp_path: Path) -> None:
    path = tmp_path / "layout.json"
    assert_bad_input(cli("certify", "--scene", "desk", "--layout", path), str(path), "no such")


# --- numerically absurd but finite input --------------------------------------------

ABSURD = [
    pytest.param(put("goals", 1, "position", value=[1e300, 0.0, 0.04]), id="position-1e300"),
    pytest.param(put("params", "beta", value=1e300), id="beta-1e300"),
    pytest.param(put("params", "sigma", value=1e300), id="sigma-1e300"),
    pytest.param(put("params", "v_max", value=1e300), id="v_max-1e300"),
    pytest.param(put("params", "v_max", value=1e-300), id="v_max-1e-300"),
]


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("mutation", ABSURD)
def test_absurd_magnitudes_are_bad_input(
    cli: Cli, write_json: WriteJson, example: dict[str, Any], mutation: Mutation
) -> None:
    mutation(example)
    path = write_json("absurd.json", example)
    assert_bad_input(cli("certify", path, "--json"), str(path))


# --- the real console script --------------------------------------------------------


@pytest.mark.parametrize(
    ("case", "needles"),
    [
        pytest.param("missing", ["no such file"], id="missing-file"),
        pytest.param("nan", ["goals[0].position[1]", "finite"], id="NaN"),
        pytest.param("cost", ["params.cost", "dragan, ratio"], id="unknown-cost"),
    ],
)
def test_console_script_exit_code(
    tmp_path: Path,
    write_json: WriteJson,
    example: dict[str, Any],
    case: str,
    needles: list[str],
) -> None:
    if case == "nan":
        put("goals", 0, "position", 1, value=float("nan"))(example)
    elif case == "cost":
        put("params", "cost", value="dragon")(example)
    path = tmp_path / "goals.json" if case == "missing" else write_json("goals.json", example)
    result = run_script("certify", path, "--json", cwd=tmp_path)
    assert "Traceback" not in result.err
    assert_bad_input(result, str(path), *needles)


def test_unknown_gl_backend_is_one_line_for_simulator_commands(tmp_path: Path) -> None:
    env = {**os.environ, "MUJOCO_GL": "no-such-backend"}
    proc = subprocess.run(
        [str(LEGWS), "eval", "--scene", "desk", "--layouts", "random:1", "--quiet"],
        capture_output=True, text=True, env=env, timeout=120, check=False, cwd=tmp_path,
    )  # fmt: skip
    line = assert_bad_input(Result(proc.returncode, proc.stdout, proc.stderr), "MUJOCO_GL")
    assert "egl" in line
