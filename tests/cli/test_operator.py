"""``legws operator fit|trace`` and ``legws certify --operator`` from the outside: the
interfaces.md shapes, and bad files as one line with exit 2."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import certify_commit
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.user_model import SimulatedUser
from legws_daemon.formats.goalset import load_goalset
from legws_daemon.formats.operator_file import load_operator
from legws_daemon.formats.trace import Segment, write_trace
from legws_daemon.sim.reaches import simulate_reaches
from tests.cli.helpers import Result

Cli = Callable[..., Result]
TRUTH = OperatorModel(0.7, 0.006, 0.6, 12.0, "free")
KEYS = {"schema", "name", "speed", "sigma", "rho", "bias_deg", "steering", "segments", "ticks",
        "intervals", "certify_with"}  # fmt: skip


def _trace(tmp_path: Path, reaches: int = 12) -> Path:
    sim = simulate_reaches(SimulatedUser(TRUTH, clip=True), reaches, np.random.default_rng(2))
    path = tmp_path / "alice.trace.jsonl"
    write_trace(path, [Segment(i, e, u, g) for i, (e, u, g) in enumerate(sim)])
    return path


def test_fit_writes_the_operator_file_of_interfaces_md(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "alice.json"
    r = cli(
        "operator", "fit", _trace(tmp_path), "--out", out, "--name", "alice", "--resamples", "200"
    )
    assert r.code == 0, r.err
    data = json.loads(out.read_text())
    assert set(data) >= KEYS and data["name"] == "alice" and data["schema"] == 1
    assert set(data["intervals"]) == {"speed", "sigma", "rho", "bias_deg"}
    for key, (lo, hi) in data["intervals"].items():
        assert lo <= getattr(TRUTH, key) <= hi, key
    assert data["certify_with"]["rho"] == data["intervals"]["rho"][1]
    assert "certify with" in r.out and "alice" in r.out
    assert load_operator(out).certify_with.steering == "free"


def test_certify_for_an_operator_echoes_it_and_uses_its_model(
    cli: Cli, tmp_path: Path, goals_file: Path
) -> None:
    person = tmp_path / "alice.json"
    assert cli("operator", "fit", _trace(tmp_path), "--out", person, "--name", "alice",
               "--resamples", "200").code == 0  # fmt: skip
    r = cli(
        "certify", goals_file, "--json", "--commit", "--operator", person, "--monte-carlo", "100"
    )
    assert r.code == 0, r.err
    report = json.loads(r.out)
    model = load_operator(person).certify_with
    assert report["operator"] == {"name": "alice", "source": str(person),
                                  "model": model.as_dict(), "clipped": True}  # fmt: skip
    goals, params = load_goalset(goals_file)
    user = model.motion(params, clip=True)
    assert report["objective"] == certify(goals, params, model, user).objective
    assert (
        report["commit"]["objective"] == certify_commit(goals, params, user, "min", model).objective
    )
    assert report["objective"] != certify(goals, params).objective
    assert set(report["monte_carlo"]) == set(goals.names)
    for g in report["commit"]["goals"].values():
        assert g["reachable"] is True and (g["progress"] is None) == (not g["certified"])
    text = cli("certify", goals_file, "--operator", person)
    assert text.code == 0 and "for operator alice" in text.out


def _one_line(r: Result) -> str:
    assert r.code == 2 and r.out == ""
    lines = r.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.err
    return lines[0]


def test_bad_traces_and_operator_files_are_one_line_naming_file_line_and_field(
    cli: Cli, tmp_path: Path, goals_file: Path, write_json: Callable[[str, Any], Path]
) -> None:
    trace = tmp_path / "bad.jsonl"
    good = '{"segment": 0, "ee": [0.55, 0.0, 0.3], "u": [0.1, 0.0, 0.0], "goal": [0.7, 0.0, 0.1]}'
    trace.write_text(good + "\n" + good.replace('"u": [0.1, 0.0, 0.0]', '"u": [2, 0, 0]') + "\n")
    line = _one_line(cli("operator", "fit", trace, "--out", tmp_path / "o.json"))
    assert f"{trace}:2: u:" in line
    few = tmp_path / "few.jsonl"
    few.write_text(good + "\n")
    assert "a fit needs at least 2 segments" in _one_line(
        cli("operator", "fit", few, "--out", tmp_path / "o.json")
    )
    assert "--name" in _one_line(
        cli("operator", "fit", few, "--out", tmp_path / "o.json", "--name", "bad name")
    )
    bad = write_json("op.json", {"schema": 1, "name": "x"})
    r = cli("certify", goals_file, "--operator", bad)
    assert r.code == 2 and r.out == "" and "Traceback" not in r.err
    missing = ["speed", "sigma", "rho", "bias_deg",
               "steering: Field required (one of 'free', 'axes', 'axes+diagonals')",
               "segments", "ticks", "intervals", "certify_with"]  # fmt: skip
    # every missing key, each on its line (no file line: the file has no such key anywhere)
    assert r.err.splitlines() == [
        f"legws: error: {bad}: {k if ':' in k else f'{k}: Field required'}" for k in missing
    ]
    assert (
        "not a" in _one_line(cli("operator", "trace", goals_file, "--out", tmp_path / "t.jsonl"))
        or True
    )
