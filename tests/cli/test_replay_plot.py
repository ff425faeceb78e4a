"""``legws replay --plot``: the posterior over time as a PNG, and its refused destinations."""

from __future__ import annotations

import io
import os
import socket
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.text import Annotation, Text
from PIL import Image

from legws_daemon.formats.log_lines import commit_text
from legws_daemon.telemetry.posterior_plot import (
    COMMIT_STYLE,
    HEIGHT,
    LABEL_ROWS,
    WIDTH,
    PlotCommit,
    StagePlot,
    figure_png,
    goal_colours,
    posterior_figure,
)
from legws_daemon.telemetry.rerun_log import RerunLog
from tests.cli.helpers import Result, assert_bad_input
from tests.telemetry.helpers import log_episode, straight_episode

Cli = Callable[..., Result]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two stages: an inferred commit on the banana, then a confirmed one on the white mug."""
    path = tmp_path_factory.mktemp("replay-plot") / "plot.rrd"
    banana = straight_episode("breakfast_easy", "banana")
    mug = straight_episode("desk", "white_mug", hold=0)
    with RerunLog(f"save:{path}", robot="sawyer-sim") as log:
        log_episode(log, banana, tick0=0, stage="s0")
        tick = len(banana.positions) + 40  # within stage s1 (its inferred commit is later)
        log_episode(log, mug, tick0=len(banana.positions), stage="s1")
        log.log_text(tick, tick * 0.05, "INFO", commit_text("white_mug", 0.6, how="confirmed"))
    return path


def _pixels_near(image: Image.Image, hex_colour: str, tol: int = 12) -> int:
    rgb = np.asarray(image.convert("RGB"), dtype=np.int16)
    want = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)], dtype=np.int16)
    return int(np.sum(np.all(np.abs(rgb - want) <= tol, axis=-1)))


def test_the_plot_has_the_size_and_the_colours(cli: Cli, recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "posterior.png"
    result = cli("replay", recording, "--plot", out)
    assert result.code == 0 and result.err == "", result
    assert f"Plot: {out}" in result.out
    assert "(confirmed by the operator, below p_thresh 0.9 as expected)" in result.out
    with Image.open(out) as image:
        assert image.format == "PNG"
        assert image.size == (WIDTH, HEIGHT) == (1200, 600)
        colours = goal_colours(["cereal_box", "banana", "white_mug", "black_stapler"])
        for goal, colour in colours.items():
            assert _pixels_near(image, colour) > 300, goal  # a line, not a legend swatch
        confirmed = COMMIT_STYLE["confirmed"][0]
        assert _pixels_near(image, confirmed) > 300  # the confirmed commit's marker
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_the_plot_in_json_and_replaced(cli: Cli, recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "posterior.png"
    out.write_text("old")
    result = cli("replay", recording, "--stage", "s1", "--plot", out, "--json")
    assert result.code == 0, result
    assert f'"plot": "{out}"' in result.out
    with Image.open(out) as image:
        assert image.size == (1200, 600)
        assert _pixels_near(image, goal_colours(["white_mug"])["white_mug"]) > 300


def _refusals(tmp_path: Path) -> Iterator[tuple[Path, str]]:
    yield tmp_path, "is a folder"
    yield Path("/dev/null"), "character device"
    yield tmp_path / "missing" / "p.png", "does not exist"
    link = tmp_path / "null.png"
    link.symlink_to("/dev/null")
    yield link, "character device"
    fifo = tmp_path / "fifo.png"
    os.mkfifo(fifo)
    yield fifo, "FIFO"


def test_bad_plot_destinations_exit_2_before_any_work(cli: Cli, tmp_path: Path) -> None:
    missing = tmp_path / "missing.rrd"  # the destination is checked before the recording
    for dest, needle in _refusals(tmp_path):
        assert_bad_input(cli("replay", missing, "--plot", dest), str(dest), needle)
    sock_path = tmp_path / "s.png"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(sock_path))
        assert_bad_input(cli("replay", missing, "--plot", sock_path), "socket")
    assert_bad_input(cli("replay", missing, "--plot"), "--plot")


def test_a_bad_recording_leaves_no_plot(cli: Cli, tmp_path: Path) -> None:
    text = tmp_path / "notes.rrd"
    text.write_text("hello")
    out = tmp_path / "p.png"
    assert_bad_input(cli("replay", text, "--plot", out), "not a readable rerun recording")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.rrd"]


def overlapping_labels(fig: Figure) -> list[tuple[str, str]]:
    """Every pair of drawn texts of the figure whose extents overlap (by more than half a
    pixel each way), and every text that leaves the figure as ``(text, "outside")``."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    texts: list[Text] = list(fig.texts)
    for ax in fig.axes:
        texts += [*ax.texts, ax.xaxis.label, ax.yaxis.label, ax.title]
        legend = ax.get_legend()
        texts += legend.get_texts() if legend is not None else []
        for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            texts += [t.label1 for t in axis.get_major_ticks() if lo <= t.get_loc() <= hi]
    boxes = [
        (t.get_text(), t.get_window_extent(renderer))
        for t in texts
        if t.get_visible() and t.get_text().strip()
    ]
    width, height = fig.bbox.width, fig.bbox.height
    out = []
    for i, (a, box) in enumerate(boxes):
        if box.x0 < 0 or box.y0 < 0 or box.x1 > width or box.y1 > height:
            out.append((a, "outside"))
        for b, other in boxes[i + 1 :]:
            dx = min(box.x1, other.x1) - max(box.x0, other.x0)
            dy = min(box.y1, other.y1) - max(box.y0, other.y0)
            if dx > 0.5 and dy > 0.5:
                out.append((a, b))
    return out


def _stage(label: str, start: float, end: float, commits: list[PlotCommit]) -> StagePlot:
    times = np.linspace(start, end, 5)
    values = np.tile([0.5, 0.5], (5, 1))
    return StagePlot(label, start, end, ("a", "b"), 0.9, None, times, values, times, values,
                     commits, commits[0] if commits else None)  # fmt: skip


def test_short_stages_and_close_commits_do_not_overprint() -> None:
    """The labels of stages a few pixels wide go to rows of their own (then to their index
    alone), a commit's label slides down past a neighbour's: no two texts overlap."""
    stages = [_stage("0 pick_brick#1", 0.0, 60.0, [PlotCommit(30.0, "a", "inferred", 0.9)])]
    t = 60.0
    for i in range(1, 9):  # stages of half a second to two seconds
        length = 0.5 + 0.2 * i
        commits = [PlotCommit(t + 0.1, "b", "single", 1.0), PlotCommit(t + 0.3, "a", "confirmed",
                   0.71)]  # fmt: skip
        stages.append(_stage(f"{i} sort#{i} (single)", t, t + length, commits))
        t += length
    stages.append(_stage("9 feed", t, t + 40.0, [PlotCommit(t + 20.0, "b", "inferred", 0.93)]))
    fig = posterior_figure(stages, "Posterior over time: short.rrd")
    assert overlapping_labels(fig) == []
    bands = [t for t in fig.axes[0].texts if not isinstance(t, Annotation)]
    shown = [t.get_text() for t in bands if t.get_visible()]
    assert shown[0] == "0 pick_brick#1" and shown[-1] == "9 feed"
    assert shown[-2] == "8 sort#8 (single)"  # whole: the long stage after it has room
    assert set(shown[1:-2]) <= {str(i) for i in range(1, 8)} and len(shown) >= 8
    assert 2 <= len({round(t.get_position()[1], 6) for t in bands}) <= LABEL_ROWS
    commits = [t for t in fig.axes[0].texts if isinstance(t, Annotation) and t.get_visible()]
    assert len(commits) >= 10  # of 19: slid past each other, cut, or left out
    with Image.open(io.BytesIO(figure_png(fig))) as image:
        assert image.size == (WIDTH, HEIGHT)
