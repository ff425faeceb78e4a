"""Regressions of a red-team run against ``legws certify`` and the endpoint options: each
input that used to cost gigabytes, a traceback or non-JSON output now exits 2 with one
``legws: error:`` line (or works in bounded memory)."""

from __future__ import annotations

import json
import math
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.core.goals import MAX_GOALS
from legws_daemon.core.montecarlo import MAX_TRIALS
from legws_daemon.scene.catalog import scenes_dir
from tests.cli.helpers import Result, assert_bad_input
from tests.formats.test_caps_files import goals_doc

Cli = Callable[..., Result]
WriteJson = Callable[[str, Any], Path]
REPO = Path(__file__).parents[2]


def many_goals(example: dict[str, Any], m: int) -> dict[str, Any]:
    example["goals"] = goals_doc(m)["goals"]
    return example


def strict_json(text: str) -> Any:
    """Parse JSON refusing NaN and Infinity (what ``json.loads`` lets through)."""

    def refuse(name: str) -> None:
        raise ValueError(f"non-JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


# --- the number of goals ------------------------------------------------------------------


def test_20000_goals_are_refused_at_once(
    cli: Cli, write_json: WriteJson, example: dict[str, Any]
) -> None:
    """Was: ``Unable to allocate 8.94 GiB``. The file is refused at load (by its size or
    its number of goals), before any array is built."""
    path = write_json("goals.json", many_goals(example, 20_000))
    start = time.perf_counter()
    result = cli("certify", path, "--json")
    assert time.perf_counter() - start < 5
    assert_bad_input(result, str(path))


@pytest.mark.parametrize("m", [2_000, MAX_GOALS + 1])
def test_goal_sets_above_the_cap_are_refused(
    cli: Cli, tmp_path: Path, example: dict[str, Any], m: int
) -> None:
    """Was (2,000 goals): 74 s, then MemoryError."""
    path = tmp_path / "goals.json"
    path.write_text(json.dumps(many_goals(example, m), separators=(",", ":")))
    start = time.perf_counter()
    result = cli("certify", path, "--commit")
    assert time.perf_counter() - start < 5
    assert_bad_input(result, str(path), "goals", f"at most {MAX_GOALS} goals, got {m}")


def test_a_goal_set_at_the_cap_is_certified(
    cli: Cli, write_json: WriteJson, example: dict[str, Any]
) -> None:
    path = write_json("goals.json", many_goals(example, MAX_GOALS))
    result = cli("certify", path, "--json", "--commit")
    assert result.code == 0, result.err
    report = strict_json(result.out)
    assert len(report["pairs"]) == MAX_GOALS * (MAX_GOALS - 1)


# --- Monte Carlo ----------------------------------------------------------------------------


def test_ten_million_trials_are_refused_by_the_option(cli: Cli, goals_file: Path) -> None:
    """Was: a traceback, although 10,000,000 was inside the option's declared range."""
    line = assert_bad_input(
        cli("certify", goals_file, "--monte-carlo", "10000000"), "--monte-carlo", "10000000"
    )
    assert f"{MAX_TRIALS}" in line


def test_too_much_simulation_is_refused_naming_the_largest_run(cli: Cli, goals_file: Path) -> None:
    line = assert_bad_input(
        cli("certify", goals_file, "--commit", "--monte-carlo", str(MAX_TRIALS)),
        "--monte-carlo",
        "goal-steps",
        "trials for this goal set",
    )
    largest = int(line.rsplit("accepted, ", 1)[1].split(" trials")[0].replace(",", ""))
    assert 1_000 < largest < MAX_TRIALS


def test_too_much_simulation_of_a_scene_is_refused(cli: Cli) -> None:
    assert_bad_input(
        cli("certify", "--scene", "cluttered", "--commit", "--monte-carlo", "500000"),
        "--monte-carlo",
        "8 goals",
    )


# --- alpha, beta, sigma -----------------------------------------------------------------------


@pytest.mark.parametrize("as_json", [True, False])
def test_alpha_1e_17_is_refused(cli: Cli, goals_file: Path, as_json: bool) -> None:
    """Was: ``--json`` exit 1 "Out of range float values are not JSON compliant", text
    ``J = -inf`` with a RuntimeWarning."""
    argv = ["certify", goals_file, "--alpha", "1e-17", *(["--json"] if as_json else [])]
    assert_bad_input(cli(*argv), "--alpha", "1e-09", "below 1e-9")


def test_alpha_1e_17_in_a_goal_set_file_is_refused(
    cli: Cli, write_json: WriteJson, example: dict[str, Any]
) -> None:
    example["params"]["alpha"] = 1e-17
    path = write_json("goals.json", example)
    assert_bad_input(cli("certify", path, "--json"), str(path), "params.alpha", "1e-09")


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--alpha", "0"),
        ("--alpha", "0.6"),
        ("--alpha", "nan"),
        ("--beta", "0"),
        ("--beta", "1e4"),
        ("--beta", "inf"),
        ("--sigma", "0"),
        ("--sigma", "-0.03"),
        ("--sigma", "11"),
        ("--sigma", "many"),
    ],
)
def test_parameters_outside_their_ranges_are_refused(
    cli: Cli, goals_file: Path, option: str, value: str
) -> None:
    assert_bad_input(cli("certify", goals_file, "--json", option, value), option)


@pytest.mark.parametrize(
    "argv",
    [
        ["--alpha", "1e-9"],
        ["--alpha", "0.5"],
        ["--beta", "1000", "--sigma", "1e-9"],
        ["--beta", "1e-6", "--sigma", "10"],
        ["--alpha", "1e-9", "--beta", "1000", "--commit", "--commit-form", "sum"],
        ["--alpha", "1e-9", "--commit", "--clip-speed", "--monte-carlo", "50"],
    ],
)
def test_the_ends_of_the_ranges_print_finite_json_without_warnings(
    cli: Cli, goals_file: Path, argv: list[str]
) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = cli("certify", goals_file, "--json", *argv)
        text = cli("certify", goals_file, *argv)
    assert result.code == 0 and result.err == "", result.err
    report = strict_json(result.out)
    assert math.isfinite(report["objective"])
    assert text.code == 0 and text.err == "" and "inf" not in text.out and "nan" not in text.out


# --- scene files ----------------------------------------------------------------------------


def test_a_100_m_object_is_refused(cli: Cli, tmp_path: Path) -> None:
    """Was: accepted (any size up to 100 m)."""
    text = (scenes_dir() / "desk.toml").read_text(encoding="utf-8")
    bad = text.replace("size = [0.16, 0.04, 0.05]", "size = [100.0, 0.04, 0.05]")
    assert bad != text
    path = tmp_path / "desk.toml"
    path.write_text(bad, encoding="utf-8")
    assert_bad_input(cli("certify", "--scene", path), str(path), "objects[1].size[0]", "0.5 m")


def test_an_object_100_m_away_is_refused(cli: Cli, tmp_path: Path) -> None:
    text = (scenes_dir() / "desk.toml").read_text(encoding="utf-8")
    path = tmp_path / "desk.toml"
    path.write_text(text.replace("x = 0.8\ny = 0.34", "x = 100.0\ny = 0.34"), encoding="utf-8")
    assert_bad_input(cli("certify", "--scene", path), str(path), "objects[4].x")


# --- endpoints --------------------------------------------------------------------------------


@pytest.mark.parametrize("flag", ["--listen", "--connect"])
def test_port_99999_on_the_command_line_is_refused(cli: Cli, flag: str) -> None:
    assert_bad_input(
        cli("bridge", "fake", "--profile", "sim", flag, "tcp/127.0.0.1:99999"),
        flag,
        "port 99999 is not in 1..65535",
    )


def test_port_99999_in_a_profile_is_refused(cli: Cli, tmp_path: Path) -> None:
    text = (REPO / "hw_profiles" / "sim.toml").read_text(encoding="utf-8")
    path = tmp_path / "p.toml"
    path.write_text(text.replace("tcp/127.0.0.1:7447", "tcp/127.0.0.1:99999"), encoding="utf-8")
    assert_bad_input(
        cli("bridge", "fake", "--profile", path),
        str(path),
        "transport.listen[0]",
        "port 99999 is not in 1..65535",
    )


def test_port_99999_for_secure_init_is_refused(cli: Cli, tmp_path: Path) -> None:
    target = tmp_path / "deploy"
    assert_bad_input(cli("secure", "init", target, "--port", "99999"), "--port", "99999")
    assert_bad_input(cli("secure", "init", target, "--listen", " 127.0.0.1"), "--listen")
    assert not target.exists()
