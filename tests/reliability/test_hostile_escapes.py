"""Names on the command line that hold terminal escapes (:mod:`.escape_corpus`): every
command that echoes one back prints it as visible escapes, in one ``legws: error:`` line.

Each class of hostile text goes in as a scene name, a task graph name, a profile path and
an input mapping name, through the real commands (forked ``legws`` processes,
:func:`tests.reliability.test_hostile_corpus.run_cases`); each case keeps the corpus's
contract (exit 2, one ``legws: error:`` line, nothing on stdout, within 5 s) and neither
output holds a character a terminal would act on.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from legws_daemon.formats.printable import MESSAGE_LIMIT
from tests.reliability.escape_corpus import as_argument, hostile_texts, unsafe_in
from tests.reliability.test_hostile_corpus import REPO, problems, run_cases

#: Where a name goes: the command line, ``{t}`` the hostile text.
COMMANDS = {
    "scene": ["certify", "--scene", "{t}", "--json"],
    "taskgraph": ["taskgraph", "check", "{t}"],
    "profile-path": ["joystick", "sim-user", "--profile", "{t}.toml", "--duration", "1"],
    "mapping": ["joystick", "evdev", "--profile", "sim", "--mapping", "{t}", "--device", "no"],
}


def test_a_hostile_scene_name_is_one_safe_error_line() -> None:
    # a real process, as a shell would run it: legws certify --scene $'desk\e]0;x\a'
    done = subprocess.run(
        [sys.executable, "-m", "legws_daemon", "certify", "--scene", "desk\x1b]0;x\x07\u202e"],
        cwd=REPO, capture_output=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 2
    assert done.stdout == b""
    err = done.stderr.decode()  # strict: every byte UTF-8
    assert err.startswith("legws: error: scene: unknown scene 'desk\\x1b]0;x\\x07\\u202e'"), err
    assert err.count("\n") == 1 and err.endswith("\n")
    assert unsafe_in(err) == []
    # bytes that are not UTF-8 (a file name from another system): shown as escapes too
    done = subprocess.run(
        [sys.executable.encode(), b"-m", b"legws_daemon", b"taskgraph", b"check", b"tea\xff\x9b"],
        cwd=REPO, capture_output=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 2 and done.stdout == b""
    err = done.stderr.decode()
    assert err.startswith("legws: error: taskgraph: unknown task graph 'tea\\udcff\\udc9b'"), err
    assert err.count("\n") == 1 and unsafe_in(err) == []


@pytest.mark.slow  # ~10 s: 64 forked commands
def test_hostile_names_on_the_command_line_end_in_one_safe_line(tmp_path: Path) -> None:
    labels, cases = [], []
    for label, text in hostile_texts():
        for where, argv in COMMANDS.items():
            labels.append(f"{where}/{label}")
            cases.append({"argv": [a.replace("{t}", as_argument(text)) for a in argv],
                          "cwd": str(tmp_path), "env": {}})  # fmt: skip
    results = run_cases(tmp_path, cases)
    found = [p for name, r in zip(labels, results, strict=True) for p in problems(name, r)]
    for name, result in zip(labels, results, strict=True):
        bad = unsafe_in(result["stdout"] + result["stderr"])
        if bad:
            found.append(f"{name}: unsafe characters in the output: {' '.join(bad)}")
        for line in result["stderr"].splitlines():
            if len(line) > len("legws: error: ") + MESSAGE_LIMIT:
                found.append(f"{name}: a line of {len(line)} characters")
    report = {"cases": len(cases), "max_seconds": max(r["seconds"] for r in results)}
    print(json.dumps(report))
    assert not found, f"{len(found)} problems in {len(cases)} cases:\n" + "\n".join(found)
