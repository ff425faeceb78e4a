"""Whole simulated studies on the stand-in: the planted effect comes back out of the analysis,
the data a lab publishes are written and read back, task graphs and personal layouts run."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from legws_daemon.cli.main import run
from legws_daemon.formats.operator_file import load_operator
from legws_daemon.study.population import load_population
from legws_daemon.study.protocol import load_protocol
from legws_daemon.study.schedule import make_schedule
from legws_daemon.study.simulate import simulate_study
from legws_daemon.study.table import COLUMNS, read_table

DATA = Path(__file__).parent / "data"
pytestmark = pytest.mark.slow


def _protocol(tmp_path: Path, name: str, body: str) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(
        f'schema_version = 1\nname = "{name}"\ntitle = "t"\nseed = 2\n{body}', encoding="utf-8"
    )
    return path


@pytest.fixture(scope="module")
def twin(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two identical conditions on one layout; the population plants +3 s of hesitation, +12
    TLX points and -1 Likert point on 'late'."""
    out = tmp_path_factory.mktemp("twin") / "study"
    code = run(["study", "run", str(DATA / "twin.toml"), "--simulate",
                str(DATA / "planted.toml"), "--participants", "6", "--out", str(out)])  # fmt: skip
    assert code == 0
    return out


def test_the_analysis_recovers_the_planted_effect_within_its_interval(
    twin: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    report = tmp_path / "report"
    capsys.readouterr()
    assert run(["study", "analyze", str(twin), "--out", str(report), "--power-sims", "10"]) == 0
    printed = capsys.readouterr().out
    assert "time to task, late vs early: +" in printed
    results = json.loads((report / "results.json").read_text())
    late = results["models"]["time_to_task_s"]["conditions"]["late"]
    assert late["low"] < 3.0 < late["high"] and late["p"] < 0.001
    # the commit time counts from the first push: the hesitation does not reach it
    commit = results["models"]["commit_time_s"]["conditions"]["late"]
    assert commit["low"] < 0.0 < commit["high"] or abs(commit["estimate"]) < 0.5
    tlx = results["models"]["tlx_raw"]["conditions"]["late"]
    assert tlx["low"] < 12.0 < tlx["high"]
    likert = results["models"]["likert"]["conditions"]["late"]
    assert likert["low"] < -1.0 < likert["high"]
    assert results["participants"] == 6 and results["trials"] == 48
    assert set(results["power"]["curves"]["late"]) == {str(n) for n in range(2, 17, 2)}
    md = (report / "report.md").read_text()
    assert "late vs early" in md and "![time to task" in md
    page = (report / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 3 and "<table>" in page
    assert (report / "figures" / "power.png").stat().st_size > 1000


def test_the_published_data_are_written_and_read_back(twin: Path) -> None:
    schedule = json.loads((twin / "schedule.json").read_text())
    assert set(schedule["participants"]) == {f"P0{k}" for k in range(1, 7)}
    rows = read_table(twin / "trials.parquet")
    assert len(rows) == 48 and {r["kind"] for r in rows} == {"trial"}
    assert all(r["completed"] and r["correct"] and r["failure"] == "" for r in rows)
    with (twin / "trials.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [r["participant"] for r in table] == [r["participant"] for r in rows]
    assert float(table[0]["time_to_task_s"]) == pytest.approx(rows[0]["time_to_task_s"])
    names = {c.name for c in COLUMNS}
    assert names <= set(rows[0]) and {"tlx_raw", "likert_1", "likert_2"} <= set(rows[0])
    dictionary = json.loads((twin / "data_dictionary.json").read_text())
    assert [e["name"] for e in dictionary] == list(rows[0])
    assert any("Likert item 1" in e["meaning"] and "one" in e["meaning"] for e in dictionary)
    for person in schedule["participants"]:
        folder = twin / person
        op = load_operator(folder / "operator.json")
        assert op.name == person and op.segments == 12  # the population's 12 reaches
        assert (folder / "calibration.trace.jsonl").stat().st_size > 0
        own = read_table(folder / "trials.parquet")
        assert {r["participant"] for r in own} == {person} and len(own) == 8
        # the certificates for the person are their fitted model's, not section 2's user's
        assert all(r["person_slack_j"] is not None for r in own)
        answers = json.loads((folder / "questionnaires.json").read_text())["answers"]
        assert set(answers) == {"early", "late"}


def test_a_task_graph_trial_takes_the_objects_asked_for(tmp_path: Path) -> None:
    path = _protocol(tmp_path, "teas", """
[design]
counterbalance = "fixed"
trials_per_condition = 2
calibrate = false
[tasks.tea]
taskgraph = "tea"
[[conditions]]
name = "random"
task = "tea"
layout = "random"
assist = "blend"
""")  # fmt: skip
    p = load_protocol(path)
    rows = simulate_study(p, make_schedule(p, 1), load_population("lab"), tmp_path / "out")
    assert len(rows) == 2
    for r in rows:
        assert r["completed"] and r["correct"], r
        assert r["chosen"] == r["targets"] and len(r["targets"].split(";")) == 2
        assert r["decisions"] == 2  # the tea, the snack (cup and plate: one candidate each)
        assert 0 < r["time_to_grasp_s"] < r["time_to_task_s"]
        assert r["person_slack_j"] is None  # no calibration: no operator file
        assert r["layout_origin"].startswith("seed ")
    assert rows[0]["layout"] != rows[1]["layout"]  # a new random layout each trial


def test_a_personal_layout_is_designed_for_the_fitted_operator(tmp_path: Path) -> None:
    path = _protocol(tmp_path, "mine", """
[design]
counterbalance = "fixed"
trials_per_condition = 1
[tasks.pick]
scene = "breakfast_easy"
[[conditions]]
name = "personal"
task = "pick"
layout = "optimised_for_operator"
iterations = 20
""")  # fmt: skip
    p = load_protocol(path)
    out = tmp_path / "out"
    rows = simulate_study(p, make_schedule(p, 2), load_population("lab"), out)
    assert [r["participant"] for r in rows] == ["P01", "P02"]
    for person in ("P01", "P02"):
        summary = json.loads(
            (out / "layouts" / f"pick-slack-{person}" / "summary.json").read_text()
        )
        assert summary["design_for"] == person and summary["iterations"] == 20
        fitted = load_operator(out / person / "operator.json").certify_with.as_dict()
        assert summary["operators"][0]["model"] == fitted


def test_a_population_that_plants_an_effect_for_no_condition_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    code = run(["study", "run", "assist_policies", "--simulate", str(DATA / "planted.toml"),
                "--participants", "4", "--out", str(tmp_path / "o")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "effects.late: a planted effect for 'late'" in err
    assert not (tmp_path / "o").exists()
