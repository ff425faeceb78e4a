"""Plain helpers of the CLI tests: the example goal set, the script runner, the checks."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: The goal-set file of ``shared/spec/interfaces.md``, verbatim.
EXAMPLE_GOALSET: dict[str, Any] = {
    "x0": {"position": [0.55, 0.0, 0.30], "quaternion": [0, 1, 0, 0]},
    "goals": [
        {
            "name": "mug",
            "position": [0.62, 0.21, 0.07],
            "quaternion": [0, 1, 0, 0],
            "symmetry": 2,
        },
        {
            "name": "stapler",
            "position": [0.70, -0.18, 0.04],
            "quaternion": [0, 0.7071068, 0.7071068, 0],
        },
    ],
    "params": {
        "beta": 5,
        "rotation_weight": 0.04,
        "sigma": 0.03,
        "v_max": 0.05,
        "dt": 0.05,
        "alpha": 0.05,
        "horizon_fraction": 0.75,
        "cost": "dragan",
    },
}

#: The installed console script (``python -m legws_daemon.cli`` is not an entry point).
LEGWS = Path(sys.executable).parent / "legws"


@dataclass(frozen=True)
class Result:
    code: int
    out: str
    err: str


def run_script(*argv: str | Path, cwd: Path) -> Result:
    """Run the installed ``legws`` script as a real subprocess."""
    proc = subprocess.run(
        [str(LEGWS), *map(str, argv)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    return Result(proc.returncode, proc.stdout, proc.stderr)


def assert_bad_input(result: Result, *needles: str) -> str:
    """Exit 2, nothing on stdout, one ``legws: error:`` line containing every needle."""
    assert result.code == 2, result
    assert result.out == "", result
    assert "Traceback" not in result.err
    assert result.err.endswith("\n"), result.err
    lines = result.err.splitlines()
    assert len(lines) == 1, result.err
    line = lines[0]
    assert line.startswith("legws: error: "), line
    for needle in needles:
        assert needle in line, f"{needle!r} not in {line!r}"
    return line


def assert_bad_input_lines(result: Result, *needles: str) -> list[str]:
    """Exit 2, nothing on stdout, one or more ``legws: error:`` lines (one per error of a
    file), each containing every needle; no traceback."""
    assert result.code == 2, result
    assert result.out == "", result
    assert "Traceback" not in result.err
    assert result.err.endswith("\n"), result.err
    lines = result.err.splitlines()
    assert lines, result.err
    for line in lines:
        assert line.startswith("legws: error: "), line
        for needle in needles:
            assert needle in line, f"{needle!r} not in {line!r}"
    return lines
