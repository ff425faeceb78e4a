"""The small protocol of a person's session (``data/person.toml``) and a valid set of its
questionnaire's answers, shared by the page's and the session's tests."""

from __future__ import annotations

from pathlib import Path

from legws_daemon.study.protocol import load_protocol

PERSON = Path(__file__).parent / "data" / "person.toml"
Q = load_protocol(PERSON).spec.questionnaires
ANSWERS = {
    "tlx_mental": 40, "tlx_physical": 10, "tlx_temporal": 55, "tlx_performance": 0,
    "tlx_effort": 100, "tlx_frustration": 25, "likert_1": 4,
}  # fmt: skip
