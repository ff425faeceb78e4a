"""A study's folder on disk: the plan ``legws study plan`` wrote, read back."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from legws_daemon.errors import InputError
from legws_daemon.formats.validation import read_json

if TYPE_CHECKING:
    from legws_daemon.study.protocol import Protocol
    from legws_daemon.study.schedule import Schedule


def existing_plan(folder: Path) -> dict[str, Any] | None:
    """The ``plan.json`` in ``folder``, or ``None`` when there is none."""
    path = folder / "plan.json"
    if not path.exists():
        return None
    data = read_json(path, "study schedule")
    if not isinstance(data, dict):
        raise InputError("expected a JSON object (a study plan)", source=str(path))
    return data


def planned_schedule(protocol: Protocol, folder: Path) -> Schedule:
    """The schedule of the plan in ``folder`` (``legws study plan``), made again from
    ``protocol`` and checked to be that plan (the same protocol text, participants and
    steps): a session runs what was planned, or not at all.

    Raises:
        InputError: no plan there, or the plan is not this protocol's.
    """
    from legws_daemon.study.schedule import make_schedule

    plan = existing_plan(folder)
    source = str(folder / "plan.json")
    if plan is None:
        raise InputError(
            f"no plan: make it first with `legws study plan {protocol.name} --participants N "
            f"--out {folder}`",
            source=source,
        )
    if plan.get("protocol_sha256") != protocol.sha256:
        raise InputError(
            f"was planned from another protocol (or another version of {protocol.name}: "
            "its text changed); run the protocol the plan was made from",
            source=source, field="protocol_sha256",
        )  # fmt: skip
    people = plan.get("participants")
    if not isinstance(people, dict) or not people:
        raise InputError("expected participants (an object)", source=source, field="participants")
    schedule = make_schedule(protocol, len(people))
    if schedule.plan_json() != plan:
        raise InputError(
            "does not match what this protocol plans for its participants (edited by hand?); "
            "plan again into a new folder",
            source=source,
        )
    return schedule


def write_study_table(folder: Path, likert_texts: Sequence[str]) -> int:
    """The study's trial table, ``folder/trials.csv`` and ``.parquet``, made of every
    participant's (``folder/PXX/trials.parquet``, pseudonym-named folders only), and the
    data dictionary beside it; returns the number of rows. A person's session writes it
    after every step, so the study's table always holds every session's trials so far."""
    from legws_daemon.study.pseudonym import what_it_looks_like
    from legws_daemon.study.table import read_table, write_dictionary, write_table

    parts = sorted(
        p for p in folder.glob("*/trials.parquet") if what_it_looks_like(p.parent.name) is None
    )
    rows = [r for p in parts for r in read_table(p)]
    write_table(folder, "trials", rows, len(likert_texts))
    write_dictionary(folder, likert_texts)
    return len(rows)
