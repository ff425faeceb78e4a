"""`legws placement`: the files of a layout and of a plan, the warnings, one-line errors;
the tea plan's mats read back (pages, labels, the preview)."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import pdfplumber
import pytest

from legws_daemon.placement.mat import decision_mat
from legws_daemon.placement.pdf import preview_labels
from legws_daemon.scene.catalog import load_scene, scenes_dir
from legws_daemon.task.plan_file import load_plan
from tests.cli.helpers import Result, assert_bad_input
from tests.placement.readback import assert_legible_preview, carried, cut_line, cut_texts, texts
from tests.plans import tea_plan_folder

Cli = Callable[..., Result]
#: What the CLI says of a mat's PDF: how many pages, of which orientation.
WROTE = re.compile(
    r"wrote (?P<path>\S+) \((?P<pages>\d+) (?P<paper>A[34]) pages?, (?P<kinds>portrait|landscape|"
    r"\d+ portrait and \d+ landscape), only where something lies; the whole table takes "
    r"(?P<full>\d+)\)"
)


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
    wrote, preview, markers = r.out.splitlines()
    found = WROTE.fullmatch(wrote)
    assert found is not None, wrote
    assert found["path"] == str(out / "layout.pdf") and found["paper"] == "A3"
    assert int(found["pages"]) == _pages(out / "layout.pdf") < int(found["full"]) == 9
    assert preview == f"wrote {out / 'layout.png'} (preview)"
    assert markers == f"wrote {out / 'markers.pdf'} (8 object markers to cut out)"
    with pdfplumber.open(out / "layout.pdf") as pdf:
        assert "layout turned.json" in pdf.pages[0].extract_text()
    assert (out / "layout.png").read_bytes().startswith(b"\x89PNG")


def test_a_scene_without_markers_writes_no_marker_sheet(cli: Cli, tmp_path: Path) -> None:
    r = cli("placement", "feeding", "--layout", "default", "--out", tmp_path, "--paper", "a3")
    assert r.code == 0, r.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["layout.pdf", "layout.png"]


def test_a_table_marker_no_page_holds_is_warned_about_in_one_line(cli: Cli, tmp_path: Path) -> None:
    text = (scenes_dir() / "tea.toml").read_text(encoding="utf-8")
    grown = text.replace("{ id = 0, size = 0.07, x = 0.245, y = 0.51 }",
                         "{ id = 0, size = 0.13, x = 0.3, y = 0.45 }")  # fmt: skip
    assert grown != text
    scene = tmp_path / "tea.toml"
    scene.write_text(grown, encoding="utf-8")
    # its white margin is 173 mm square: no A4 tile (166 x 253 mm) holds it, an A3 one does
    r = cli("placement", scene, "--layout", "default", "--out", tmp_path / "a4")
    assert r.code == 0, r.err
    found = re.fullmatch(
        r"legws: warning: table marker 0 lies across the cut between pages (\d+(, \d+)+) "
        r"of layout.pdf: tape it flat and exact, or print on --paper a3\n",
        r.err,
    )
    assert found is not None, r.err
    r = cli("placement", scene, "--layout", "default", "--out", tmp_path / "a3", "--paper", "a3")
    assert r.code == 0 and r.err == ""


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


@pytest.fixture(scope="module")
def tea_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tea graph's plan as `legws plan tea` makes it (default settings; once a session)."""
    return tea_plan_folder(tmp_path_factory)


@pytest.mark.slow  # the tea plan (~20 s once a session, tests/plans.py), draws its 4 mats
def test_a_plan_gives_one_mat_per_decision(cli: Cli, tmp_path: Path, tea_plan: Path) -> None:
    out = tmp_path / "mats"
    r = cli("placement", "tea", "--plan", tea_plan, "--out", out, "--paper", "a3")
    assert r.code == 0, r.err
    stems = ["01-choose_tea", "02-steep", "03-choose_snack", "04-serve"]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{s}.{ext}" for s in stems for ext in ("pdf", "png")] + ["markers.pdf"]
    )
    assert [ln.split()[1] for ln in r.out.splitlines()] == [
        *(str(out / f"{s}.{ext}") for s in stems for ext in ("pdf", "png")),
        str(out / "markers.pdf"),
    ]
    data = json.loads((tea_plan / "plan.json").read_text())
    with pdfplumber.open(out / "01-choose_tea.pdf") as pdf:
        text = pdf.pages[0].extract_text()
    j = data["decisions"][0]["certificate"]
    assert "decision choose_tea" in text and f"J = {j:.3f}" in text


#: The issue's bound: a tea decision's mat on A4.
MOST_A4_PAGES = 12


@pytest.mark.slow  # draws and reads back the tea plan's 4 A4 mats: ~20 s
def test_the_tea_plans_a4_mats_are_worth_printing(cli: Cli, tmp_path: Path, tea_plan: Path) -> None:
    """Every tea decision's mat: at most 12 A4 pages, each carrying an object's outline or
    label or a table marker inside its cut line; no text a cut goes through or the page's
    printed part cuts off; every object's label whole inside a tile; a preview whose
    labels can be read (:func:`~tests.placement.readback.assert_legible_preview`: 13 px
    or more, their characters 9 px tall or more, none overlapping)."""
    out = tmp_path / "mats"
    r = cli("placement", "tea", "--plan", tea_plan, "--out", out)
    assert r.code == 0, r.err
    assert r.err == ""  # no table marker across a cut
    scene = load_scene("tea")
    plan = load_plan(tea_plan / "plan.json", scene)
    colours = [o.color for o in scene.spec.objects]
    assert scene.spec.markers is not None
    markers = [f"table marker {m.id} ({m.size * 1000:g} mm)" for m in scene.spec.markers.table]
    said = {m["path"]: m for m in map(WROTE.fullmatch, r.out.splitlines()) if m is not None}
    counts = {}
    for i, decision in enumerate(plan.decisions, 1):
        stem = f"{i:02d}-{decision.label.replace('|', '+')}"
        path = out / f"{stem}.pdf"
        fixed = set(scene.objects) - set(scene.movable) - set(decision.candidates)
        names = [
            (o.label or o.name) + (" (fixed)" if o.name in fixed else "")
            for o in scene.spec.objects
        ]
        with pdfplumber.open(path) as pdf:
            count = len(pdf.pages)
            assert int(said[str(path)]["pages"]) == count <= MOST_A4_PAGES, stem
            assert int(said[str(path)]["full"]) == 21
            whole = set()
            for number, page in enumerate(pdf.pages, 1):
                assert carried(page, colours, names + markers), (stem, number)
                assert cut_texts(page) == [], (stem, number)
                assert f"page {number} of {count}" in page.extract_text()
                tile = cut_line(page)
                whole |= {t for t, b in texts(page) if tile.holds(b)}
            assert set(names) | set(markers) <= whole, stem
        counts[decision.label] = count
        mat = decision_mat(scene, decision)
        assert_legible_preview((out / f"{stem}.png").read_bytes(), preview_labels(mat))
    assert len(counts) == 4
