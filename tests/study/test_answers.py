"""Questionnaire answers: the fields in the order asked, the table's columns of valid answers,
and a refusal naming the field for anything else."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.study.answers import TLX_STEP, check_answers, questionnaire_fields
from legws_daemon.study.protocol import NASA_TLX, QuestionnaireSpec, load_protocol
from tests.study.person import PERSON

TLX = [f"tlx_{key}" for key, _ in NASA_TLX]
Q = load_protocol(PERSON).spec.questionnaires
SOURCE = "the questionnaire"


def valid() -> dict[str, Any]:
    """Answers to every question of person.toml (six TLX subscales, one 5-point item)."""
    return {
        "tlx_mental": 40, "tlx_physical": 10, "tlx_temporal": 55, "tlx_performance": 0,
        "tlx_effort": 100, "tlx_frustration": 25, "likert_1": 4,
    }  # fmt: skip


def refused(data: Any) -> InputError:
    with pytest.raises(InputError) as info:
        check_answers(Q, data, SOURCE)
    assert "\n" not in str(info.value)
    assert str(info.value).startswith(SOURCE + ": ")
    return info.value


def test_the_fields_are_the_tlx_subscales_then_the_likert_items_with_their_scales() -> None:
    fields = questionnaire_fields(Q)
    assert [f.name for f in fields] == [*TLX, "likert_1"]
    for f, (_, text) in zip(fields[:6], NASA_TLX, strict=True):
        assert (f.kind, f.low, f.high, f.step, f.text) == ("tlx", 0, 100, TLX_STEP, text)
    performance = fields[TLX.index("tlx_performance")]
    assert (performance.low_label, performance.high_label) == ("Perfect", "Failure")
    assert (fields[0].low_label, fields[0].high_label) == ("Very low", "Very high")
    likert = fields[-1]
    assert (likert.kind, likert.low, likert.high, likert.step) == ("likert", 1, 5, 1)
    assert likert.text == "The robot understood which object I wanted."
    assert likert.as_data()["high"] == 5 and likert.as_data()["name"] == "likert_1"


def test_without_tlx_only_the_likert_items_are_asked() -> None:
    q = QuestionnaireSpec(nasa_tlx=False, likert_points=7, likert=["a", "b"])
    assert [(f.name, f.high) for f in questionnaire_fields(q)] == [
        ("likert_1", 7),
        ("likert_2", 7),
    ]
    out = check_answers(q, {"likert_1": 7, "likert_2": 1}, SOURCE)
    assert out == {"likert_1": 7, "likert_2": 1}  # no tlx_raw without TLX


def test_valid_answers_are_the_table_columns_with_the_raw_tlx_their_mean() -> None:
    out = check_answers(Q, valid(), SOURCE)
    assert set(out) == {*TLX, "tlx_raw", "likert_1"}
    for name in TLX:
        assert type(out[name]) is float and out[name] == valid()[name]
    assert type(out["likert_1"]) is int and out["likert_1"] == 4
    assert out["tlx_raw"] == pytest.approx((40 + 10 + 55 + 0 + 100 + 25) / 6)


def test_whole_floats_are_taken_as_the_integers_they_are() -> None:
    data = {**valid(), "tlx_mental": 45.0, "likert_1": 2.0}
    out = check_answers(Q, data, SOURCE)
    assert out["tlx_mental"] == 45.0 and type(out["likert_1"]) is int and out["likert_1"] == 2


@pytest.mark.parametrize("data", [[1, 2], "answers", None, 3])
def test_anything_but_an_object_is_refused(data: Any) -> None:
    err = refused(data)
    assert "expected a JSON object of answers" in str(err)


def test_an_unanswered_question_is_refused_naming_it() -> None:
    data = valid()
    del data["tlx_effort"]
    err = refused(data)
    assert err.field == "tlx_effort" and "unanswered" in str(err)


def test_a_field_the_questionnaire_has_not_is_refused_naming_it() -> None:
    err = refused({**valid(), "likert_2": 3})
    assert err.field == "likert_2" and "not a question" in str(err)
    assert "likert_1" in str(err)  # it lists the fields there are


@pytest.mark.parametrize(
    ("name", "value", "words"),
    [
        ("tlx_mental", True, "got bool"),
        ("likert_1", False, "got bool"),
        ("tlx_physical", "50", "got str"),
        ("likert_1", None, "got NoneType"),
        ("likert_1", [3], "got list"),
        ("tlx_temporal", 42.5, "whole number"),
        ("likert_1", 3.5, "whole number"),
        ("tlx_effort", math.nan, "whole number"),
        ("tlx_effort", math.inf, "whole number"),
        ("likert_1", -math.inf, "whole number"),
        ("tlx_frustration", 105, "expected 0-100 in steps of 5, got 105"),
        ("tlx_frustration", -5, "got -5"),
        ("tlx_performance", 42, "in steps of 5, got 42"),
        ("likert_1", 0, "expected 1-5, got 0"),
        ("likert_1", 6, "expected 1-5, got 6"),
        ("likert_1", 1e300, "expected 1-5"),
    ],
)
def test_a_value_off_its_scale_is_refused_naming_the_field(
    name: str, value: Any, words: str
) -> None:
    err = refused({**valid(), name: value})
    assert err.field == name
    assert words in str(err)


TLX_VALUES = st.integers(0, 100 // TLX_STEP).map(lambda k: k * TLX_STEP)
LIKERT_VALUES = st.integers(1, Q.likert_points)


@st.composite
def answers(draw: st.DrawFn) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in questionnaire_fields(Q):
        v = draw(TLX_VALUES if f.kind == "tlx" else LIKERT_VALUES)
        out[f.name] = float(v) if draw(st.booleans()) else v
    return out


def not_on_scale(kind: str) -> st.SearchStrategy[Any]:
    """Values a field of ``kind`` refuses: off the scale, between its steps, not a number."""
    f = next(f for f in questionnaire_fields(Q) if f.kind == kind)
    off = st.integers(-(10**6), 10**6).filter(
        lambda v: not (f.low <= v <= f.high and (v - f.low) % f.step == 0)
    )
    between = st.floats(allow_nan=False, allow_infinity=False).filter(lambda v: v != int(v))
    return st.one_of(
        off,
        off.map(float),
        between,
        st.sampled_from([math.nan, math.inf, -math.inf, True, False, None, "3", [1], {}]),
    )


@settings(max_examples=200, deadline=None)
@given(answers())
def test_any_valid_answers_are_accepted_and_come_back_as_given(data: dict[str, Any]) -> None:
    out = check_answers(Q, data, SOURCE)
    fields = questionnaire_fields(Q)
    for f in fields:
        assert out[f.name] == data[f.name]
        assert type(out[f.name]) is (float if f.kind == "tlx" else int)
    assert out["tlx_raw"] == pytest.approx(sum(data[n] for n in TLX) / len(TLX))
    assert set(out) == {f.name for f in fields} | {"tlx_raw"}


@settings(max_examples=300, deadline=None)
@given(answers(), st.data())
def test_any_one_answer_made_invalid_is_refused_naming_that_field(
    data: dict[str, Any], draw: st.DataObject
) -> None:
    f = draw.draw(st.sampled_from(questionnaire_fields(Q)))
    bad = draw.draw(not_on_scale(f.kind))
    with pytest.raises(InputError) as info:
        check_answers(Q, {**data, f.name: bad}, SOURCE)
    assert info.value.field == f.name
