"""Plans are held to the rule of ``--layout`` when they are loaded: every stage layout must
meet the scene's constraints, and the certificates it records must be the ones its layout
gives. A cached plan (``--plan auto``) that does not is logged, planned again and replaced;
an explicit ``--plan DIR`` is refused with one line; the daemon's catalog (``plan: "auto"``)
refuses and says how to plan it again."""

from __future__ import annotations

import copy
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import pytest
import zenoh

from legws_daemon.cli import daemon as daemon_cli
from legws_daemon.cli.main import run
from legws_daemon.daemon import service
from legws_daemon.design.plan_cache import PLAN_FILE, plan_cache_dir, plan_key
from legws_daemon.design.stage_plan import cached_plan, plan_settings, plan_taskgraph
from legws_daemon.errors import InputError
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.plan_file import check_plan, load_plan, plan_to_data
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from tests.design.test_stage_plan import counting_search

GRAPHS = ("tea", "lego", "feeding")
#: Real plans, quickly: map-elites needs no JIT compilation (cma-me's takes ~10 s).
QUICK: dict[str, Any] = {"method": "map-elites", "iterations": 3, "render": False}


def load(name: str) -> tuple[TaskGraph, Scene]:
    return load_taskgraph(resolve_taskgraph(name))


@pytest.fixture(scope="module")
def plans() -> dict[str, Plan]:
    """A plan of every shipped graph, made by ``legws plan``'s planner (not cached)."""
    return {name: plan_taskgraph(*load(name), use_cache=False, **QUICK) for name in GRAPHS}


# --- tampering: (graph, what is done to plan.json, the field and words of the error) ----------
Data = dict[str, Any]


def _closer(data: Data) -> None:
    """green_tea 1 cm from black_tea, in every decision (as a consistent edit would)."""
    for d in data["decisions"]:
        black = d["layout"]["black_tea"]
        d["layout"]["green_tea"] = {**black, "x": black["x"] + 0.01}


def _off_the_table(data: Data) -> None:
    """The cookie at x = 1.0 m (the tea table ends at 0.85) where it is placed, and after."""
    for d in data["decisions"][2:]:
        d["layout"]["cookie"] = {**d["layout"]["cookie"], "x": 1.0}


def _certificate(data: Data) -> None:
    data["decisions"][0]["certificate"] += 0.25


def _add(path: tuple[Any, ...], delta: float) -> Callable[[Data], None]:
    def edit(data: Data) -> None:
        node = data
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] += delta

    return edit


def _set(path: tuple[Any, ...], value: Any) -> Callable[[Data], None]:
    def edit(data: Data) -> None:
        node = data
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value

    return edit


def _drop_last(data: Data) -> None:
    del data["decisions"][-1]


#: name -> (graph, tampering, field after the file name, words the message holds)
TAMPERED: dict[str, tuple[str, Callable[[Data], None], str, list[str]]] = {
    "two objects 1 cm apart": ("tea", _closer, "decisions[0].layout", [
        "stage 'choose_tea'", "infeasible layout",
        "black_tea and green_tea are 0.010 m apart (< 0.12)"]),
    "an object off the table": ("tea", _off_the_table, "decisions[2].layout", [
        "stage 'choose_snack'", "infeasible layout", "cookie at (1.000,",
        "outside x 0.3..0.85"]),
    "a certificate changed": ("tea", _certificate, "decisions[0].certificate", [
        "stage 'choose_tea'", "certificate is recorded as", "but the layout gives"]),
    "the start certificate changed": (
        "tea", _add(("decisions", 2, "certificate_start"), -0.1),
        "decisions[2].certificate_start", ["stage 'choose_snack'", "certificate_start"]),
    "K changed": ("lego", _add(("decisions", 1, "commit_objective"), 0.05),
                  "decisions[1].commit_objective", ["stage 'sort'", "commit_objective"]),
    "R changed": ("feeding", _set(("decisions", 0, "commit_rate_estimate"), 0.0),
                  "decisions[0].commit_rate_estimate", ["stage 'choose_food'"]),
    "an object moved where it is not placed": (
        "tea", _add(("decisions", 1, "layout", "black_tea", "x"), 0.002),
        "decisions[1].layout.black_tea",
        ["stage 'steep'", "'black_tea' is not placed at this stage",
         "(after stage 'choose_tea')"]),
    "an object fixed by the graph placed": (
        "feeding", _set(("decisions", 1, "optimised"), ["chocolate_bowl"]),
        "decisions[1].optimised", ["stage 'dip|feed'", "'chocolate_bowl' is fixed"]),
    "a decision missing": ("tea", _drop_last, "decisions", ["no layout for stage 'serve'"]),
    "the candidates changed": (
        "lego", _set(("decisions", 1, "actions", "bin_a"), "pick"),
        "decisions[1].actions", ["stage 'sort'", "expected the task graph's candidates"]),
    "other model parameters": ("feeding", _set(("settings", "params", "beta"), -1.0),
                               "settings.params.beta", ["expected a number in"]),
}  # fmt: skip


def tampered(plan: Plan, edit: Callable[[Data], None]) -> Data:
    data = copy.deepcopy(plan_to_data(plan))
    edit(data)
    return data


def write_plan(folder: Path, data: Data) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / PLAN_FILE
    path.write_text(json.dumps(data))
    return path


def one_line(text: str) -> str:
    assert "\n" not in text.rstrip("\n"), text
    return text.strip()


# --- the planner's plans pass; every tampering is found, named and explained ------------------
@pytest.mark.parametrize("name", GRAPHS)
def test_planned_plans_pass_and_reload_passes(
    plans: dict[str, Plan], name: str, tmp_path: Path
) -> None:
    graph, sc = load(name)
    assert check_plan(plans[name], graph, sc, "plan.json") is plans[name]
    path = write_plan(tmp_path, plan_to_data(plans[name]))
    assert check_plan(load_plan(path, sc), graph, sc, str(path)) == plans[name]


@pytest.mark.parametrize("case", list(TAMPERED))
def test_a_tampered_plan_is_refused_naming_file_stage_and_check(
    plans: dict[str, Plan], case: str, tmp_path: Path
) -> None:
    name, edit, field, words = TAMPERED[case]
    graph, sc = load(name)
    path = write_plan(tmp_path, tampered(plans[name], edit))
    plan = load_plan(path, sc)  # the schema is met: only the check against the scene fails
    with pytest.raises(InputError) as info:
        check_plan(plan, graph, sc, str(path))
    text = one_line(str(info.value))
    assert text.startswith(f"{path}: {field}: "), text
    for w in words:
        assert w in text, text


def test_another_graphs_plan_is_refused(plans: dict[str, Plan]) -> None:
    graph, sc = load("tea")
    with pytest.raises(InputError, match="taskgraph: the plan is for task graph 'lego'"):
        check_plan(plans["lego"], graph, sc, "plan.json")


# --- an explicit plan folder: --plan DIR ------------------------------------------------------
@pytest.mark.parametrize("case", ["two objects 1 cm apart", "an object off the table",
                                  "a certificate changed"])  # fmt: skip
def test_explicit_plan_folder_is_refused(plans: dict[str, Plan], case: str, tmp_path: Path) -> None:
    name, edit, field, words = TAMPERED[case]
    graph, sc = load(name)
    path = write_plan(tmp_path / "plan", tampered(plans[name], edit))
    with pytest.raises(InputError) as info:
        daemon_cli._load_plan(str(tmp_path / "plan"), graph, sc)
    text = one_line(str(info.value))
    assert text.startswith(f"{path}:1: {field}: stage '"), text  # the line of the field
    assert words[0] in text and words[-1] in text
    good = write_plan(tmp_path / "good", plan_to_data(plans[name]))
    assert daemon_cli._load_plan(str(good), graph, sc) == plans[name]  # the file itself too


class _NoDaemon:
    """Stands in for the daemon service: records its configuration, opens no session."""

    started: ClassVar[list[Any]] = []

    def __init__(self, config: Any) -> None:
        self.config = config

    def run(self, stop: Any) -> int:
        _NoDaemon.started.append(self.config)
        return 0


@pytest.fixture
def no_daemon(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """``legws daemon`` in-process up to the point where it would start: no network session,
    no signal handlers; the list holds the configuration of each start."""

    def no_session(*_: Any, **__: Any) -> Any:
        raise AssertionError("a network session was opened")

    _NoDaemon.started = []
    monkeypatch.setattr(service, "DaemonService", _NoDaemon)
    monkeypatch.setattr(service, "open_session", no_session)
    monkeypatch.setattr(zenoh, "open", no_session)
    monkeypatch.setattr(daemon_cli, "install_stop_handlers", lambda stop: None)
    return _NoDaemon.started


def test_cli_refuses_a_tampered_plan_folder_in_one_line(
    plans: dict[str, Plan],
    tmp_path: Path,
    no_daemon: list[Any],
    capsys: pytest.CaptureFixture[str],
) -> None:
    _, edit, _, words = TAMPERED["two objects 1 cm apart"]
    folder = tmp_path / "plan"
    path = write_plan(folder, tampered(plans["tea"], edit))
    argv = ["daemon", "--taskgraph", "tea", "--plan", str(folder), "--duration", "0.1"]
    capsys.readouterr()
    assert run(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1, err
    assert err.startswith(f"legws: error: {path}:1: decisions[0].layout: stage 'choose_tea': ")
    assert words[-1] in err
    assert no_daemon == []  # refused before the daemon (and its session) started
    # the same plan untampered starts the daemon with it
    write_plan(folder, plan_to_data(plans["tea"]))
    assert run(argv) == 0, capsys.readouterr().err
    assert len(no_daemon) == 1 and no_daemon[0].plan == plans["tea"]


# --- the cache: --plan auto and plan_taskgraph ------------------------------------------------


@pytest.mark.parametrize("case", ["two objects 1 cm apart", "an object off the table",
                                  "a certificate changed"])  # fmt: skip
def test_a_tampered_cached_plan_is_logged_planned_again_and_replaced(
    case: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    calls = counting_search(monkeypatch)
    name, edit, field, words = TAMPERED[case]
    graph, sc = load(name)
    first = plan_taskgraph(graph, sc, **QUICK)
    folder = first.directory
    assert folder is not None and folder.parent == plan_cache_dir()
    assert plan_taskgraph(graph, sc, **QUICK).cached  # intact: used as it is
    searches = len(calls)

    bad = tampered(first, edit)
    write_plan(folder, bad)
    with caplog.at_level(logging.WARNING, logger="legws.plan"):
        again = plan_taskgraph(graph, sc, **QUICK)
    warnings = [r.getMessage() for r in caplog.records if r.name == "legws.plan"]
    assert len(warnings) == 1, warnings
    text = one_line(warnings[0])
    assert text.startswith(f"legws: warning: the cached plan in {folder} is not usable ("), text
    assert f"{folder / PLAN_FILE}: {field}: {words[0]}" in text and words[-1] in text
    assert text.endswith("planning again")
    # planned again (the tampered plan is not used) and replaced by a valid entry
    assert len(calls) > searches and not again.cached
    assert plan_to_data(again) != bad
    assert again.decisions == first.decisions  # seeded: the plan before the tampering
    check_plan(again, graph, sc, "plan.json")
    assert load_plan(folder / PLAN_FILE) == again
    caplog.clear()
    reloaded = plan_taskgraph(graph, sc, **QUICK)
    assert reloaded.cached and reloaded == again and not caplog.records


def _default_key_folder(plan: Plan, graph: TaskGraph, sc: Scene, data: Data) -> Path:
    """Write ``data`` where ``cached_plan`` (the default settings) looks for the graph's plan."""
    key = plan_key(graph, sc, plan_settings())
    folder = plan_cache_dir() / key
    write_plan(folder, {**data, "key": key})
    return folder


def test_the_daemons_catalog_refuses_a_tampered_cached_plan_and_says_how_to_replan(
    plans: dict[str, Plan], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    calls = counting_search(monkeypatch)
    graph, sc = load("tea")
    _, edit, _, words = TAMPERED["two objects 1 cm apart"]
    folder = _default_key_folder(plans["tea"], graph, sc, tampered(plans["tea"], edit))
    with pytest.raises(InputError) as info:
        daemon_cli.cached_catalog_plan(graph, sc)
    text = one_line(str(info.value))
    assert text.startswith("plan: the cached plan of task graph 'tea' is not usable (")
    assert f"{folder / PLAN_FILE}: decisions[0].layout: stage 'choose_tea'" in text
    assert words[-1] in text
    assert "plan it again with `legws plan tea`" in text
    assert calls == []  # nothing is planned on the daemon's loop
    _default_key_folder(plans["tea"], graph, sc, plan_to_data(plans["tea"]))
    plan = daemon_cli.cached_catalog_plan(graph, sc)
    assert plan.cached and plan.decisions == plans["tea"].decisions
    assert cached_plan(graph, sc) == plan


def test_explicit_plan_of_another_graph_is_still_named_as_such(
    plans: dict[str, Plan], tmp_path: Path
) -> None:
    graph, sc = load("lego")
    write_plan(tmp_path, plan_to_data(plans["lego"]))
    data = {**plan_to_data(plans["lego"]), "taskgraph": "tea"}
    write_plan(tmp_path, data)
    with pytest.raises(InputError, match="--plan: the plan is for task graph 'tea', not 'lego'"):
        daemon_cli._load_plan(str(tmp_path), graph, sc)


@pytest.mark.slow  # `--plan auto` plans again with the default settings: cma-me, ~30 s
def test_daemon_plan_auto_replans_a_tampered_cache_and_starts_with_the_new_plan(
    plans: dict[str, Plan],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    no_daemon: list[Any],
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The red-team case: tea bags 1 cm apart in the cached plan `--plan auto` takes."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    graph, sc = load("tea")
    _, edit, _, words = TAMPERED["two objects 1 cm apart"]
    folder = _default_key_folder(plans["tea"], graph, sc, tampered(plans["tea"], edit))
    capsys.readouterr()
    code = run(["daemon", "--taskgraph", "tea", "--plan", "auto", "--duration", "0.1"])
    err = capsys.readouterr().err  # the daemon logs to stderr
    assert code == 0, err
    warnings = [line for line in err.splitlines() if "legws: warning: the cached plan" in line]
    assert len(warnings) == 1, err
    assert f"in {folder} is not usable ({folder / PLAN_FILE}: decisions[0].layout: " in warnings[0]
    assert "stage 'choose_tea'" in warnings[0] and words[-1] in warnings[0]
    assert len(no_daemon) == 1
    used = no_daemon[0].plan
    assert not used.cached and used.directory == folder
    assert used.settings == plan_settings()  # planned anew with `legws plan tea`'s settings
    check_plan(used, graph, sc, "plan.json")
    assert load_plan(folder / PLAN_FILE) == used  # the cache entry is replaced
