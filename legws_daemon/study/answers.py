"""A questionnaire's answers, as the participant's page sends them: validated before they
are kept.

The questionnaire after a condition is the protocol's ``[questionnaires]``: the six raw
NASA-TLX subscales (each 0-100 in steps of 5) when ``nasa_tlx``, then each Likert item (an
integer point 1..``likert_points``). :func:`questionnaire_fields` lists its fields (what the
page shows); :func:`check_answers` turns a submitted JSON object into the trial table's
questionnaire columns (``tlx_<subscale>``, ``tlx_raw`` — their mean — and ``likert_<k>``),
or refuses it with one line naming the field and what was expected: an answer left out, a
value off the scale, a field the questionnaire has not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

from legws_daemon.errors import InputError
from legws_daemon.study.protocol import NASA_TLX, QuestionnaireSpec

#: NASA-TLX subscales are marked in steps of this many points.
TLX_STEP = 5


@dataclass(frozen=True, slots=True)
class Field:
    """One question: ``name`` (the table's column), ``kind``, the question's ``text``, the
    scale's ends and step, and the words at its ends."""

    name: str
    kind: Literal["tlx", "likert"]
    text: str
    low: int
    high: int
    step: int
    low_label: str
    high_label: str

    def as_data(self) -> dict[str, Any]:
        return {
            "name": self.name, "kind": self.kind, "text": self.text, "low": self.low,
            "high": self.high, "step": self.step, "low_label": self.low_label,
            "high_label": self.high_label,
        }  # fmt: skip


def questionnaire_fields(q: QuestionnaireSpec) -> tuple[Field, ...]:
    """The questions, in the order asked."""
    out: list[Field] = []
    if q.nasa_tlx:
        for key, text in NASA_TLX:
            low, high = (
                ("Perfect", "Failure") if key == "performance" else ("Very low", "Very high")
            )
            out.append(Field(f"tlx_{key}", "tlx", text, 0, 100, TLX_STEP, low, high))
    for k, text in enumerate(q.likert, start=1):
        out.append(
            Field(f"likert_{k}", "likert", text, 1, q.likert_points, 1,
                  "Strongly disagree", "Strongly agree")
        )  # fmt: skip
    return tuple(out)


def check_answers(q: QuestionnaireSpec, data: Any, source: str) -> dict[str, Any]:
    """The trial table's questionnaire columns of the submitted ``data`` (a JSON object of
    field name -> integer).

    Raises:
        InputError: naming ``source`` and the field, when ``data`` is not an object, a
            question is unanswered, an answer is not an integer of its scale (TLX: 0-100 in
            steps of 5; Likert: 1..points), or a field is not a question.
    """
    if not isinstance(data, dict):
        raise InputError(f"expected a JSON object of answers, got {type(data).__name__}",
                         source=source)  # fmt: skip
    fields = questionnaire_fields(q)
    names = {f.name for f in fields}
    extra = sorted(str(k) for k in data if k not in names)
    if extra:
        raise InputError(
            f"not a question of this questionnaire (its fields: {', '.join(sorted(names))})",
            source=source, field=extra[0][:64],
        )  # fmt: skip
    out: dict[str, Any] = {}
    for f in fields:
        if f.name not in data:
            raise InputError("unanswered: every question needs an answer", source=source,
                             field=f.name)  # fmt: skip
        value = data[f.name]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"expected a number {f.low}-{f.high}, got {type(value).__name__}",
                             source=source, field=f.name)  # fmt: skip
        if not math.isfinite(value) or value != int(value):
            raise InputError(f"expected a whole number {f.low}-{f.high}", source=source,
                             field=f.name)  # fmt: skip
        v = int(value)
        if not f.low <= v <= f.high or (v - f.low) % f.step:
            steps = f" in steps of {f.step}" if f.step > 1 else ""
            raise InputError(f"expected {f.low}-{f.high}{steps}, got {v}", source=source,
                             field=f.name)  # fmt: skip
        out[f.name] = float(v) if f.kind == "tlx" else v
    tlx = [out[f.name] for f in fields if f.kind == "tlx"]
    if tlx:
        out["tlx_raw"] = sum(tlx) / len(tlx)
    return out
