"""The hostile-input corpus of issue 16, measured: cases, time and memory per group.

Builds the corpus of ``tests/reliability/corpus.py`` (every file kind broken every way,
every output option pointed at devices, FIFOs, sockets and links, numeric options at
their extremes), runs each case as a ``legws`` process forked from one that imported legws
once (``tests/reliability/corpus_runner.py``), and reports per group the number of cases,
how many ended as required (exit 2, one ``legws: error:`` line, within 5 s), the median
and largest wall time, and the largest peak resident set (``ru_maxrss`` of the case's
process, which includes the ~200 MiB of the imported libraries it shares with its parent).

Usage:
    python benchmarks/hostile_corpus.py [--out docs/results/hostile_corpus.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.net import free_port  # noqa: E402
from tests.reliability.corpus import GROUPS, Sandbox, all_cases, snapshot  # noqa: E402
from tests.reliability.test_hostile_corpus import (  # noqa: E402
    TIME_LIMIT,
    problems,
    run_cases,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs/results/hostile_corpus.json")
    args = parser.parse_args()
    rows = []
    for group in GROUPS:
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            box = Sandbox(root, free_port())
            cases = all_cases(box, group)
            before = snapshot(root)
            results = run_cases(root, [c.to_json(root) for c in cases], TIME_LIMIT)
            changed = [k for k, v in snapshot(root).items() if before.get(k) != v]
        bad = [
            p for c, r in zip(cases, results, strict=True) for p in problems(c.name, r, TIME_LIMIT)
        ]
        seconds = [r["seconds"] for r in results]
        row = {
            "group": group,
            "cases": len(cases),
            "as_required": len(cases) - len({b.split(": ")[0] for b in bad}),
            "median_s": round(statistics.median(seconds), 3),
            "max_s": round(max(seconds), 3),
            "max_rss_mib": round(max(r["maxrss_mib"] for r in results), 1),
            "files_changed_outside_output": len(changed),
            "problems": bad,
        }
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "problems"}), flush=True)
    total = {
        "cases": sum(r["cases"] for r in rows),
        "as_required": sum(r["as_required"] for r in rows),
        "max_s": max(r["max_s"] for r in rows),
        "max_rss_mib": max(r["max_rss_mib"] for r in rows),
        "files_changed_outside_output": sum(r["files_changed_outside_output"] for r in rows),
    }
    print(json.dumps({"total": total}))
    print("\n| group | cases | as required | median s | max s | max RSS MiB |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['group']} | {r['cases']} | {r['as_required']} | {r['median_s']:.2f} | "
            f"{r['max_s']:.2f} | {r['max_rss_mib']:.0f} |"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"groups": rows, "total": total}, indent=1) + "\n")


if __name__ == "__main__":
    main()
