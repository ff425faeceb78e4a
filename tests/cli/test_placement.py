"""`legws placement`: the files of a layout and of a plan, the warnings, one-line errors."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pdfplumber
import pytest

from legws_daemon.scene.catalog import scenes_dir
from tests.cli.helpers import Result, assert_bad_input

Cli = Callable[..., Result]


@pytest.fixture(autouse=True)
def own_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def _pages(path: Path) -> int:
    with pdfplumber.open(path) as pdf:
        return len(pdf.pages)


def test_one_layout_writes_the_mat_its_preview_and_the_marker_sheet(
    cli: Cli, tmp_path: Path
) -> None:
    layout = tmp_path / "turned.json"
    layout.write_text(json.dumps({"black_tea": {"x": 0.7, "y": 0.3, "yaw": 0.5}}))
    out = tmp_path / "mats"
    r = cli("placement", "tea", "--layout", layout, "--out", out, "--paper", "a3")
    assert r.code == 0, r.err
    assert r.err == ""
    assert r.out.splitlines() == [
        f"wrote {out / 'layout.pdf'} (9 A3 pages, landscape: 3 rows x 3 columns)",
        f"wrote {out / 'layout.png'} (preview)",
        f"wrote {out / 'markers.pdf'} (8 object markers to cut out)",
    ]
    assert _pages(out / "layout.pdf") == 9
    with pdfplumber.open(out / "layout.pdf") as pdf:
        assert "layout turned.json" in pdf.pages[0].extract_text()
    assert (out / "layout.png").read_bytes().startswith(b"\x89PNG")


def test_a_scene_without_markers_writes_no_marker_sheet(cli: Cli, tmp_path: Path) -> None:
    r = cli("placement", "feeding", "--layout", "default", "--out", tmp_path, "--paper", "a3")
    assert r.code == 0, r.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["layout.pdf", "layout.png"]


def test_a_table_marker_across_a_cut_is_warned_about_in_one_line(cli: Cli, tmp_path: Path) -> None:
    text = (scenes_dir() / "tea.toml").read_text(encoding="utf-8")
    moved = text.replace("{ id = 0, size = 0.07, x = 0.245, y = 0.51 }",
                         "{ id = 0, size = 0.07, x = 0.245, y = 0.188 }")  # fmt: skip
    assert moved != text
    scene = tmp_path / "tea.toml"
    scene.write_text(moved, encoding="utf-8")
    # on A3 the first cut is 376 mm from the sheet's left, the table's +y edge 14 mm
    r = cli("placement", scene, "--layout", "default", "--out", tmp_path / "out", "--paper", "a3")
    assert r.code == 0, r.err
    assert r.err == (
        "legws: warning: table marker 0 lies across the cut between pages 7, 8: tape it "
        "flat and exact, or print on --paper a3\n"
    )


def test_a_task_graph_without_a_cached_plan_says_how_to_make_one(cli: Cli, tmp_path: Path) -> None:
    r = cli("placement", "tea", "--out", tmp_path / "out")
    assert_bad_input(r, "no cached plan of task graph 'tea'", "legws plan tea", "--layout")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["nope", "--layout", "default"], ["unknown scene 'nope'", "tea"]),
        (["nope"], ["unknown task graph 'nope'"]),
        (["cluttered"], ["'cluttered' is a scene, not a task graph", "--layout"]),
        (["tea", "--layout", "missing.json"], ["missing.json", "no such file"]),
        (["tea", "--layout", "default", "--plan", "x"], ["--layout and --plan exclude"]),
        (["tea", "--plan", "missing"], ["missing", "no such file"]),
        (["tea", "--layout", "default", "--paper", "a5"], ["a5"]),
    ],
)
def test_bad_input_is_one_line(
    cli: Cli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], needles: list[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert_bad_input(cli("placement", *args, "--out", tmp_path / "out"), *needles)


@pytest.mark.parametrize(
    ("content", "needles"),
    [
        ("{not json", ["bad.json"]),
        ('{"teapot": {"x": 0.5, "y": 0.0}}', ["bad.json", "unknown object 'teapot'"]),
        ('{"cup": {"x": 0.5, "y": 0.0}}', ["bad.json", "'cup' is fixed"]),
    ],
)
def test_a_bad_layout_file_is_one_line(
    cli: Cli, tmp_path: Path, content: str, needles: list[str]
) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    r = cli("placement", "tea", "--layout", bad, "--out", tmp_path / "out")
    assert_bad_input(r, *needles)


def test_out_pointing_at_a_file_is_one_line_and_leaves_it(cli: Cli, tmp_path: Path) -> None:
    target = tmp_path / "a-file"
    target.write_text("keep me")
    r = cli("placement", "tea", "--layout", "default", "--out", target)
    assert_bad_input(r, "a-file", "expected a folder")
    assert target.read_text() == "keep me"


@pytest.mark.slow  # plans the tea graph (a few iterations) and draws its four decisions: ~25 s
def test_a_plan_gives_one_mat_per_decision(cli: Cli, tmp_path: Path) -> None:
    plan = tmp_path / "plan"
    made = cli("plan", "tea", "--iterations", "3", "--quiet", "--no-cache", "--out", plan)
    assert made.code == 0, made.err
    out = tmp_path / "mats"
    r = cli("placement", "tea", "--plan", plan, "--out", out, "--paper", "a3")
    assert r.code == 0, r.err
    stems = ["01-choose_tea", "02-steep", "03-choose_snack", "04-serve"]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{s}.{ext}" for s in stems for ext in ("pdf", "png")] + ["markers.pdf"]
    )
    assert [ln.split()[1] for ln in r.out.splitlines()] == [
        *(str(out / f"{s}.{ext}") for s in stems for ext in ("pdf", "png")),
        str(out / "markers.pdf"),
    ]
    data = json.loads((plan / "plan.json").read_text())
    with pdfplumber.open(out / "01-choose_tea.pdf") as pdf:
        text = pdf.pages[0].extract_text()
    j = data["decisions"][0]["certificate"]
    assert "decision choose_tea" in text and f"J = {j:.3f}" in text
