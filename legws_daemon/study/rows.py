"""A trial's row of the trial table (:mod:`.table`): what the step was, the layout and its
certificates, what was measured — the same for a simulated participant and a person."""

from __future__ import annotations

import json
from typing import Any

from legws_daemon.design.operators import finite_or_none
from legws_daemon.study.certificates import TrialCertificates
from legws_daemon.study.layouts import TrialLayout
from legws_daemon.study.outcome import Outcome
from legws_daemon.study.protocol import Protocol
from legws_daemon.study.schedule import Step


def trial_row(
    protocol: Protocol,
    step: Step,
    participant: str,
    assist: str,
    layout: TrialLayout,
    certs: TrialCertificates,
    outcome: Outcome,
    *,
    hesitation_s: float | None,
    recording: str = "",
    frames: str = "",
) -> dict[str, Any]:
    """The row of ``step`` (a practice or trial step of ``participant``)."""
    assert step.task is not None
    task = protocol.tasks[step.task]
    row: dict[str, Any] = {
        "participant": participant,
        "protocol": protocol.name,
        "protocol_sha256": protocol.sha256,
        "index": step.index,
        "kind": step.kind,
        "condition": step.condition or "",
        "position": step.position,
        "trial": step.trial,
        "task": task.name,
        "source": task.source,
        "assist": assist,
        "layout_source": layout.source,
        "layout_origin": layout.origin,
        "layout": json.dumps(layout.as_data(), separators=(",", ":")),
        "goal": step.targets[0] if step.targets else "",
        "targets": ";".join(step.targets),
        "decisions": certs.decisions,
        "slack_j": certs.slack_j,
        "commit_k": finite_or_none(certs.commit_k),
        "person_slack_j": certs.person_slack_j,
        "person_commit_k": (
            None if certs.person_commit_k is None else finite_or_none(certs.person_commit_k)
        ),
        "hesitation_s": hesitation_s,
        "recording": recording,
        "frames": frames,
    }
    row.update(outcome.columns(step.targets))
    return row
