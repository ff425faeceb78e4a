"""``legws replay``: re-run the intent observer on the EE path of a daemon recording.

**One replay stage per decision.** The daemon sets up a stage in the recording for every
decision (:meth:`~legws_daemon.telemetry.rerun_log.RerunLog.log_setup`), single-candidate
ones included; a recording made before those were set up has their ``how=single`` commit
in the previous stage's log, and such a commit (its goal not a candidate of the stage it
was logged in) is split off into a stage of its own at its tick, named after the
``stage_done`` line that closes it. Stages are addressed by index (negative from the
end) or by label: the name when one stage has it, else ``NAME#K``, the K-th stage of
that name (:func:`~legws_daemon.telemetry.recording.select_index`; an ambiguous name is
one line listing the choices, exit 2).

**What is replayed.** The observer (:class:`~legws_daemon.core.observer.IntentObserver`)
is fed a stage's recorded EE poses in tick order, from the stage's start pose ``x0``,
with the stage's recorded parameters unless overridden, **up to the end of inference**:
the daemon's last commit of the stage (inferred or confirmed by the operator), or, without
one, the stage's last tick with a recorded posterior. After it the arm moves on its own
(to the goal, home) and a posterior of that path would mean nothing: it is not fed, and
every comparison is at a tick up to the end of inference. A stage with a single candidate
infers nothing and replays nothing.

The report says, per stage, when and on which goal the replay would have committed and
its posterior there; every commit the daemon logged (``commit goal=<name> p=<prob>``
lines of the text log, with how it came: inferred, confirmed by the operator, or single
candidate) with the daemon's own posterior (``plots/posterior/*``) and the replay's at
that tick; and, where either did not commit, both posteriors at the end of inference.

**Clocks.** ``tick`` is the daemon's control tick (one count for the whole session);
``time`` is seconds on the recording's ``time`` timeline, the daemon's monotonic clock
since it started: of the tick's EE sample for what the replay computes, of the log line
for a recorded commit (logged during its tick, a few milliseconds before the tick's EE
sample). ``--plot`` draws the posterior over ``time``
(:mod:`legws_daemon.telemetry.posterior_plot`).

**The recording is input.** It is read as any file legws reads
(:mod:`legws_daemon.telemetry.recording`): a damaged one (cut off, flipped bits, another
header) is refused naming ``legws recording finish FILE --out OTHER.rrd``, which recovers its
whole messages; every stage document, column and text-log row is validated
(:mod:`legws_daemon.formats.recording_doc`). Anything else is one line naming the file and
the field, exit 2.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import click
import numpy as np

from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import COST_FORMS, CostForm, Params
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path, write_atomic
from legws_daemon.formats.printable import echo
from legws_daemon.telemetry.recording import (
    EePath,
    Posterior,
    RecordedCommit,
    Stage,
    read_ee_path,
    read_posterior,
    read_recorded_commits,
    read_stages,
    read_text_log,
    select_index,
    stage_labels,
)

if TYPE_CHECKING:  # matplotlib loads only for --plot
    from matplotlib.figure import Figure

#: Longest stage name read from a ``stage_done`` line (that of a stage document).
MAX_NAME = 64
#: What ended a stage's inference: the daemon's last commit, or its last recorded posterior.
EndCause = Literal["commit", "last posterior"]
CLOCKS = (
    "tick: the daemon's control tick; time: seconds on the recording's `time` timeline "
    "(the daemon's clock from its start), a tick's that of its EE sample, a recorded "
    "commit's that of its log line (logged during the tick, before the EE sample)"
)


def _check_beta(_ctx: click.Context, _param: click.Parameter, value: float | None) -> float | None:
    if value is not None:
        try:
            Params(beta=value)
        except InputError as err:
            raise click.BadParameter(str(err).removeprefix("beta: ")) from None
    return value


def _check_threshold(
    _ctx: click.Context, _param: click.Parameter, value: float | None
) -> float | None:
    if value is not None and not (math.isfinite(value) and 0.5 < value < 1.0):
        raise click.BadParameter(f"expected a number in (0.5, 1), got {value!r}")
    return value


@dataclass(frozen=True)
class Decision:
    """One decision of a recording, with what was recorded during it.

    Attributes:
        index: its place among the recording's decisions (0 for the first).
        label: its name, or ``NAME#K`` where the name repeats (:func:`stage_labels`).
        name: the stage's name (``None``: unnamed).
        stage: the set-up it was recorded under (for a split-off single candidate: the
            stage whose log holds its commit).
        candidates: the candidates' names.
        goals: the goal set the daemon inferred over (``None``: a single candidate).
        set_up: False for a single candidate split off another stage (an older recording).
        ee: the EE samples of the decision.
        posterior: the daemon's posterior during it.
        commits: the commits it logged, in logging order.
    """

    index: int
    label: str
    name: str | None
    stage: Stage
    candidates: tuple[str, ...]
    goals: GoalSet | None
    set_up: bool
    ee: EePath
    posterior: Posterior
    commits: list[RecordedCommit]


def read_decisions(source: Path) -> list[Decision]:
    """Every decision of the recording ``source``, in order."""
    parts: list[Decision] = []
    for stage in read_stages(source):
        ee = read_ee_path(source, stage.index)
        posterior = read_posterior(source, stage.index)
        commits = read_recorded_commits(source, stage.index)
        parts += _split_off_singles(source, stage, ee, posterior, commits)
    labels = stage_labels([d.name for d in parts])
    return [replace(d, index=i, label=labels[i]) for i, d in enumerate(parts)]


def _split_off_singles(
    source: Path, stage: Stage, ee: EePath, posterior: Posterior, commits: list[RecordedCommit]
) -> list[Decision]:
    """The stage, and each single-candidate commit logged in it that is not its own (an
    older recording) as a decision of its own from its tick on (not yet numbered)."""
    cuts = [
        i for i, c in enumerate(commits) if c.how == "single" and c.goal not in stage.candidates
    ]
    whole = Decision(-1, "", stage.name, stage, stage.candidates, stage.goals, True, ee,
                     posterior, commits)  # fmt: skip
    if not cuts:
        return [whole]
    lines = read_text_log(source, stage.index)
    bounds = [0, *cuts, len(commits)]
    ticks = [-math.inf, *(commits[i].tick for i in cuts), math.inf]
    out = []
    for k in range(len(bounds) - 1):
        part = replace(
            whole,
            ee=_ee_within(ee, ticks[k], ticks[k + 1]),
            posterior=_posterior_within(posterior, ticks[k], ticks[k + 1]),
            commits=commits[bounds[k] : bounds[k + 1]],
        )
        if k > 0:
            single = commits[bounds[k]]
            part = replace(part, name=_done_name(lines, single, source), candidates=(single.goal,),
                           goals=None, set_up=False)  # fmt: skip
        out.append(part)
    return out


def _ee_within(ee: EePath, lo: float, hi: float) -> EePath:
    keep = (ee.ticks >= lo) & (ee.ticks < hi)
    return EePath(ee.ticks[keep], ee.times[keep], ee.positions[keep], ee.quaternions[keep])


def _posterior_within(posterior: Posterior, lo: float, hi: float) -> Posterior:
    keep = (posterior.ticks >= lo) & (posterior.ticks < hi)
    return Posterior(
        posterior.goals, posterior.ticks[keep], posterior.times[keep], posterior.values[keep]
    )


def _done_name(
    lines: list[tuple[int, str, str]], commit: RecordedCommit, source: Path
) -> str | None:
    """The stage of the first ``stage_done`` line for the commit's goal after it (a name of
    1 to 64 characters, as a stage document's)."""
    for tick, _, text in lines:
        if tick >= commit.tick and text.startswith("stage_done "):
            fields = dict(part.split("=", 1) for part in text.split()[1:] if "=" in part)
            if fields.get("goal") == commit.goal:
                name = fields.get("stage")
                if name is not None and not 1 <= len(name) <= MAX_NAME:
                    raise InputError(
                        f"expected a stage name of 1 to {MAX_NAME} characters in a "
                        f"stage_done line, got {len(name)}",
                        source=str(source),
                        field=f"log (tick {tick})",
                    )
                return name
    return None


@dataclass(frozen=True)
class Replay:
    """The observer run over one stage's EE path, up to the end of inference.

    Attributes:
        goals: the goal names.
        ticks: ``(K,)`` ticks of the samples fed.
        times: ``(K,)`` their ``time`` (s).
        posteriors: ``(K, M)`` the posterior after each sample.
        prior: ``(M,)`` the posterior before any sample (uniform).
        commit: the first commit (goal, tick, time, p, samples, posterior), or None.
    """

    goals: tuple[str, ...]
    ticks: IntArray
    times: FloatArray
    posteriors: FloatArray
    prior: FloatArray
    commit: dict[str, Any] | None

    def at(self, tick: int) -> dict[str, float]:
        """The posterior after the latest sample at or before ``tick`` (the prior if none)."""
        i = int(np.searchsorted(self.ticks, tick, side="right")) - 1
        row = self.posteriors[i] if i >= 0 else self.prior
        return dict(zip(self.goals, row.tolist(), strict=True))


def replay_stage(goals: GoalSet, path: EePath, params: Params, source: str) -> Replay:
    """Run the observer on ``path``: its posterior at every sample and its commit."""
    observer = IntentObserver(goals, params)
    names = goals.names
    prior = observer.posterior
    posteriors = np.empty((len(path.ticks), len(names)))
    commit: dict[str, Any] | None = None
    for i, tick in enumerate(path.ticks.tolist()):
        try:
            post = observer.update(path.positions[i], path.quaternions[i])
        except InputError as err:
            raise InputError(str(err), source=source, field=f"world/ee tick {tick}") from None
        posteriors[i] = post
        k = observer.committed
        if commit is None and k is not None:
            commit = {
                "goal": names[k],
                "tick": tick,
                "time": float(path.times[i]),
                "p": float(post[k]),
                "samples": i + 1,
                "posterior": dict(zip(names, post.tolist(), strict=True)),
            }
    return Replay(tuple(names), path.ticks, path.times, posteriors, prior, commit)


def end_of_inference(d: Decision) -> tuple[int, float | None, EndCause] | None:
    """The tick where the daemon's inference of ``d`` ended, the ``time`` of its EE sample
    and why; None when it never inferred (a single candidate, or no posterior and no
    commit)."""
    if d.goals is None:
        return None
    inferred = [c for c in d.commits if c.how != "single"]
    cause: EndCause = "commit"
    if inferred:
        tick = inferred[-1].tick
    elif len(d.posterior.ticks):
        tick, cause = int(d.posterior.ticks[-1]), "last posterior"
    else:
        return None
    i = int(np.searchsorted(d.ee.ticks, tick))
    found = i < len(d.ee.ticks) and int(d.ee.ticks[i]) == tick
    return tick, float(d.ee.times[i]) if found else None, cause


@dataclass(frozen=True)
class StageReplay:
    """Everything read and computed for one decision: the report and what the plot needs."""

    decision: Decision
    params: Params
    replay: Replay | None
    report: dict[str, Any]


def replay_decision(source: Path, d: Decision, overrides: dict[str, Any]) -> StageReplay:
    """Replay one decision of ``source`` up to its end of inference; its report."""
    params = replace(d.stage.params, **overrides)
    end = end_of_inference(d)
    replay = None
    if d.goals is not None and end is not None:
        fed = _ee_within(d.ee, -math.inf, end[0] + 1)
        replay = replay_stage(d.goals, fed, params, str(source))
    recorded = [_recorded_commit(c, d, replay) for c in d.commits]
    inferred = [c for c in recorded if c["how"] != "single"]
    first = inferred[0] if inferred else None
    commit = replay.commit if replay is not None else None
    agrees = None if commit is None or first is None else commit["goal"] == first["goal"]
    mismatches = []
    if agrees is False and commit is not None and first is not None:
        mismatches.append(
            f"the replay commits on {commit['goal']}, the daemon first on {first['goal']}"
        )
    for c in recorded:
        if c["how"] == "inferred" and c["below_threshold"]:
            mismatches.append(
                f"inferred commit on {c['goal']} at tick {c['tick']} with p = {c['p']:g}, "
                f"below p_thresh {d.stage.p_thresh:g}"
            )
    ticks, times = d.ee.ticks.tolist(), d.ee.times.tolist()
    report = {
        "index": d.index,
        "label": d.label,
        "name": d.name,
        "scene": d.stage.scene,
        "candidates": list(d.candidates),
        "inference": d.goals is not None,
        "set_up": d.set_up,
        "recorded_stage": d.stage.index,
        "samples": len(ticks),
        "first_tick": ticks[0] if ticks else None,
        "last_tick": ticks[-1] if ticks else None,
        "first_time": times[0] if times else None,
        "last_time": times[-1] if times else None,
        "params": params.as_dict(),
        "recorded_params": d.stage.params.as_dict(),
        "p_thresh": d.stage.p_thresh,
        "replayed_samples": 0 if replay is None else len(replay.ticks),
        "commit": commit,
        "recorded_commit": first,
        "recorded_commits": recorded,
        "end_of_inference": _end_report(d, end, replay),
        "agrees": agrees,
        "mismatches": mismatches,
    }
    return StageReplay(d, params, replay, report)


def _recorded_commit(c: RecordedCommit, d: Decision, replay: Replay | None) -> dict[str, Any]:
    """A commit the daemon logged, with its posterior and the replay's at that tick (both
    ``None`` for a single candidate: nothing was inferred)."""
    row = d.posterior.row_at(c.tick) if d.goals is not None else None
    tick = c.tick if row is None else int(d.posterior.ticks[row])
    return {
        "tick": c.tick,
        "time": c.seconds,
        "goal": c.goal,
        "p": c.p,
        "how": c.how,
        "below_threshold": c.p < d.stage.p_thresh,
        "posterior_tick": tick,
        "recorded_posterior": None if row is None else d.posterior.as_dict(row),
        "replayed_posterior": None if replay is None else replay.at(tick),
    }


def _end_report(
    d: Decision, end: tuple[int, float | None, EndCause] | None, replay: Replay | None
) -> dict[str, Any] | None:
    """Both posteriors at the end of inference (None: the stage inferred nothing)."""
    if end is None or replay is None:
        return None
    tick, t, cause = end
    row = d.posterior.row_at(tick)
    return {
        "tick": tick,
        "time": t,
        "cause": cause,
        "recorded_posterior": None if row is None else d.posterior.as_dict(row),
        "replayed_posterior": replay.at(tick),
    }


_HOW = {
    "inferred": "inferred",
    "confirmed": "confirmed by the operator",
    "single": "single candidate, no inference",
}
_CAUSE = {"commit": "the daemon's commit", "last posterior": "its last recorded posterior"}
LOGGED = "logged at time"


def _when(tick: int | None, t: float | None, what: str = "time") -> str:
    return f"tick {tick}" + ("" if t is None else f" ({what} {t:.3f} s)")


def _posterior(values: dict[str, float | None] | None) -> str:
    if values is None:
        return "none"
    return ", ".join(f"{g} {'-' if v is None else f'{v:.3f}'}" for g, v in values.items())


def _stage_text(s: dict[str, Any]) -> list[str]:
    head = f"Stage {s['index']} {s['label']} (scene {s['scene']}): "
    if s["inference"]:
        head += "candidates " + ", ".join(s["candidates"])
    else:
        head += f"a single candidate, {s['candidates'][0]}: no inference, nothing replayed"
    lines = ["", head]
    if not s["set_up"]:
        lines.append(
            f"  (not set up in this recording, made by an older legws: its commit is in "
            f"stage {s['recorded_stage']}'s log)"
        )
    if s["samples"]:
        lines.append(
            f"  EE samples: {s['samples']}, {_when(s['first_tick'], s['first_time'])} .. "
            f"{_when(s['last_tick'], s['last_time'])}"
        )
    else:
        lines.append("  EE samples: none")
    if s["inference"]:
        lines += _inference_text(s)
    for c in s["recorded_commits"]:
        if c["how"] == "single":
            lines.append(
                f"  recorded commit: {c['goal']} at {_when(c['tick'], c['time'], LOGGED)}, "
                f"p = {c['p']:.3f} ({_HOW['single']})"
            )
    lines += [f"  MISMATCH: {m}" for m in s["mismatches"]]
    return lines


def _inference_text(s: dict[str, Any]) -> list[str]:
    p, rec = s["params"], s["recorded_params"]
    lines = [
        f"  observer: beta {p['beta']:g}, p_thresh {p['p_thresh']:g}, cost {p['cost']} "
        f"(recorded: beta {rec['beta']:g}, p_thresh {rec['p_thresh']:g}, cost {rec['cost']})"
    ]
    end = s["end_of_inference"]
    if end is None:
        lines.append("  replayed: nothing (no recorded posterior and no commit in this stage)")
    else:
        lines.append(
            f"  replayed: {s['replayed_samples']} samples, up to the end of inference at "
            f"{_when(end['tick'], end['time'])}: {_CAUSE[end['cause']]}"
        )
    commit = s["commit"]
    if commit is None:
        lines.append("  replayed commit: none" + ("" if end is None else f" by tick {end['tick']}"))
    else:
        lines += [
            f"  replayed commit: {commit['goal']} at "
            f"{_when(commit['tick'], commit['time'])}, p = {commit['p']:.3f}",
            f"    posterior at the commit: {_posterior(commit['posterior'])}",
        ]
    inferred = [c for c in s["recorded_commits"] if c["how"] != "single"]
    if not inferred:
        lines.append("  recorded commit: none")
    agree = {True: " (same goal)", False: " (DIFFERENT goal)", None: ""}[s["agrees"]]
    for n, c in enumerate(inferred):
        how = _HOW[c["how"]]
        if c["how"] != "inferred" and c["below_threshold"]:
            how += f", below p_thresh {s['p_thresh']:g} as expected"
        lines += [
            f"  recorded commit: {c['goal']} at {_when(c['tick'], c['time'], LOGGED)}, "
            f"p = {c['p']:.3f} ({how})" + (agree if n == 0 else ""),
            f"    recorded posterior at tick {c['posterior_tick']}: "
            + _posterior(c["recorded_posterior"]),
            f"    replayed posterior at tick {c['posterior_tick']}: "
            + _posterior(c["replayed_posterior"]),
        ]
    if end is not None and (commit is None or not inferred):
        lines += [
            f"  posterior at the end of inference, {_when(end['tick'], end['time'])} "
            f"({_CAUSE[end['cause']]}):",
            f"    recorded: {_posterior(end['recorded_posterior'])}",
            f"    replayed: {_posterior(end['replayed_posterior'])}",
        ]
    return lines


def render_text(report: dict[str, Any]) -> str:
    """The report as text, a block per stage."""
    n = len(report["stages"])
    lines = [
        f"Replay of {report['recording']}: {n} stage{'s' if n != 1 else ''} "
        f"(of {report['decisions']}, one per decision)",
        f"  {report['clocks']}",
    ]
    for s in report["stages"]:
        lines += _stage_text(s)
    if report.get("plot"):
        lines += ["", f"Plot: {report['plot']}"]
    return "\n".join(lines)


def plot_figure(recording: Path, stages: list[StageReplay]) -> Figure:
    """The ``--plot`` picture of the replayed stages, drawn and laid out."""
    # matplotlib loads only here: the other commands (and replay without --plot) never pay
    from legws_daemon.telemetry.posterior_plot import PlotCommit, StagePlot, posterior_figure

    plots = []
    for r in stages:
        d = r.decision
        if not len(d.ee.ticks):
            continue
        rec_times, rec_values = _broken_at_gaps(d.posterior)
        empty = np.empty((0, len(d.candidates)))
        commit = r.replay.commit if r.replay is not None else None
        thresh = r.params.p_thresh
        plots.append(
            StagePlot(
                label=f"{d.index} {d.label}" + ("" if d.goals is not None else " (single)"),
                start=float(d.ee.times[0]),
                end=float(d.ee.times[-1]),
                goals=d.goals.names if d.goals is not None else d.candidates,
                p_thresh=d.stage.p_thresh,
                replay_thresh=None if thresh == d.stage.p_thresh else thresh,
                recorded_times=rec_times if d.goals is not None else np.empty(0),
                recorded=rec_values if d.goals is not None else empty,
                replayed_times=r.replay.times if r.replay is not None else np.empty(0),
                replayed=r.replay.posteriors if r.replay is not None else empty,
                commits=[
                    PlotCommit(_seconds(c.seconds, c.tick, d.ee), c.goal, c.how, c.p)
                    for c in d.commits
                ],
                replayed_commit=None
                if commit is None
                else PlotCommit(commit["time"], commit["goal"], "inferred", commit["p"]),
                inference=d.goals is not None,
            )
        )
    return posterior_figure(plots, f"Posterior over time: {recording.name}")


def plot_png(recording: Path, stages: list[StageReplay]) -> bytes:
    """The ``--plot`` picture as PNG bytes."""
    from legws_daemon.telemetry.posterior_plot import figure_png

    return figure_png(plot_figure(recording, stages))


def _broken_at_gaps(posterior: Posterior) -> tuple[FloatArray, FloatArray]:
    """Times and values with a ``NaN`` row in every gap of ticks (no line drawn across)."""
    gaps = np.flatnonzero(np.diff(posterior.ticks) > 1) + 1
    times = np.insert(posterior.times, gaps, np.nan)
    values = np.insert(posterior.values, gaps, np.nan, axis=0)
    return times, values


def _seconds(seconds: float | None, tick: int, ee: EePath) -> float:
    """A commit's time: its own, else that of the latest EE sample at or before its tick."""
    if seconds is not None:
        return seconds
    i = max(int(np.searchsorted(ee.ticks, tick, side="right")) - 1, 0)
    return float(ee.times[i])


@click.command("replay")
@click.argument("recording", type=click.Path(path_type=Path))
@click.option(
    "--stage",
    help="Replay only this stage: its index (negative from the end), its name when only "
    "one stage has it, or NAME#K, the K-th stage of that name (default: every stage).",
)
@click.option(
    "--beta", type=FiniteFloat(), callback=_check_beta, help="Override the recorded beta (> 0)."
)
@click.option(
    "--threshold",
    type=FiniteFloat(),
    callback=_check_threshold,
    help="Override the recorded commit threshold p_thresh, in (0.5, 1).",
)
@click.option("--cost", type=click.Choice(COST_FORMS), help="Override the recorded cost form.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option(
    "--plot",
    type=click.Path(path_type=Path),
    help="Also draw the posterior over time to this PNG (1200x600).",
)
def replay_cmd(
    recording: Path,
    stage: str | None,
    beta: float | None,
    threshold: float | None,
    cost: CostForm | None,
    as_json: bool,
    plot: Path | None,
) -> None:
    """Re-run the intent observer on the EE path of RECORDING (a daemon .rrd).

    One stage per decision, single-candidate ones included. Reports, per stage, when
    (tick, time) and on which goal the observer would have committed with the recorded or
    overridden parameters, fed the EE path up to the end of inference (the daemon's last
    commit, else its last recorded posterior), and its posterior there; each commit the
    daemon logged, how it came (inferred, confirmed by the operator, single candidate),
    with the daemon's posterior and the replay's at that tick; and, where either did not
    commit, both posteriors at the end of inference. Ticks are the daemon's control ticks,
    times seconds on the recording's `time` timeline.
    """
    if plot is not None:
        output_path(plot)  # a folder or device there: one line before any work
    overrides: dict[str, Any] = {}
    if beta is not None:
        overrides["beta"] = beta
    if threshold is not None:
        overrides["p_thresh"] = threshold
    if cost is not None:
        overrides["cost"] = cost
    decisions = read_decisions(recording)
    chosen = decisions
    if stage is not None:
        chosen = [decisions[select_index([d.name for d in decisions], stage, str(recording))]]
    replays = [replay_decision(recording, d, overrides) for d in chosen]
    report = {
        "recording": str(recording),
        "decisions": len(decisions),
        "clocks": CLOCKS,
        "stages": [r.report for r in replays],
        "plot": None if plot is None else str(plot),
    }
    if plot is not None:
        write_atomic(plot, plot_png(recording, replays))
    if as_json:  # json.dumps writes every character outside printable ASCII as an escape
        click.echo(json.dumps(report, allow_nan=False))
    else:
        echo(render_text(report), limit=None)
