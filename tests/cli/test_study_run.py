"""``legws study run`` with a person: what is refused before anything starts — a name or an
e-mail address for a pseudonym, the wrong flags, no plan, a participant the plan has not."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.study import rig, session, web
from legws_daemon.telemetry import web_viewer
from tests.cli.helpers import Result, assert_bad_input, run_script
from tests.study.person import PERSON

Cli = Callable[..., Result]


@pytest.fixture(autouse=True)
def nothing_starts(monkeypatch: pytest.MonkeyPatch) -> None:
    """A daemon, a viewer, the page or the session's loop started is a failure here."""

    def started(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("started something before refusing")

    monkeypatch.setattr(rig.Child, "__init__", started)
    monkeypatch.setattr(web_viewer.WebViewer, "start", started)
    monkeypatch.setattr(web.StudyPage, "__init__", started)
    monkeypatch.setattr(session.Session, "run", started)


@pytest.fixture
def planned(cli: Cli, tmp_path: Path) -> Path:
    """A study folder with the plan of two participants of person.toml."""
    out = tmp_path / "study"
    r = cli("study", "plan", PERSON, "--participants", "2", "--out", out)
    assert r.code == 0, r.err
    assert (out / "plan.json").is_file()
    return out


@pytest.mark.parametrize(
    ("who", "looks", "secret"),
    [
        ("Jane Doe", "looks like a name", ("Jane", "Doe")),
        ("jane@example.org", "looks like an e-mail address", ("jane", "example")),
        ("Jane", "looks like a name", ("Jane",)),
        ("mailto:P07", "looks like an e-mail address", ("mailto",)),
    ],
)
def test_a_name_or_an_address_is_refused_without_repeating_it(
    cli: Cli, planned: Path, who: str, looks: str, secret: tuple[str, ...]
) -> None:
    before = sorted(p.name for p in planned.iterdir())
    r = cli("study", "run", PERSON, "--participant", who, "--out", planned)
    line = assert_bad_input(r, "--participant", looks, "pseudonym", "e.g. P07")
    for word in secret:
        assert word.lower() not in line.lower(), line
    assert sorted(p.name for p in planned.iterdir()) == before  # no folder of theirs


def test_a_name_is_refused_by_the_installed_script_too(tmp_path: Path) -> None:
    r = run_script("study", "run", PERSON, "--participant", "Jane Doe", "--out",
                   tmp_path / "study", cwd=tmp_path)  # fmt: skip
    line = assert_bad_input(r, "--participant", "looks like a name")
    assert "Jane" not in line and "Doe" not in line
    assert not (tmp_path / "study").exists()


def test_a_pseudonym_not_of_the_usual_form_is_refused(cli: Cli, planned: Path) -> None:
    for who in ("p07", "P-07", "P07 ", "12345", ""):
        r = cli("study", "run", PERSON, "--participant", who, "--out", planned)
        assert_bad_input(r, "--participant", "pseudonyms only")


def test_neither_participant_nor_simulate_is_refused(cli: Cli, planned: Path) -> None:
    r = cli("study", "run", PERSON, "--out", planned)
    assert_bad_input(r, "--participant", "give --participant", "--simulate", "rehearsal")


def test_a_rehearsal_with_a_population_planting_an_unknown_condition_is_refused(
    cli: Cli, planned: Path
) -> None:
    population = Path(__file__).parents[1] / "study" / "data" / "planted.toml"  # plants 'late'
    r = cli("study", "run", PERSON, "--participant", "P01", "--simulate", population,
            "--out", planned)  # fmt: skip
    assert_bad_input(r, "late")


def test_participants_is_for_simulate_only(cli: Cli, planned: Path) -> None:
    r = cli("study", "run", PERSON, "--participant", "P01", "--participants", "2", "--out", planned)
    assert_bad_input(r, "--participants", "is for --simulate")


def test_no_plan_in_out_is_refused_naming_plan_json(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "empty"
    r = cli("study", "run", PERSON, "--participant", "P01", "--out", out)
    assert_bad_input(r, str(out / "plan.json"), "no plan", "legws study plan person")
    assert not out.exists()  # nothing made


def test_a_participant_the_plan_has_not_is_refused_naming_participant(
    cli: Cli, planned: Path
) -> None:
    before = sorted(p.name for p in planned.iterdir())
    r = cli("study", "run", PERSON, "--participant", "P09", "--out", planned)
    assert_bad_input(r, "--participant", "P09 is not a participant of this plan", "P01", "P02")
    # the same with no viewer, and on a page port of its own: refused the same way
    r = cli("study", "run", PERSON, "--participant", "P09", "--out", planned,
            "--viewer-port", "0", "--page-port", "0")  # fmt: skip
    assert_bad_input(r, "--participant", "P09 is not a participant")
    assert sorted(p.name for p in planned.iterdir()) == before  # no participant folder


def test_another_protocols_plan_is_refused(cli: Cli, planned: Path, tmp_path: Path) -> None:
    other = tmp_path / "v2" / "person.toml"
    other.parent.mkdir()
    other.write_text(PERSON.read_text().replace("one pick each", "one pick apiece"))
    r = cli("study", "run", other, "--participant", "P01", "--out", planned)
    assert_bad_input(r, "plan.json", "protocol_sha256", "another protocol")
