"""A study folder's plan read back: the plan `legws study plan` wrote runs; no plan, another
protocol's or an edited one does not."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.cli.study import write_plan
from legws_daemon.errors import InputError
from legws_daemon.study.protocol import Protocol, load_protocol
from legws_daemon.study.schedule import make_schedule
from legws_daemon.study.store import existing_plan, planned_schedule, write_study_table
from tests.study.person import PERSON


@pytest.fixture(scope="module")
def person() -> Protocol:
    return load_protocol(PERSON)


def plan_of(folder: Path) -> dict[str, Any]:
    data = json.loads((folder / "plan.json").read_text())
    assert isinstance(data, dict)
    return data


def rewrite(folder: Path, plan: dict[str, Any]) -> None:
    (folder / "plan.json").write_text(json.dumps(plan, indent=1) + "\n")


def refused(p: Protocol, folder: Path) -> InputError:
    with pytest.raises(InputError) as info:
        planned_schedule(p, folder)
    assert info.value.source == str(folder / "plan.json")
    assert "\n" not in str(info.value)
    return info.value


def test_no_plan_is_refused_naming_plan_json_and_the_command(
    person: Protocol, tmp_path: Path
) -> None:
    folder = tmp_path / "study"
    assert existing_plan(folder) is None
    err = refused(person, folder)
    assert str(err).startswith(f"{folder / 'plan.json'}: no plan")
    assert f"legws study plan person --participants N --out {folder}" in str(err)
    folder.mkdir()
    (folder / "schedule.json").write_text("{}")  # a folder with other files, no plan
    assert "no plan" in str(refused(person, folder))


def test_the_written_plan_is_the_schedule_make_schedule_makes(
    person: Protocol, tmp_path: Path
) -> None:
    folder = tmp_path / "study"
    written = write_plan(person, 2, folder, False, False)
    assert existing_plan(folder) == written.plan_json()
    schedule = planned_schedule(person, folder)
    fresh = make_schedule(person, 2)
    assert schedule.steps == fresh.steps == written.steps
    assert list(schedule.steps) == ["P01", "P02"]
    assert schedule.orders == fresh.orders and schedule.problems == ()
    assert schedule.protocol_sha256 == person.sha256
    kinds = [s.kind for s in schedule.steps["P01"]]
    assert kinds[0] == "calibration" and kinds.count("trial") == 2


def test_an_incomplete_plan_runs_as_planned(person: Protocol, tmp_path: Path) -> None:
    folder = tmp_path / "study"
    write_plan(person, 3, folder, True, False)
    schedule = planned_schedule(person, folder)
    assert list(schedule.steps) == ["P01", "P02", "P03"] and schedule.problems


@pytest.mark.parametrize(
    ("where", "value"),
    [("assist", "none"), ("targets", ["stapler"]), ("layout_seed", 12345), ("kind", "break")],
)
def test_an_edited_step_is_refused(
    person: Protocol, tmp_path: Path, where: str, value: Any
) -> None:
    folder = tmp_path / "study"
    write_plan(person, 2, folder, False, False)
    plan = plan_of(folder)
    step = next(s for s in plan["participants"]["P02"] if s["kind"] == "trial")
    assert step[where] != value
    step[where] = value
    rewrite(folder, plan)
    assert "edited by hand" in str(refused(person, folder))


def test_a_plan_with_a_participant_more_or_less_is_refused(
    person: Protocol, tmp_path: Path
) -> None:
    folder = tmp_path / "study"
    write_plan(person, 2, folder, False, False)
    plan = plan_of(folder)
    plan["participants"]["P03"] = plan["participants"]["P01"]
    rewrite(folder, plan)
    assert "does not match" in str(refused(person, folder))
    plan["participants"] = {"P01": plan["participants"]["P01"]}
    rewrite(folder, plan)
    assert "does not match" in str(refused(person, folder))


@pytest.mark.parametrize("people", [None, {}, [], "P01"])
def test_a_plan_without_participants_is_refused_naming_them(
    person: Protocol, tmp_path: Path, people: Any
) -> None:
    folder = tmp_path / "study"
    write_plan(person, 2, folder, False, False)
    plan = plan_of(folder)
    if people is None:
        del plan["participants"]
    else:
        plan["participants"] = people
    rewrite(folder, plan)
    assert refused(person, folder).field == "participants"


def test_another_protocols_plan_is_refused_naming_protocol_sha256(
    person: Protocol, tmp_path: Path
) -> None:
    folder = tmp_path / "study"
    write_plan(person, 2, folder, False, False)
    # the same protocol with one word changed: the same name, another text
    changed = tmp_path / "v2" / "person.toml"
    changed.parent.mkdir()
    changed.write_text(PERSON.read_text().replace("one pick each", "one pick apiece"))
    other = load_protocol(changed)
    assert other.name == person.name and other.sha256 != person.sha256
    err = refused(other, folder)
    assert err.field == "protocol_sha256" and "another protocol" in str(err)
    # and a plan whose hash was changed by hand
    plan = plan_of(folder)
    plan["protocol_sha256"] = "0" * 64
    rewrite(folder, plan)
    assert refused(person, folder).field == "protocol_sha256"
    del plan["protocol_sha256"]
    rewrite(folder, plan)
    assert refused(person, folder).field == "protocol_sha256"


@pytest.mark.parametrize(
    ("text", "words"),
    [("[1, 2]\n", "expected a JSON object"), ('{"schema": 1,\n', "invalid JSON at line")],
)
def test_a_plan_file_that_is_no_plan_is_refused(
    person: Protocol, tmp_path: Path, text: str, words: str
) -> None:
    folder = tmp_path / "study"
    folder.mkdir()
    (folder / "plan.json").write_text(text)
    err = refused(person, folder)
    assert words in str(err)
    with pytest.raises(InputError):
        existing_plan(folder)


def test_the_study_table_is_every_participants_table_and_nothing_else(tmp_path: Path) -> None:
    from legws_daemon.study.table import read_table, write_table

    likert = ["The robot understood which object I wanted."]
    for who, trials in (("P01", [2, 5]), ("P02", [2])):
        rows = [{"participant": who, "index": i, "kind": "trial", "condition": "c"} for i in trials]
        (tmp_path / who).mkdir()
        write_table(tmp_path / who, "trials", rows, 1)
    # a folder that is not a participant's (an optimisation run's) is not read
    (tmp_path / "layouts").mkdir()
    write_table(tmp_path / "layouts", "trials", [{"participant": "x", "index": 9}], 1)
    assert write_study_table(tmp_path, likert) == 3
    rows = read_table(tmp_path / "trials.parquet")
    assert [(r["participant"], r["index"]) for r in rows] == [("P01", 2), ("P01", 5), ("P02", 2)]
    assert "likert_1" in (tmp_path / "data_dictionary.md").read_text()
    assert (tmp_path / "trials.csv").read_text().count("\n") == 4  # header and 3 rows
