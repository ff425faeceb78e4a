"""Hostile recordings through the real ``legws replay FILE`` and ``legws recording finish
FILE`` (:mod:`tests.reliability.recording_corpus`): each case ends within 5 s with exit 2,
exactly one ``legws: error:`` line on stderr and nothing on stdout, under 1 GiB, and no
file changes (a recording that cannot be finished whole is left byte for byte). A healthy
raw recording behind a link is finished in its own folder, the link kept; replayed through
the link, it replays.

The cases run as real ``legws`` processes forked from one that imported legws once
(:mod:`tests.reliability.corpus_runner`), a group per test.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.telemetry.rrd_file import scan
from tests.reliability.corpus import snapshot
from tests.reliability.recording_corpus import GROUPS, Box, Case, all_cases
from tests.reliability.test_hostile_corpus import problems, run_cases
from tests.telemetry.helpers import raw_recording, verify


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """A raw recording as the daemon leaves it when killed (two stages, no footer)."""
    return raw_recording(tmp_path_factory.mktemp("raw") / "raw.rrd").read_bytes()


def one_line(name: str, result: dict[str, Any]) -> list[str]:
    """:func:`problems`, and exactly one error line."""
    found = problems(name, result)
    if len(result["stderr"].splitlines()) != 1:
        found.append(f"{name}: {len(result['stderr'].splitlines())} lines on stderr")
    return found


@pytest.mark.slow
@pytest.mark.parametrize("group", GROUPS)
def test_hostile_recordings_end_in_one_line_and_change_nothing(
    tmp_path: Path, group: str, raw: bytes
) -> None:
    box = Box(tmp_path)
    cases = all_cases(box, group, raw)
    assert cases
    good: list[Case] = []
    if group == "links":  # a link to a healthy raw recording: replayed, then finished
        target = box.path("raw-target", "target.rrd")
        target.write_bytes(raw)
        link = target.parent / "session.rrd"
        link.symlink_to(target.name)
        good = [
            box.case("links/to-a-raw-recording/replay", ["replay", "{f}", "--json"], link),
            box.case("links/to-a-raw-recording/finish", ["recording", "finish", "{f}"], link),
        ]
    before = snapshot(tmp_path)
    results = run_cases(tmp_path, [c.to_json(tmp_path) for c in cases + good])
    after = snapshot(tmp_path)
    found = [p for c, r in zip(cases, results, strict=False) for p in one_line(c.name, r)]
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    if good:
        replayed, finished = results[len(cases) :]
        assert replayed["code"] == 0, replayed["stderr"]
        assert len(json.loads(replayed["stdout"])["stages"]) == 2
        assert finished["code"] == 0 and finished["stderr"] == "", finished
        assert finished["stdout"].startswith(f"{link.relative_to(tmp_path)} (-> "), finished
        assert link.is_symlink() and os.readlink(link) == "target.rrd"
        assert verify(target).returncode == 0 and scan(target).footer
        expected = {str(p.relative_to(tmp_path)) for p in (target, target.parent)}
        assert set(changed) <= expected, changed  # the target (and its folder's time)
        changed = [k for k in changed if k not in expected]
    found += [f"changed: {k}" for k in changed]
    report = {
        "group": group,
        "cases": len(cases),
        "max_seconds": round(max(r["seconds"] for r in results), 2),
        "total_seconds": round(sum(r["seconds"] for r in results), 2),
        "max_rss_mib": round(max(r["maxrss_mib"] for r in results), 1),
    }
    print(json.dumps(report))
    assert not found, f"{len(found)} problems in {len(cases)} cases:\n" + "\n".join(found)
