"""Issue 16: a generated corpus of hostile inputs through every command and the daemon's
loaders (:mod:`tests.reliability.corpus`). Each case ends within 5 s with exit 2 and
``legws: error:`` lines only (one per error), under 1 GiB resident, and no file outside its
output path changes.

The cases run as real ``legws`` processes forked from one that imported legws once
(:mod:`tests.reliability.corpus_runner`), so the few hundred of them take a minute or two.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.net import free_port
from tests.reliability.corpus import GROUPS, Sandbox, all_cases, snapshot

REPO = Path(__file__).parents[2]
#: The issue's bounds: seconds, and MiB of resident memory.
TIME_LIMIT = 5.0
MEMORY_LIMIT_MIB = 1024.0


def run_cases(root: Path, cases: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Run the cases with the fork runner; its results, in order."""
    todo, done = root / ".runner-cases.json", root / ".runner-results.json"
    todo.write_text(json.dumps(cases))
    out = subprocess.run(
        [sys.executable, "-m", "tests.reliability.corpus_runner", str(todo), str(done)],
        cwd=REPO, capture_output=True, text=True, timeout=60 + 8 * len(cases), check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    results: list[dict[str, Any]] = json.loads(done.read_text())
    todo.unlink()
    done.unlink()
    return results


def problems(name: str, result: dict[str, Any]) -> list[str]:
    """What is wrong with one case's outcome (nothing when it is a one-line exit 2)."""
    found = []
    if result["killed"]:
        found.append(f"killed after {result['seconds']:.1f} s")
    elif result["seconds"] > TIME_LIMIT:
        found.append(f"took {result['seconds']:.1f} s")
    if result["code"] != 2:
        found.append(f"exit {result['code']}")
    lines = result["stderr"].splitlines()  # one line per error (a file's every error)
    if not lines or not all(line.startswith("legws: error: ") for line in lines):
        found.append(f"stderr {len(lines)} lines: {result['stderr'][-400:]!r}")
    if result["stdout"]:
        found.append(f"stdout: {result['stdout'][-200:]!r}")
    if result["maxrss_mib"] > MEMORY_LIMIT_MIB:
        found.append(f"{result['maxrss_mib']:.0f} MiB resident")
    return [f"{name}: {p}" for p in found]


@pytest.mark.slow
@pytest.mark.parametrize("group", GROUPS)
def test_hostile_inputs_end_in_one_line(tmp_path: Path, group: str) -> None:
    box = Sandbox(tmp_path, free_port())
    cases = all_cases(box, group)
    assert cases
    before = snapshot(tmp_path)
    assets = snapshot(REPO / ".assets", skip=())
    results = run_cases(tmp_path, [c.to_json(tmp_path) for c in cases])
    after = snapshot(tmp_path)
    found = [p for c, r in zip(cases, results, strict=True) for p in problems(c.name, r)]
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    found += [f"changed outside the output path: {k}" for k in changed]
    if snapshot(REPO / ".assets", skip=()) != assets:
        found.append("the asset cache changed")
    report = {
        "group": group,
        "cases": len(cases),
        "max_seconds": max(r["seconds"] for r in results),
        "max_rss_mib": max(r["maxrss_mib"] for r in results),
    }
    print(json.dumps(report))
    assert not found, f"{len(found)} problems in {len(cases)} cases:\n" + "\n".join(found)
