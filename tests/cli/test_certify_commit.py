"""``legws certify --commit`` (interfaces.md: the commit certificate of method.md §9)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from legws_daemon.core.commit import certify_commit
from legws_daemon.formats.goalset import load_goalset
from tests.cli.helpers import Result

Cli = Callable[..., Result]
WriteJson = Callable[[str, Any], Path]

GOAL_KEYS = {"fraction", "step", "arrival_steps", "slack_at_arrival", "wrong_commit_slack",
             "certified"}  # fmt: skip
MC_KEYS = {"rate_by_step", "lower95", "wrong", "before_arrival", "trials"}


def commit_json(cli: Cli, *argv: str | Path) -> dict[str, Any]:
    result = cli("certify", *argv, "--json", "--commit")
    assert result.code == 0, result.err
    assert result.err == ""
    assert len(result.out.splitlines()) == 1
    report = json.loads(result.out)
    assert isinstance(report, dict)
    return report


def test_contract_and_the_core_agree(cli: Cli, goals_file: Path) -> None:
    report = commit_json(cli, goals_file)
    plain = json.loads(cli("certify", goals_file, "--json").out)
    # the slack certificate is unchanged by --commit
    assert report["objective"] == plain["objective"] and report["pairs"] == plain["pairs"]
    c = report["commit"]
    assert set(c["goals"]) == {"mug", "stapler"}
    goals, params = load_goalset(goals_file)
    core = certify_commit(goals, params)
    assert c["objective"] == core.objective  # to the last digit
    assert c["certified"] == core.certified == sum(g["certified"] for g in c["goals"].values())
    for name, g in c["goals"].items():
        assert set(g) >= GOAL_KEYS
        assert g["fraction"] == core.goals[name].fraction
        assert isinstance(g["arrival_steps"], int) and g["arrival_steps"] >= 1
        if g["certified"]:
            assert isinstance(g["step"], int) and 1 <= g["step"] <= g["arrival_steps"]
            assert 0 < g["fraction"] <= 1
        else:
            assert g["step"] is None and g["fraction"] > 1
    assert c["objective"] == max(g["fraction"] for g in c["goals"].values())
    assert "monte_carlo_commit" not in report


def test_monte_carlo_commit(cli: Cli, goals_file: Path) -> None:
    report = commit_json(cli, goals_file, "--monte-carlo", "400", "--seed", "2")
    mc = report["monte_carlo_commit"]
    assert set(mc) == {"mug", "stapler"}
    for name, r in mc.items():
        assert set(r) >= MC_KEYS
        assert r["trials"] == 400
        assert 0.0 <= r["lower95"] <= r["rate_by_step"] <= r["before_arrival"] <= 1.0
        assert 0.0 <= r["wrong"] <= 1.0 - r["before_arrival"] + 1e-12
        g = report["commit"]["goals"][name]
        assert r["by_step"] == (g["step"] if g["certified"] else g["arrival_steps"])
    again = commit_json(cli, goals_file, "--monte-carlo", "400", "--seed", "2")
    assert again == report  # seeded


def test_two_close_goals_are_not_commit_certified(
    cli: Cli, write_json: WriteJson, example: dict[str, Any]
) -> None:
    example["goals"][1]["position"] = [0.64, 0.21, 0.07]
    example["goals"][1]["quaternion"] = [0, 1, 0, 0]
    report = commit_json(cli, write_json("close.json", example), "--monte-carlo", "300")
    assert report["commit"]["certified"] == 0 and report["commit"]["objective"] > 1
    # neither goal commits reliably before arrival
    assert min(r["before_arrival"] for r in report["monte_carlo_commit"].values()) < 0.95


def test_scene_form_and_text(cli: Cli) -> None:
    report = commit_json(cli, "--scene", "breakfast_easy")
    assert report["commit"]["certified"] == 2 and report["commit"]["objective"] <= 1
    text = cli("certify", "--scene", "breakfast_easy", "--commit", "--monte-carlo", "200")
    assert text.code == 0, text.err
    assert "commit objective K = " + f"{report['commit']['objective']:.4f}" in text.out
    assert "commit-certified" in text.out and "before arrival" in text.out


def test_clip_speed_certifies_the_robots_slower_user(cli: Cli) -> None:
    plain = commit_json(cli, "--scene", "breakfast_easy")
    clipped = commit_json(cli, "--scene", "breakfast_easy", "--clip-speed", "--monte-carlo", "300")
    assert plain["commit"]["user"]["clipped"] is False
    assert clipped["commit"]["user"]["clipped"] is True
    assert clipped["commit"]["user"]["speed"] < 1.0
    for name, g in clipped["commit"]["goals"].items():
        assert g["arrival_steps"] > plain["commit"]["goals"][name]["arrival_steps"]
        r = clipped["monte_carlo_commit"][name]
        assert r["by_step"] == (g["step"] if g["certified"] else g["arrival_steps"])


def test_commit_form_sum(cli: Cli, goals_file: Path) -> None:
    even = commit_json(cli, goals_file)
    exact = commit_json(cli, goals_file, "--commit-form", "sum")
    assert even["commit"]["form"] == "min" and exact["commit"]["form"] == "sum"
    goals, params = load_goalset(goals_file)
    assert exact["commit"]["objective"] == certify_commit(goals, params, form="sum").objective
    assert exact["commit"]["objective"] <= even["commit"]["objective"]
    bad = cli("certify", goals_file, "--commit", "--commit-form", "max")
    assert bad.code == 2
