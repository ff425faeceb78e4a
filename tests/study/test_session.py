"""A session's saved state read back: it resumes only as what it was — the same participant,
protocol text, and a person's session never a rehearsal's (their data never mix)."""

from __future__ import annotations

from pathlib import Path

import pytest

from legws_daemon.cli.study import write_plan
from legws_daemon.errors import InputError
from legws_daemon.study.control import Control
from legws_daemon.study.layouts import Layouts
from legws_daemon.study.protocol import load_protocol
from legws_daemon.study.rig import RigSpec
from legws_daemon.study.session import STATE_FILE, Session
from tests.study.person import PERSON


def _session(study: Path, rehearsal: str | None, participant: str = "P01") -> Session:
    p = load_protocol(PERSON)
    schedule = write_plan(p, 2, study, False, True)
    return Session(
        p, schedule, participant, study / participant, RigSpec("sim"),
        Control(p.spec.questionnaires), Layouts(study / "layouts"), rehearsal=rehearsal,
    )  # fmt: skip


def test_a_new_session_starts_at_its_first_step_and_saves_what_it_is(tmp_path: Path) -> None:
    s = _session(tmp_path, "lab")
    assert s.next_step is not None and s.next_step.index == 1
    assert s.state.rehearsal == "lab" and s.state.done == []
    s._save()
    again = _session(tmp_path, "lab")
    assert again.state == s.state


@pytest.mark.parametrize(("first", "then"), [("lab", None), (None, "lab")])
def test_a_rehearsal_and_a_person_never_share_a_folder(
    tmp_path: Path, first: str | None, then: str | None
) -> None:
    _session(tmp_path, first)._save()
    with pytest.raises(InputError) as info:
        _session(tmp_path, then)
    assert info.value.field == "rehearsal"
    assert info.value.source == str(tmp_path / "P01" / STATE_FILE)
    assert "never share a study folder" in str(info.value)


def test_another_participants_state_is_refused(tmp_path: Path) -> None:
    _session(tmp_path, None)._save()
    (tmp_path / "P02").mkdir()
    (tmp_path / "P02" / STATE_FILE).write_bytes((tmp_path / "P01" / STATE_FILE).read_bytes())
    with pytest.raises(InputError) as info:
        _session(tmp_path, None, "P02")
    assert info.value.field == "protocol_sha256" and "P01" in str(info.value)


def test_a_participant_not_in_the_plan_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InputError) as info:
        _session(tmp_path, None, "P09")
    assert info.value.field == "--participant"
