"""The posterior over time as a PNG (``legws replay --plot``).

One shared axis: x is seconds on the recording's ``time`` timeline (the daemon's clock
from its start; the axis says so), y the posterior, fixed to 0–1. Each goal is one colour
(:func:`goal_colours`): the posterior the daemon plotted is a solid line, the replayed
observer's (up to the end of inference) a thin dotted one. Every stage is a band, shaded
on alternate stages and labelled at the top with its index and label (``3 sort#2``; a
single candidate's ``(single)``, without curves or threshold), the labels in up to
:data:`LABEL_ROWS` rows so that a short stage's does not overprint its neighbour's; its
threshold is a dashed line across it.
Every commit the daemon logged is a vertical marker labelled with the goal and how it came
(inferred: black; *confirmed* by the operator: a thick magenta dash, bold label; *single*
candidate: grey dots); the replayed commit is a thin dash-dotted black marker labelled at
the bottom. A ``--threshold`` override is a dotted line beside the recorded one. No two
labels overlap (:func:`posterior_figure` lays them out with their drawn extents).

Drawn with matplotlib's Agg canvas on a :class:`~matplotlib.figure.Figure` (no pyplot, no
global state); matplotlib is imported by this module only, which ``legws replay`` imports
only for ``--plot``.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.text import Text
from matplotlib.transforms import Bbox, blended_transform_factory

from legws_daemon.core.geometry import FloatArray
from legws_daemon.formats.log_lines import How

#: Size of the picture in pixels (``WIDTH`` x ``HEIGHT`` at ``DPI``).
WIDTH, HEIGHT, DPI = 1200, 600, 100
#: The clock of the x axis, as its label says.
TIME_CLOCK = "the daemon's clock from its start"

#: Goal colours in order of first appearance (matplotlib's tab10, then tab20's light tones).
PALETTE = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
    "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5",
    "#c49c94", "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5",
)  # fmt: skip

#: Commit markers by how the commit came: (colour, line style, width, label suffix).
COMMIT_STYLE: dict[How, tuple[str, str, float, str]] = {
    "inferred": ("#000000", "-", 1.5, "inferred"),
    "confirmed": ("#c800c8", "--", 3.0, "confirmed"),
    "single": ("#555555", ":", 2.0, "single"),
}
#: Behind a commit's label: a pale backdrop, so that the curves it crosses do not hide it.
_BACKDROP = {"facecolor": "white", "alpha": 0.75, "edgecolor": "none", "pad": 1.0}
#: Rows of stage labels above the plot, before a label is cut to its stage's index or left out.
LABEL_ROWS = 3
_GAP = 4.0  # pixels between two labels
REPLAY_COMMIT_COLOUR = "#000000"
THRESHOLD_COLOUR = "#555555"
STAGE_SHADE = "#000000"


def goal_colours(names: Iterable[str]) -> dict[str, str]:
    """A colour per distinct goal name, in order of first appearance (cycling the palette)."""
    out: dict[str, str] = {}
    for name in names:
        if name not in out:
            out[name] = PALETTE[len(out) % len(PALETTE)]
    return out


@dataclass(frozen=True)
class PlotCommit:
    """A commit marker: when (seconds), on what, and how it came."""

    seconds: float
    goal: str
    how: How
    p: float


@dataclass(frozen=True)
class StagePlot:
    """What one stage contributes to the picture.

    Attributes:
        label: the stage's label (``"stage 0 's0'"``).
        start: first second of the stage.
        end: last second of the stage.
        goals: the goal names, one column of ``recorded`` and ``replayed`` each.
        p_thresh: the daemon's threshold.
        replay_thresh: the replay's threshold when it differs (``--threshold``), else None.
        recorded_times: ``(K,)`` seconds of the daemon's posterior.
        recorded: ``(K, M)`` the daemon's posterior (``NaN`` where a goal has no value).
        replayed_times: ``(L,)`` seconds of the replay's posterior.
        replayed: ``(L, M)`` the replayed posterior.
        commits: the commits the daemon logged.
        replayed_commit: the replay's commit, or None.
        inference: False for a stage with a single candidate (a band, its label and its
            commit; no curves and no threshold).
    """

    label: str
    start: float
    end: float
    goals: tuple[str, ...]
    p_thresh: float
    replay_thresh: float | None
    recorded_times: FloatArray
    recorded: FloatArray
    replayed_times: FloatArray
    replayed: FloatArray
    commits: list[PlotCommit] = field(default_factory=list)
    replayed_commit: PlotCommit | None = None
    inference: bool = True


def figure_png(fig: Figure) -> bytes:
    """A figure of :func:`posterior_figure` as PNG bytes."""
    out = io.BytesIO()
    fig.savefig(out, format="png", dpi=DPI)
    return out.getvalue()


def posterior_figure(stages: Sequence[StagePlot], title: str) -> Figure:
    """The picture of ``stages``, drawn, its labels laid out so that none overlaps another
    (:func:`_lay_out`)."""
    fig = Figure(figsize=(WIDTH / DPI, HEIGHT / DPI), dpi=DPI)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.06, right=0.80, top=0.84, bottom=0.10)
    ax = fig.add_subplot()
    colours = goal_colours(g for s in stages for g in s.goals if s.inference)
    top = blended_transform_factory(ax.transData, ax.transAxes)
    stage_labels: list[Text] = []
    commit_labels: list[Text] = []
    replay_labels: list[Text] = []
    for n, s in enumerate(stages):
        if n % 2 == 1:
            ax.axvspan(s.start, s.end, color=STAGE_SHADE, alpha=0.06, linewidth=0)
        stage_labels.append(
            ax.text(s.start, 1.0, s.label, transform=top, fontsize=9, va="bottom", ha="left")
        )
        if s.inference:
            ax.hlines(s.p_thresh, s.start, s.end, colors=THRESHOLD_COLOUR, linestyles="--", lw=1)
        if s.inference and s.replay_thresh is not None:
            ax.hlines(s.replay_thresh, s.start, s.end, colors=THRESHOLD_COLOUR, linestyles=":")
        for j, goal in enumerate(s.goals if s.inference else ()):
            if len(s.recorded_times):
                ax.plot(s.recorded_times, s.recorded[:, j], color=colours[goal], lw=2.2)
            if len(s.replayed_times):
                ax.plot(s.replayed_times, s.replayed[:, j], color=colours[goal], lw=1.2, ls=":")
        for c in s.commits:
            colour, style, width, how = COMMIT_STYLE[c.how]
            ax.axvline(c.seconds, color=colour, ls=style, lw=width)
            bold = "bold" if c.how == "confirmed" else "normal"
            commit_labels.append(
                ax.annotate(
                    f"{c.goal} p={c.p:.2f} ({how})",
                    (c.seconds, 0.98),
                    xycoords=top,
                    xytext=(-2 - width, 0),
                    textcoords="offset points",
                    rotation=90,
                    fontsize=8,
                    color=colour,
                    ha="right",
                    va="top",
                    fontweight=bold,
                    bbox=_BACKDROP,
                )
            )
        if s.replayed_commit is not None:
            c = s.replayed_commit
            ax.axvline(c.seconds, color=REPLAY_COMMIT_COLOUR, ls="-.", lw=1)
            replay_labels.append(
                ax.annotate(
                    f"replay: {c.goal}",
                    (c.seconds, 0.02),
                    xycoords=top,
                    xytext=(3, 0),
                    textcoords="offset points",
                    rotation=90,
                    fontsize=8,
                    ha="left",
                    va="bottom",
                    bbox=_BACKDROP,
                )
            )
    ax.set_ylim(0.0, 1.0)
    if stages:
        lo, hi = min(s.start for s in stages), max(s.end for s in stages)
        pad = 0.01 * (hi - lo) if hi > lo else 0.5
        ax.set_xlim(lo - pad, hi + pad)
    else:
        ax.text(0.5, 0.5, "no stage with EE samples", transform=ax.transAxes, ha="center")
    ax.set_xlabel(f"time (s) on the recording's `time` timeline: {TIME_CLOCK}")
    ax.set_ylabel("posterior")
    ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle(title, fontsize=11)
    replay_thresh = any(s.replay_thresh is not None for s in stages)
    ax.legend(
        handles=_legend(colours, replay_thresh),
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        fontsize=8,
        frameon=False,
        ncol=1 if len(colours) <= 14 else 2,
    )
    _lay_out(fig, ax, stage_labels, commit_labels, replay_labels)
    return fig


def _lay_out(
    fig: Figure,
    ax: Axes,
    stage_labels: list[Text],
    commit_labels: list[Text],
    replay_labels: list[Text],
) -> None:
    """Place the labels so that none overlaps another.

    A stage's label goes to the lowest of :data:`LABEL_ROWS` rows above the plot where it
    clears the labels before it, whole if it ends within the next stage's band, else cut
    to the stage's index; kept within the plot's width. A commit's label that would cover
    an earlier one slides down past it (a replayed commit's up), cut to the goal's name if
    it would then leave the plot. A label with no room even so is not drawn (its stage
    band or commit marker still is).
    """
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    box = ax.get_window_extent(renderer)
    starts = [ax.transData.transform((t.get_position()[0], 0.0))[0] for t in stage_labels]
    height = max((t.get_window_extent(renderer).height for t in stage_labels), default=0.0)
    ends = [-math.inf] * LABEL_ROWS
    for n, text in enumerate(stage_labels):
        limit = starts[n + 2] if n + 2 < len(starts) else box.x1
        row = None
        for candidate in _shorter(text.get_text()):
            text.set_text(candidate)
            left, width = _clamp(text, ax, box, renderer)
            if left + width > limit + _GAP and candidate != _shorter(candidate)[-1]:
                continue  # whole, it would crowd the stages after the next: its index
            row = next((r for r in range(LABEL_ROWS) if ends[r] + _GAP <= left), None)
            if row is not None:
                break
        if row is None:
            text.set_visible(False)
            continue
        ends[row] = left + width
        text.set_y(1.0 + (3.0 + row * (height + 2.0)) / box.height)
    placed = [t.get_window_extent(renderer) for t in stage_labels if t.get_visible()]
    for text, down in [(t, True) for t in commit_labels] + [(t, False) for t in replay_labels]:
        if _slide(text, down, placed, box, renderer, fig.dpi):
            placed.append(text.get_window_extent(renderer))
        else:
            text.set_visible(False)


def _shorter(label: str) -> list[str]:
    """The label, then its first word (a stage's index) if that is shorter."""
    first = label.split(" ", 1)[0]
    return [label] if first == label else [label, first]


def _clamp(text: Text, ax: Axes, box: Bbox, renderer: Any) -> tuple[float, float]:
    """Move a stage label left so that it ends within the plot; its left edge and width."""
    extent = text.get_window_extent(renderer)
    if extent.x1 > box.x1:
        x = ax.transData.inverted().transform((box.x1 - extent.width, 0.0))[0]
        text.set_x(x)
        extent = text.get_window_extent(renderer)
    return extent.x0, extent.width


def _slide(
    text: Text, down: bool, placed: list[Bbox], box: Bbox, renderer: Any, dpi: float
) -> bool:
    """Slide a rotated label along its marker until it covers no placed label, within the
    plot; whole, then cut to its goal's name. Whether it found room."""
    start = text.get_position()  # the offset from the anchor, in points
    whole = text.get_text()
    words = whole.split(" ")
    goal = words[1] if words[0] == "replay:" else words[0]
    for candidate in dict.fromkeys([whole, goal]):
        text.set_text(candidate)
        text.set_position(start)
        for _ in range(len(placed) + 1):
            extent = text.get_window_extent(renderer)
            if extent.y0 < box.y0 - 0.5 or extent.y1 > box.y1 + 0.5:
                break  # out of the plot: try it shorter
            hits = [b for b in placed if b.overlaps(extent)]
            if not hits:
                return True
            dx, dy = text.get_position()
            if down:
                dy -= (extent.y1 - min(b.y0 for b in hits) + _GAP) * 72.0 / dpi
            else:
                dy += (max(b.y1 for b in hits) - extent.y0 + _GAP) * 72.0 / dpi
            text.set_position((dx, dy))
    return False


def _legend(colours: dict[str, str], replay_thresh: bool) -> list[Line2D]:
    def line(label: str, colour: str, style: str = "-", width: float = 2.0) -> Line2D:
        return Line2D([], [], color=colour, ls=style, lw=width, label=label)

    handles = [line(goal, colour) for goal, colour in colours.items()]
    handles += [
        line("daemon (recorded)", "#333333", "-", 2.2),
        line("replay", "#333333", ":", 1.2),
        line("p_thresh", THRESHOLD_COLOUR, "--", 1.0),
    ]
    if replay_thresh:
        handles.append(line("replay p_thresh", THRESHOLD_COLOUR, ":", 1.5))
    handles += [line(f"commit ({how})", c, st, w) for c, st, w, how in COMMIT_STYLE.values()]
    handles.append(line("replayed commit", REPLAY_COMMIT_COLOUR, "-.", 1.0))
    return handles
