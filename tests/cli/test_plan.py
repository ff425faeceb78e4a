"""`legws plan`: the table, --json, --out, the cache, and one-line errors."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from PIL import Image

from legws_daemon.scene.catalog import load_scene
from legws_daemon.task.plan_file import load_plan
from tests.cli.helpers import Result, assert_bad_input

Cli = Callable[..., Result]


@pytest.fixture(autouse=True)
def own_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


@pytest.mark.slow  # plans the feeding graph and renders its decisions: ~12 s
def test_table_files_and_cache(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["plan", "feeding", "--iterations", "5", "--quiet"]
    first = cli(*args, "--out", out)
    assert first.code == 0, first.err
    lines = first.out.splitlines()
    assert lines[0].startswith(
        "plan of 'feeding' (scene feeding; cma-me for slack, 5 iterations, seed 0;"
    )
    assert f"in {out}" in lines[0]
    rows = {ln.split()[0]: ln for ln in lines[4:] if ln.strip()}
    assert set(rows) == {"choose_food", "dip|feed", "feed"}
    assert "no inference needed" in rows["feed"]
    assert "(not optimised)" in rows["dip|feed"]
    assert " -> " in rows["choose_food"] and "strawberry, grape, brownie" in rows["choose_food"]
    assert all(" yes " in r for r in rows.values())
    assert sorted(p.name for p in out.iterdir()) == [
        "choose_food.png", "dip+feed.png", "feed.png", "plan.json",
    ]  # fmt: skip
    plan = load_plan(out / "plan.json", load_scene("feeding"))
    assert plan.settings["iterations"] == 5
    with Image.open(out / "dip+feed.png") as img:
        assert img.size == (800, 600)
    second = cli(*args, "--json")
    assert second.code == 0, second.err
    data = json.loads(second.out)
    assert data["cached"] is True
    assert data["key"] == plan.key
    assert Path(data["directory"]).parent.name == "plan"
    assert [d["label"] for d in data["decisions"]] == ["choose_food", "dip|feed", "feed"]
    assert data["decisions"][2]["certificate"] is None


def test_no_cache_without_out_writes_to_out_plan(
    cli: Cli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    r = cli("plan", "feeding", "--iterations", "3", "--quiet", "--no-cache", "--json")
    assert r.code == 0, r.err
    data = json.loads(r.out)
    assert data["cached"] is False
    assert Path(data["directory"]) == Path("out") / "plan" / "feeding"
    assert (tmp_path / "out" / "plan" / "feeding" / "plan.json").is_file()
    assert not (tmp_path / "cache").exists()


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["nope"], ["unknown task graph 'nope'", "known: feeding, lego, tea"]),
        (["missing.toml"], ["missing.toml", "no such file"]),
        (["feeding", "--method", "random"], ["'random' is not one of", "cma-me"]),
        (["feeding", "--iterations", "0"], ["--iterations", "0"]),
    ],
)
def test_bad_input_is_one_line(cli: Cli, args: list[str], needles: list[str]) -> None:
    assert_bad_input(cli("plan", *args, "--quiet"), *needles)


def test_malformed_graph_names_line_and_field(cli: Cli, tmp_path: Path) -> None:
    text = (Path(__file__).parents[2] / "taskgraphs" / "feeding.toml").read_text()
    bad = tmp_path / "feeding.toml"
    bad.write_text(text.replace('"grape", "brownie"]', '"grape", "teapot"]'))
    assert_bad_input(cli("plan", bad, "--quiet"), f"{bad}:15:", "stages[0].candidates[2]",
                     "unknown object or place 'teapot'")  # fmt: skip


def test_out_under_a_file_is_one_line(cli: Cli, tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    r = cli("plan", "feeding", "--iterations", "3", "--quiet", "--out", blocker / "out")
    assert_bad_input(r, f"{blocker / 'out'}: cannot create the folder: ")
