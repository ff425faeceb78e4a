"""docs/messages.md names every field of every wire message and every value people see."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import get_args

import pytest
from pydantic import BaseModel

from legws_daemon.autonomy import events
from legws_daemon.autonomy.modes import Mode
from legws_daemon.daemon.inbox import REJECTIONS, NoInput
from legws_daemon.daemon.lease import LeaseReason
from legws_daemon.formats import messages

DOC = (Path(__file__).parents[2] / "docs" / "messages.md").read_text(encoding="utf-8")
NAMED = set(re.findall(r"`([^`\s]+)`", DOC))


def fields_of(model: type[BaseModel], prefix: str = "") -> set[str]:
    out = set()
    for name, info in model.model_fields.items():
        wire = info.alias or name
        out.add(prefix + wire)
        annotation = info.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            out |= fields_of(annotation, f"{wire}.")
    return out


@pytest.mark.parametrize(
    "model",
    [
        messages.JoystickMessage,
        messages.StatusMessage,
        messages.EventMessage,
        messages.CommandRequest,
        messages.ObjectsMessage,
    ],
)
def test_every_field_is_documented(model: type[BaseModel]) -> None:
    missing = {f for f in fields_of(model) if f not in NAMED and f.rsplit(".", 1)[-1] not in NAMED}
    assert not missing, f"{model.__name__}: {sorted(missing)} not in docs/messages.md"


def test_every_event_kind_and_detail_key_is_documented() -> None:
    kinds = set(get_args(messages.EventKind))
    assert kinds <= NAMED
    for cls in vars(events).values():
        if isinstance(cls, type) and issubclass(cls, events.Event) and cls is not events.Event:
            keys = {f.name for f in dataclasses.fields(cls)}
            assert keys <= NAMED, f"{cls.__name__}: {sorted(keys - NAMED)}"


def test_every_value_of_mode_reasons_and_commands_is_documented() -> None:
    values = {m.value for m in Mode}
    values |= set(get_args(messages.StatusMessage.model_fields["mode"].annotation))
    values |= set(REJECTIONS) | set(get_args(LeaseReason)) | set(get_args(NoInput))
    values |= set(get_args(messages.CommandRequest.model_fields["command"].annotation))
    assert values <= NAMED, sorted(values - NAMED)
    assert {m.value for m in Mode} == set(
        get_args(messages.StatusMessage.model_fields["mode"].annotation)
    )  # the schema allows exactly the modes the controller has
