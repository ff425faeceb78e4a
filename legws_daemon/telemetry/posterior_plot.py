"""The posterior over time as a PNG (``legws replay --plot``).

One shared axis: x is seconds on the recording's ``time`` timeline, y the posterior, fixed
to 0–1. Each goal is one colour (:func:`goal_colours`): the posterior the daemon plotted is
a solid line, the replayed observer's a thin dotted one. Every stage is a band, shaded
on alternate stages and labelled at the top; its threshold is a dashed line across it.
Every commit the daemon logged is a vertical marker labelled with the goal and how it came
(inferred: black; *confirmed* by the operator: a thick magenta dash, bold label; *single*
candidate: grey dots); the replayed commit is a thin dash-dotted black marker labelled at
the bottom. A ``--threshold`` override is a dotted line beside the recorded one.

Drawn with matplotlib's Agg canvas on a :class:`~matplotlib.figure.Figure` (no pyplot, no
global state); matplotlib is imported by this module only, which ``legws replay`` imports
only for ``--plot``.
"""

from __future__ import annotations

import io
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.transforms import blended_transform_factory

from legws_daemon.core.geometry import FloatArray
from legws_daemon.formats.log_lines import How

#: Size of the picture in pixels (``WIDTH`` x ``HEIGHT`` at ``DPI``).
WIDTH, HEIGHT, DPI = 1200, 600, 100

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


def posterior_png(stages: Sequence[StagePlot], title: str) -> bytes:
    """The picture of ``stages`` (``WIDTH`` x ``HEIGHT`` pixels) as PNG bytes."""
    fig = Figure(figsize=(WIDTH / DPI, HEIGHT / DPI), dpi=DPI)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.06, right=0.80, top=0.88, bottom=0.10)
    ax = fig.add_subplot()
    colours = goal_colours(g for s in stages for g in s.goals)
    top = blended_transform_factory(ax.transData, ax.transAxes)
    for n, s in enumerate(stages):
        if n % 2 == 1:
            ax.axvspan(s.start, s.end, color=STAGE_SHADE, alpha=0.06, linewidth=0)
        ax.text(s.start, 1.01, s.label, transform=top, fontsize=9, va="bottom", ha="left")
        ax.hlines(s.p_thresh, s.start, s.end, colors=THRESHOLD_COLOUR, linestyles="--", lw=1)
        if s.replay_thresh is not None:
            ax.hlines(s.replay_thresh, s.start, s.end, colors=THRESHOLD_COLOUR, linestyles=":")
        for j, goal in enumerate(s.goals):
            if len(s.recorded_times):
                ax.plot(s.recorded_times, s.recorded[:, j], color=colours[goal], lw=2.2)
            if len(s.replayed_times):
                ax.plot(s.replayed_times, s.replayed[:, j], color=colours[goal], lw=1.2, ls=":")
        for c in s.commits:
            colour, style, width, how = COMMIT_STYLE[c.how]
            ax.axvline(c.seconds, color=colour, ls=style, lw=width)
            bold = "bold" if c.how == "confirmed" else "normal"
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
            )
        if s.replayed_commit is not None:
            c = s.replayed_commit
            ax.axvline(c.seconds, color=REPLAY_COMMIT_COLOUR, ls="-.", lw=1)
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
            )
    ax.set_ylim(0.0, 1.0)
    if stages:
        lo, hi = min(s.start for s in stages), max(s.end for s in stages)
        pad = 0.01 * (hi - lo) if hi > lo else 0.5
        ax.set_xlim(lo - pad, hi + pad)
    else:
        ax.text(0.5, 0.5, "no stage with EE samples", transform=ax.transAxes, ha="center")
    ax.set_xlabel("time (s)")
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
    out = io.BytesIO()
    fig.savefig(out, format="png", dpi=DPI)
    return out.getvalue()


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
