"""``legws replay``: re-run the intent observer on the EE path of a daemon recording.

The observer (:class:`~legws_daemon.core.observer.IntentObserver`) is fed every recorded
EE pose of a stage, in tick order, from the stage's start pose ``x0``, with the stage's
recorded parameters unless overridden. The report says, per stage, when and on which goal
it would have committed and its posterior at that tick; every commit the daemon logged
(``commit goal=<name> p=<prob>`` lines of the text log, with how it came: inferred,
confirmed by the operator, or single candidate) with the daemon's own posterior
(``plots/posterior/*``) and the replay's at that tick; and the posterior at the end of
inference (the stage's last tick with a recorded posterior), not after it: once the
daemon stops inferring, the arm moves on its own (to the goal, home) and a posterior of
that path means nothing. ``--plot`` draws the posterior over time
(:mod:`legws_daemon.telemetry.posterior_plot`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import click
import numpy as np

from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import COST_FORMS, CostForm, Params
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path, write_atomic
from legws_daemon.telemetry.recording import (
    EePath,
    Posterior,
    RecordedCommit,
    Stage,
    read_ee_path,
    read_posterior,
    read_recorded_commits,
    read_stages,
    select_stage,
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
class Replay:
    """The observer run over one stage's EE path.

    Attributes:
        goals: the goal names.
        ticks: ``(K,)`` ticks of the samples.
        times: ``(K,)`` their seconds.
        posteriors: ``(K, M)`` the posterior after each sample.
        prior: ``(M,)`` the posterior before any sample (uniform).
        commit: the first commit (goal, tick, seconds, p, samples, posterior), or None.
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


def replay_stage(stage: Stage, path: EePath, params: Params, source: str) -> Replay:
    """Run the observer on one stage's path: its posterior at every sample and its commit."""
    observer = IntentObserver(stage.goals, params)
    names = stage.goals.names
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
                "seconds": float(path.times[i]),
                "p": float(post[k]),
                "samples": i + 1,
                "posterior": dict(zip(names, post.tolist(), strict=True)),
            }
    return Replay(tuple(names), path.ticks, path.times, posteriors, prior, commit)


@dataclass(frozen=True)
class StageReplay:
    """Everything read and computed for one stage: the report and what the plot needs."""

    stage: Stage
    params: Params
    ee: EePath
    replay: Replay
    posterior: Posterior
    commits: list[RecordedCommit]
    report: dict[str, Any]


def replay_recorded_stage(source: Path, stage: Stage, overrides: dict[str, Any]) -> StageReplay:
    """Read one stage of ``source``, replay it and build its report."""
    ee = read_ee_path(source, stage.index)
    params = replace(stage.params, **overrides)
    replay = replay_stage(stage, ee, params, str(source))
    posterior = read_posterior(source, stage.index)
    commits = read_recorded_commits(source, stage.index)
    recorded = [_recorded_commit(c, stage, posterior, replay) for c in commits]
    first = recorded[0] if recorded else None
    commit = replay.commit
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
                f"below p_thresh {stage.p_thresh:g}"
            )
    ticks = ee.ticks.tolist()
    report = {
        "index": stage.index,
        "name": stage.name,
        "scene": stage.scene,
        "goals": list(stage.goals.names),
        "samples": len(ticks),
        "first_tick": ticks[0] if ticks else None,
        "last_tick": ticks[-1] if ticks else None,
        "params": params.as_dict(),
        "recorded_params": stage.params.as_dict(),
        "p_thresh": stage.p_thresh,
        "commit": commit,
        "recorded_commit": first,
        "recorded_commits": recorded,
        "posterior_at_end_of_inference": _end_of_inference(posterior, replay),
        "agrees": agrees,
        "mismatches": mismatches,
    }
    return StageReplay(stage, params, ee, replay, posterior, commits, report)


def stage_report(source: Path, stage: Stage, overrides: dict[str, Any]) -> dict[str, Any]:
    """The replay report of one stage (one element of the ``stages`` list of ``--json``)."""
    return replay_recorded_stage(source, stage, overrides).report


def _recorded_commit(
    c: RecordedCommit, stage: Stage, posterior: Posterior, replay: Replay
) -> dict[str, Any]:
    """A commit the daemon logged, with its posterior and the replay's at that tick."""
    row = posterior.row_at(c.tick)
    tick = c.tick if row is None else int(posterior.ticks[row])
    return {
        "tick": c.tick,
        "seconds": c.seconds,
        "goal": c.goal,
        "p": c.p,
        "how": c.how,
        "below_threshold": c.p < stage.p_thresh,
        "posterior_tick": tick,
        "recorded_posterior": None if row is None else posterior.as_dict(row),
        "replayed_posterior": replay.at(tick),
    }


def _end_of_inference(posterior: Posterior, replay: Replay) -> dict[str, Any] | None:
    """The posteriors at the stage's last tick with a recorded posterior (None: no such)."""
    if not len(posterior.ticks):
        return None
    tick = int(posterior.ticks[-1])
    seconds = float(posterior.times[-1])
    return {
        "tick": tick,
        "seconds": seconds if math.isfinite(seconds) else None,
        "recorded_posterior": posterior.as_dict(len(posterior.ticks) - 1),
        "replayed_posterior": replay.at(tick),
    }


_HOW = {
    "inferred": "inferred",
    "confirmed": "confirmed by the operator",
    "single": "single candidate, no inference",
}


def _when(tick: int, seconds: float | None) -> str:
    return f"tick {tick}" + ("" if seconds is None else f" ({seconds:.3f} s)")


def _posterior(values: dict[str, float | None]) -> str:
    return ", ".join(f"{g} {'-' if v is None else f'{v:.3f}'}" for g, v in values.items())


def _stage_text(s: dict[str, Any]) -> list[str]:
    p, rec = s["params"], s["recorded_params"]
    name = f" '{s['name']}'" if s["name"] else ""
    span = f"ticks {s['first_tick']}..{s['last_tick']}" if s["samples"] else "no EE samples"
    lines = [
        "",
        f"Stage {s['index']}{name} (scene {s['scene']}): {s['samples']} EE samples, {span}",
        f"  observer: beta {p['beta']:g}, p_thresh {p['p_thresh']:g}, cost {p['cost']} "
        f"(recorded: beta {rec['beta']:g}, p_thresh {rec['p_thresh']:g}, cost {rec['cost']})",
    ]
    commit = s["commit"]
    if commit is None:
        lines.append("  replayed commit: none")
    else:
        lines += [
            f"  replayed commit: {commit['goal']} at "
            f"{_when(commit['tick'], commit['seconds'])}, p = {commit['p']:.3f}",
            f"    posterior at the commit: {_posterior(commit['posterior'])}",
        ]
    if not s["recorded_commits"]:
        lines.append("  recorded commit: none")
    agree = {True: " (same goal)", False: " (DIFFERENT goal)", None: ""}[s["agrees"]]
    for n, c in enumerate(s["recorded_commits"]):
        how = _HOW[c["how"]]
        if c["how"] != "inferred" and c["below_threshold"]:
            how += f", below p_thresh {s['p_thresh']:g} as expected"
        lines.append(
            f"  recorded commit: {c['goal']} at {_when(c['tick'], c['seconds'])}, "
            f"p = {c['p']:.3f} ({how})" + (agree if n == 0 else "")
        )
        if c["how"] == "single":
            continue  # a stage of one candidate infers nothing: no posterior to show
        lines += [
            f"    recorded posterior at tick {c['posterior_tick']}: "
            + ("none" if c["recorded_posterior"] is None else _posterior(c["recorded_posterior"])),
            f"    replayed posterior at tick {c['posterior_tick']}: "
            + _posterior(c["replayed_posterior"]),
        ]
    end = s["posterior_at_end_of_inference"]
    if commit is None or not s["recorded_commits"]:
        if end is None:
            lines.append("  posterior at the end of inference: none recorded in this stage")
        else:
            lines += [
                f"  posterior at the end of inference ({_when(end['tick'], end['seconds'])}):",
                f"    recorded: {_posterior(end['recorded_posterior'])}",
                f"    replayed: {_posterior(end['replayed_posterior'])}",
            ]
    lines += [f"  MISMATCH: {m}" for m in s["mismatches"]]
    return lines


def render_text(report: dict[str, Any]) -> str:
    """The report as text, a block per stage."""
    lines = [f"Replay of {report['recording']}"]
    for s in report["stages"]:
        lines += _stage_text(s)
    if report.get("plot"):
        lines += ["", f"Plot: {report['plot']}"]
    return "\n".join(lines)


def plot_png(recording: Path, stages: list[StageReplay]) -> bytes:
    """The ``--plot`` picture of the replayed stages."""
    # matplotlib loads only here: the other commands (and replay without --plot) never pay
    from legws_daemon.telemetry.posterior_plot import PlotCommit, StagePlot, posterior_png

    plots = []
    for r in stages:
        if not len(r.ee.ticks):
            continue
        times, posts = r.replay.times, r.replay.posteriors
        if len(r.posterior.ticks):  # the replay up to its commit or the end of inference
            last = max(int(r.posterior.ticks[-1]), (r.replay.commit or {}).get("tick", 0))
            keep = r.replay.ticks <= last
            times, posts = times[keep], posts[keep]
        rec_times, rec_values = _broken_at_gaps(r.posterior)
        name = f" '{r.stage.name}'" if r.stage.name else ""
        commit = r.replay.commit
        thresh = r.params.p_thresh
        plots.append(
            StagePlot(
                label=f"stage {r.stage.index}{name}",
                start=float(r.ee.times[0]),
                end=float(r.ee.times[-1]),
                goals=r.replay.goals,
                p_thresh=r.stage.p_thresh,
                replay_thresh=None if thresh == r.stage.p_thresh else thresh,
                recorded_times=rec_times,
                recorded=rec_values,
                replayed_times=times,
                replayed=posts,
                commits=[
                    PlotCommit(_seconds(c.seconds, c.tick, r.ee), c.goal, c.how, c.p)
                    for c in r.commits
                ],
                replayed_commit=None
                if commit is None
                else PlotCommit(commit["seconds"], commit["goal"], "inferred", commit["p"]),
            )
        )
    return posterior_png(plots, f"Posterior over time: {recording.name}")


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
    help="Replay only this stage (its name or index; default: every stage).",
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

    Reports, per stage, when (tick, seconds) and on which goal the observer would have
    committed with the recorded or overridden parameters and its posterior there; each
    commit the daemon logged, how it came (inferred, confirmed by the operator, single
    candidate), with the daemon's posterior and the replay's at that tick; and the
    posterior at the end of inference.
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
    stages = read_stages(recording)
    if stage is not None:
        stages = [select_stage(stages, stage, str(recording))]
    replays = [replay_recorded_stage(recording, s, overrides) for s in stages]
    report = {
        "recording": str(recording),
        "stages": [r.report for r in replays],
        "plot": None if plot is None else str(plot),
    }
    if plot is not None:
        write_atomic(plot, plot_png(recording, replays))
    click.echo(json.dumps(report, allow_nan=False) if as_json else render_text(report))
