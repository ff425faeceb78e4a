"""``legws study check|plan`` from the outside: the schedule files, refusals in one line."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

from tests.cli.helpers import Result

Cli = Callable[..., Result]


def test_plan_writes_schedule_json_csv_and_the_plan(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "study"
    r = cli("study", "plan", "layouts_tea", "--participants", "12", "--out", out)
    assert r.code == 0, r.err
    assert "12 participants, williams design of 3 conditions (6 orders), balanced" in r.err
    schedule = json.loads((out / "schedule.json").read_text())
    assert set(schedule) == {"conditions", "participants"}
    assert schedule["conditions"] == ["random", "optimised", "personal"]
    assert list(schedule["participants"]) == [f"P{k:02d}" for k in range(1, 13)]
    for order in schedule["participants"].values():
        assert sorted(order) == sorted(schedule["conditions"])
    plan = json.loads((out / "plan.json").read_text())
    assert plan["balanced"] and plan["problems"] == []
    assert all(counts == [4, 4, 4] for counts in plan["positions"].values())
    assert set(plan["neighbours"].values()) == {4}
    rows = list(csv.DictReader((out / "schedule.csv").open()))
    assert {r["participant"] for r in rows} == set(schedule["participants"])
    # planning again the same is a no-op; the files stay as they were
    before = (out / "plan.json").read_bytes()
    assert cli("study", "plan", "layouts_tea", "--participants", "12", "--out", out).code == 0
    assert (out / "plan.json").read_bytes() == before


def test_an_unbalanced_number_of_participants_is_refused_unless_asked(
    cli: Cli, tmp_path: Path
) -> None:
    out = tmp_path / "study"
    r = cli("study", "plan", "assist_policies", "--participants", "6", "--out", out)
    assert r.code == 2 and len(r.err.splitlines()) == 1
    assert "6 participants do not balance a williams design of 4 conditions" in r.err
    assert "use a multiple of 4 (4, 8) or --incomplete" in r.err
    assert not out.exists()
    r = cli("study", "plan", "assist_policies", "--participants", "6", "--out", out, "--incomplete")
    assert r.code == 0 and "NOT balanced" in r.err
    plan = json.loads((out / "plan.json").read_text())
    assert not plan["balanced"] and plan["problems"]


def test_a_different_plan_is_not_written_over_without_force(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "study"
    assert cli("study", "plan", "assist_policies", "--participants", "4", "--out", out).code == 0
    r = cli("study", "plan", "assist_policies", "--participants", "8", "--out", out)
    assert r.code == 2 and "holds a different plan" in r.err
    assert len(json.loads((out / "schedule.json").read_text())["participants"]) == 4
    r = cli("study", "plan", "assist_policies", "--participants", "8", "--out", out, "--force")
    assert r.code == 0
    assert len(json.loads((out / "schedule.json").read_text())["participants"]) == 8


def test_check_lists_conditions_and_the_balancing_multiple(cli: Cli) -> None:
    r = cli("study", "check", "assist_policies")
    assert r.code == 0, r.err
    assert "blend: scene cluttered, layout optimised, assist blend" in r.out
    assert "williams design: 4 orders; participants in multiples of 4" in r.out


def test_a_bad_protocol_is_one_line_per_error(cli: Cli, tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('schema_version = 1\nname = "bad"\ntitle = "x"\n', encoding="utf-8")
    r = cli("study", "plan", bad, "--participants", "4", "--out", tmp_path / "o")
    assert r.code == 2 and "Traceback" not in r.err
    lines = r.err.splitlines()
    assert any("design: Field required" in line for line in lines), lines
    assert all(line.startswith("legws: error: ") for line in lines)
