"""`legws taskgraph check|show`: summaries, the tree, the diagram, one-line errors."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from legws_daemon.task.diagram import CHOICE, REPEAT
from tests.cli.helpers import Result, assert_bad_input

Cli = Callable[..., Result]
GRAPHS = Path(__file__).parents[2] / "taskgraphs"


@pytest.mark.parametrize(
    ("name", "summary"),
    [
        ("tea", "4 stages, 4 decision points (2 with inference, 0 choices), 1 path, scene tea"),
        ("lego", "2 stages, 2 decision points (2 with inference, 0 choices), 1 path, scene "
                 "lego, repeats until consumed"),
        ("feeding", "3 stages, 3 decision points (2 with inference, 1 choice), 2 paths, "
                    "scene feeding"),
    ],
)  # fmt: skip
def test_check_shipped_graphs(cli: Cli, name: str, summary: str) -> None:
    r = cli("taskgraph", "check", name)
    assert r.code == 0, r.err
    assert r.out == f"{GRAPHS / name}.toml: ok: {summary}\n"
    assert r.err == ""


@pytest.mark.parametrize(
    ("old", "new", "needles"),
    [
        (
            'next = ["feed"]',
            'next = ["choose_food"]',
            [":24:", "stages[1].next", "cycle choose_food -> dip"],
        ),
        ('"grape", "brownie"]', '"grape", "teapot"]', [":15:", "unknown object or place"]),
        ('action = "feed"', "action = feed", ["invalid TOML"]),
        ('action = "pick"', 'action = "place"', [":16:", "the gripper holds nothing"]),
    ],
)
def test_check_malformed_graph_is_one_line(
    cli: Cli, tmp_path: Path, old: str, new: str, needles: list[str]
) -> None:
    text = (GRAPHS / "feeding.toml").read_text()
    assert old in text
    bad = tmp_path / "feeding.toml"
    bad.write_text(text.replace(old, new, 1))
    assert_bad_input(cli("taskgraph", "check", bad), str(bad), *needles)


def test_check_unknown_name_and_missing_file(cli: Cli, tmp_path: Path) -> None:
    assert_bad_input(cli("taskgraph", "check", "nope"), "known: feeding, lego, tea")
    assert_bad_input(cli("taskgraph", "check", tmp_path / "x.toml"), "no such file")


def test_show_feeding_marks_choice_and_single_candidates(cli: Cli) -> None:
    r = cli("taskgraph", "show", "feeding")
    assert r.code == 0, r.err
    lines = r.out.splitlines()
    assert lines[0].startswith("task graph 'feeding'")
    assert "fixed objects: chocolate_bowl, sprinkles_bowl" in lines[0]
    body = "\n".join(lines[lines.index("") + 1 :])
    assert body == (
        'choose_food: pick {strawberry, grape, brownie} "Which food?"\n'
        "└─ choice: dip | feed (the daemon infers over their 3 candidates; the commit picks "
        "the branch)\n"
        '   ├─ dip: dip {chocolate_bowl (fixed), sprinkles_bowl (fixed)} "Chocolate or '
        'sprinkles?"\n'
        '   │  └─ feed: feed {mouth} "To the mouth"  [no inference]\n'
        "   └─ feed (shown above)"
    )


def test_show_lego_notes_the_repeat(cli: Cli) -> None:
    r = cli("taskgraph", "show", "lego")
    assert r.code == 0, r.err
    assert "repeat until_consumed" in r.out
    assert r.out.rstrip().endswith("└─ repeat from pick_brick while it has candidates left")


def _has(img: Image.Image, colour: tuple[int, int, int]) -> bool:
    arr = np.asarray(img.convert("RGB")).reshape(-1, 3)
    return bool(np.any(np.all(arr == np.array(colour), axis=1)))


@pytest.mark.parametrize(
    ("name", "choice", "repeat"),
    [("feeding", True, False), ("lego", False, True), ("tea", False, False)],
)
def test_show_png_draws_the_diagram(
    cli: Cli, tmp_path: Path, name: str, choice: bool, repeat: bool
) -> None:
    out = tmp_path / "pics" / f"{name}.png"
    r = cli("taskgraph", "show", name, "--png", out)
    assert r.code == 0, r.err
    assert r.out.rstrip().endswith(f"wrote {out}")
    with Image.open(out) as img:
        assert img.format == "PNG"
        stages = {"feeding": 3, "lego": 2, "tea": 4}[name]
        assert img.width >= stages * 250  # one column of boxes per stage in these graphs
        assert 150 <= img.height <= 600
        assert _has(img, CHOICE) is choice  # a choice's arrows and box outline are orange
        assert _has(img, REPEAT) is repeat  # the repeat arrow is blue
    assert [p.name for p in out.parent.iterdir()] == [f"{name}.png"]  # no temporary left


def test_show_png_into_an_impossible_place_is_one_line(cli: Cli, tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    r = cli("taskgraph", "show", "tea", "--png", blocker / "x.png")
    assert_bad_input(r, f"{blocker}: is a regular file, expected a folder to write into")
