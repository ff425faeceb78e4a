"""Output of ``legws certify`` and ``legws scenes`` (interfaces.md contracts, method.md §7)."""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.formats.goalset import load_goalset
from tests.cli.helpers import EXAMPLE_GOALSET, Result, run_script
from tests.expected import ALL_SCENES, PAPER_TIERS

Cli = Callable[..., Result]
WriteJson = Callable[[str, Any], Path]

PAIR_KEYS = {"true", "other", "margin", "variance", "slack", "steps"}
MOVED_MUG = {"white_mug": {"x": 0.45, "y": -0.35, "yaw": 0.3}}


def certify_json(cli: Cli, *argv: str | Path) -> dict[str, Any]:
    result = cli("certify", *argv, "--json")
    assert result.code == 0, result.err
    assert result.err == ""
    lines = result.out.splitlines()
    assert len(lines) == 1, "--json prints one JSON object on one line"
    report = json.loads(lines[0])
    assert isinstance(report, dict)
    return report


def check_pairs(report: dict[str, Any], names: list[str]) -> None:
    pairs = report["pairs"]
    m = len(names)
    assert len(pairs) == m * (m - 1)
    assert {(p["true"], p["other"]) for p in pairs} == set(itertools.permutations(names, 2))
    for p in pairs:
        assert set(p) >= PAIR_KEYS
        for key in ("margin", "variance", "slack"):
            assert isinstance(p[key], float), (key, p)
        assert isinstance(p["steps"], int)
        assert p["steps"] >= 1
        assert p["variance"] >= 0.0
        assert p["slack"] <= p["margin"]
    assert isinstance(report["objective"], float)
    assert report["objective"] == min(p["slack"] for p in pairs)


# --- goal-set files -------------------------------------------------------------------


def test_json_contract_example(cli: Cli, goals_file: Path) -> None:
    report = certify_json(cli, goals_file)
    check_pairs(report, ["mug", "stapler"])
    assert "monte_carlo" not in report
    assert report["params"]["cost"] == "dragan"
    # the example's goals are far apart: the certificate holds
    assert report["objective"] > 0


def test_json_contract_four_goals(cli: Cli, write_json: WriteJson, example: dict[str, Any]) -> None:
    example["goals"] += [
        {"name": "pen_cup", "position": [0.60, -0.30, 0.05], "quaternion": [0, 1, 0, 0]},
        {"name": "tape", "position": [0.42, 0.30, 0.06], "quaternion": [0, 1, 0, 0], "symmetry": 0},
    ]
    report = certify_json(cli, write_json("four.json", example))
    check_pairs(report, ["mug", "stapler", "pen_cup", "tape"])


def test_default_params_without_params_block(
    cli: Cli, write_json: WriteJson, example: dict[str, Any], goals_file: Path
) -> None:
    """The example's params are the defaults: leaving them out changes nothing."""
    del example["params"]
    without = certify_json(cli, write_json("bare.json", example))
    with_params = certify_json(cli, goals_file)
    assert without["objective"] == with_params["objective"]
    assert without["pairs"] == with_params["pairs"]


def test_monte_carlo(cli: Cli, goals_file: Path) -> None:
    report = certify_json(cli, goals_file, "--monte-carlo", "500", "--seed", "3")
    check_pairs(report, ["mug", "stapler"])
    mc = report["monte_carlo"]
    assert set(mc) == {"mug", "stapler"}
    for entry in mc.values():
        assert entry["trials"] == 500
        assert 0.0 <= entry["lower95"] <= entry["accuracy"] <= 1.0
        assert entry["accuracy"] * 500 == pytest.approx(round(entry["accuracy"] * 500))
    # the certificate does not depend on the Monte Carlo check
    plain = certify_json(cli, goals_file)
    assert report["objective"] == plain["objective"]
    assert report["pairs"] == plain["pairs"]


def test_monte_carlo_seeded(cli: Cli, write_json: WriteJson, example: dict[str, Any]) -> None:
    # two goals 2 cm apart: accuracy well below 1, so the seed shows in the counts
    example["goals"][1]["position"] = [0.64, 0.21, 0.07]
    example["goals"][1]["quaternion"] = [0, 1, 0, 0]
    path = write_json("close.json", example)
    args = (path, "--monte-carlo", "500")
    first = cli("certify", *args, "--seed", "3", "--json")
    again = cli("certify", *args, "--seed", "3", "--json")
    other = cli("certify", *args, "--seed", "4", "--json")
    assert first.code == again.code == other.code == 0
    assert first.out == again.out
    a, b = json.loads(first.out), json.loads(other.out)
    assert a["objective"] == b["objective"] < 0
    accuracies = [a["monte_carlo"][g]["accuracy"] for g in ("mug", "stapler")]
    assert all(0.0 < acc < 1.0 for acc in accuracies)
    assert a["monte_carlo"] != b["monte_carlo"]


def test_cost_ratio(cli: Cli, goals_file: Path) -> None:
    dragan = certify_json(cli, goals_file)
    ratio = certify_json(cli, goals_file, "--cost", "ratio")
    assert dragan["params"]["cost"] == "dragan"
    assert ratio["params"]["cost"] == "ratio"
    assert ratio["objective"] != dragan["objective"]
    check_pairs(ratio, ["mug", "stapler"])
    # the horizon is the user model's, the same under both observers
    assert [p["steps"] for p in ratio["pairs"]] == [p["steps"] for p in dragan["pairs"]]


def test_cost_flag_overrides_file(
    cli: Cli, write_json: WriteJson, example: dict[str, Any], goals_file: Path
) -> None:
    example["params"]["cost"] = "ratio"
    path = write_json("ratio.json", example)
    from_file = certify_json(cli, path)
    from_flag = certify_json(cli, goals_file, "--cost", "ratio")
    overridden = certify_json(cli, path, "--cost", "dragan")
    assert from_file["params"]["cost"] == "ratio"
    assert from_file["objective"] == from_flag["objective"]
    assert overridden["params"]["cost"] == "dragan"
    assert overridden["objective"] == certify_json(cli, goals_file)["objective"]


def test_text_output(cli: Cli, goals_file: Path) -> None:
    report = certify_json(cli, goals_file)
    result = cli("certify", goals_file)
    assert result.code == 0, result.err
    assert result.err == ""
    assert "mug" in result.out
    assert "stapler" in result.out
    assert f"{report['objective']:.4f}" in result.out
    assert "CERTIFIED" in result.out
    with pytest.raises(json.JSONDecodeError):
        json.loads(result.out)


def test_text_output_monte_carlo(cli: Cli, goals_file: Path) -> None:
    result = cli("certify", goals_file, "--monte-carlo", "200", "--seed", "1")
    assert result.code == 0, result.err
    assert "Monte Carlo" in result.out
    assert "200" in result.out


def test_text_output_not_certified(
    cli: Cli, write_json: WriteJson, example: dict[str, Any]
) -> None:
    example["goals"][1]["position"] = [0.63, 0.21, 0.07]
    example["goals"][1]["quaternion"] = [0, 1, 0, 0]
    result = cli("certify", write_json("close.json", example))
    assert result.code == 0, result.err
    assert "NOT certified" in result.out


def test_console_script_matches_in_process(cli: Cli, goals_file: Path, tmp_path: Path) -> None:
    result = run_script("certify", goals_file, "--json", cwd=tmp_path)
    assert result.code == 0, result.err
    assert json.loads(result.out) == certify_json(cli, goals_file)


# --- scenes -------------------------------------------------------------------------


def test_scene_json(cli: Cli) -> None:
    report = certify_json(cli, "--scene", "desk")
    check_pairs(report, ["white_mug", "black_stapler", "maroon_pen_cup"])
    assert "desk" in report["source"]


def test_scene_export_round_trip(cli: Cli, tmp_path: Path) -> None:
    exported = tmp_path / "desk_goals.json"
    scene = certify_json(cli, "--scene", "desk", "--export-goals", exported)
    assert exported.is_file()
    goals, params = load_goalset(exported)
    assert list(goals.names) == ["white_mug", "black_stapler", "maroon_pen_cup"]
    assert params.as_dict() == scene["params"]
    again = certify_json(cli, exported)
    assert again["objective"] == scene["objective"]  # to the last digit
    assert again["pairs"] == scene["pairs"]


def test_export_round_trip_goal_file(cli: Cli, goals_file: Path, tmp_path: Path) -> None:
    exported = tmp_path / "copy.json"
    first = certify_json(cli, goals_file, "--cost", "ratio", "--export-goals", exported)
    second = certify_json(cli, exported)
    assert second["params"]["cost"] == "ratio"
    assert second["objective"] == first["objective"]


def _without_mug(report: dict[str, Any]) -> list[dict[str, Any]]:
    return [p for p in report["pairs"] if "white_mug" not in (p["true"], p["other"])]


def test_scene_layout_moves_an_object(cli: Cli, write_json: WriteJson) -> None:
    default = certify_json(cli, "--scene", "desk")
    layout = write_json("layout.json", MOVED_MUG)
    moved = certify_json(cli, "--scene", "desk", "--layout", layout)
    assert moved["objective"] != default["objective"]
    assert str(layout) in moved["source"]
    check_pairs(moved, ["white_mug", "black_stapler", "maroon_pen_cup"])
    # dragan: the pairs without the mug change only through the common scale
    # D = mean_g d(x0, g) (method.md §3): margins by one factor, variances by its square
    before, after = _without_mug(default), _without_mug(moved)
    assert [(p["true"], p["other"], p["steps"]) for p in before] == [
        (p["true"], p["other"], p["steps"]) for p in after
    ]
    factors = [a["margin"] / b["margin"] for a, b in zip(after, before, strict=True)]
    assert factors[0] != pytest.approx(1.0)
    assert factors[1] == pytest.approx(factors[0], rel=1e-9)
    for a, b in zip(after, before, strict=True):
        assert a["variance"] / b["variance"] == pytest.approx(factors[0] ** 2, rel=1e-9)


def test_scene_layout_ratio_cost_is_local(cli: Cli, write_json: WriteJson) -> None:
    """Under the per-goal ratio cost, moving the mug leaves the other pairs untouched."""
    layout = write_json("layout.json", MOVED_MUG)
    default = certify_json(cli, "--scene", "desk", "--cost", "ratio")
    moved = certify_json(cli, "--scene", "desk", "--layout", layout, "--cost", "ratio")
    assert moved["objective"] != default["objective"]
    before, after = _without_mug(default), _without_mug(moved)
    assert len(before) == 2
    for a, b in zip(after, before, strict=True):
        for key in ("margin", "variance", "slack"):
            assert a[key] == pytest.approx(b[key], rel=1e-12, abs=1e-15)


def test_scene_layout_equal_to_default(cli: Cli, write_json: WriteJson) -> None:
    same = {
        "white_mug": {"x": 0.68, "y": 0.22, "yaw": 0.0},
        "black_stapler": {"x": 0.72, "y": -0.05},
    }
    default = certify_json(cli, "--scene", "desk")
    given = certify_json(cli, "--scene", "desk", "--layout", write_json("same.json", same))
    assert given["objective"] == default["objective"]


def test_scenes_text(cli: Cli) -> None:
    result = cli("scenes")
    assert result.code == 0, result.err
    for name in ALL_SCENES:
        assert name in result.out


def test_scenes_json(cli: Cli) -> None:
    result = cli("scenes", "--json")
    assert result.code == 0, result.err
    rows = {row["name"]: row for row in json.loads(result.out)}
    assert sorted(rows) == ALL_SCENES
    for name, (tier, m, total) in PAPER_TIERS.items():
        row = rows[name]
        assert (row["tier"], row["m"], row["total"]) == (tier, m, total), name
    for row in rows.values():
        assert row["m"] == len(row["goals"]) >= 2
        assert row["total"] == len(row["movable"]) + len(row["fixed"])
        assert set(row["goals"]) <= set(row["movable"])


@pytest.mark.parametrize("argv", [["--help"], ["-h"], ["certify", "--help"], ["scenes", "--help"]])
def test_help(cli: Cli, argv: list[str]) -> None:
    result = cli(*argv)
    assert result.code == 0
    assert "Usage" in result.out
    assert result.err == ""


def test_version(cli: Cli) -> None:
    result = cli("--version")
    assert result.code == 0
    assert "legws" in result.out


def test_example_is_the_interfaces_example() -> None:
    """Guard: the fixture is the documented example (two goals, mug with symmetry 2)."""
    assert [g["name"] for g in EXAMPLE_GOALSET["goals"]] == ["mug", "stapler"]
    assert EXAMPLE_GOALSET["goals"][0]["symmetry"] == 2
