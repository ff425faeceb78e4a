"""``legws replay``: re-run the intent observer on the EE path of a daemon recording.

The observer (:class:`~legws_daemon.core.observer.IntentObserver`) is fed every recorded
EE pose of a stage, in tick order, from the stage's start pose ``x0``, with the stage's
recorded parameters unless overridden. The report says when and on which goal it would
have committed, the final posterior, and what the daemon itself logged as committed
(``commit goal=<name> p=<prob>`` lines of the recording's text log).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import click

from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import COST_FORMS, CostForm, Params
from legws_daemon.errors import InputError
from legws_daemon.telemetry.recording import (
    EePath,
    Stage,
    read_commits,
    read_ee_path,
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


def replay_stage(stage: Stage, path: EePath, params: Params, source: str) -> dict[str, Any]:
    """Run the observer on one stage's path: its commit (or ``None``) and final posterior."""
    observer = IntentObserver(stage.goals, params)
    names = stage.goals.names
    commit: dict[str, Any] | None = None
    for i, tick in enumerate(path.ticks.tolist()):
        try:
            post = observer.update(path.positions[i], path.quaternions[i])
        except InputError as err:
            raise InputError(str(err), source=source, field=f"world/ee tick {tick}") from None
        k = observer.committed
        if commit is None and k is not None:
            commit = {
                "goal": names[k],
                "tick": tick,
                "seconds": float(path.times[i]),
                "p": float(post[k]),
                "samples": i + 1,
            }
    final = dict(zip(names, observer.posterior.tolist(), strict=True))
    return {"commit": commit, "final_posterior": final}


def stage_report(source: Path, stage: Stage, overrides: dict[str, Any]) -> dict[str, Any]:
    """The replay report of one stage (one element of the ``stages`` list of ``--json``)."""
    ee = read_ee_path(source, stage.index)
    params = replace(stage.params, **overrides)
    result = replay_stage(stage, ee, params, str(source))
    recorded = [
        {"tick": tick, "goal": goal, "p": p} for tick, goal, p in read_commits(source, stage.index)
    ]
    first = recorded[0] if recorded else None
    commit = result["commit"]
    agrees = None if commit is None or first is None else commit["goal"] == first["goal"]
    ticks = ee.ticks.tolist()
    return {
        "index": stage.index,
        "name": stage.name,
        "scene": stage.scene,
        "goals": list(stage.goals.names),
        "samples": len(ticks),
        "first_tick": ticks[0] if ticks else None,
        "last_tick": ticks[-1] if ticks else None,
        "params": params.as_dict(),
        "recorded_params": stage.params.as_dict(),
        "commit": commit,
        "final_posterior": result["final_posterior"],
        "recorded_commit": first,
        "recorded_commits": recorded,
        "agrees": agrees,
    }


def _commit_line(what: str, commit: dict[str, Any] | None) -> str:
    if commit is None:
        return f"  {what}: none"
    when = f"tick {commit['tick']}"
    if "seconds" in commit:
        when += f" ({commit['seconds']:.3f} s)"
    return f"  {what}: {commit['goal']} at {when}, p = {commit['p']:.3f}"


def render_text(report: dict[str, Any]) -> str:
    lines = [f"Replay of {report['recording']}"]
    for s in report["stages"]:
        p, rec = s["params"], s["recorded_params"]
        name = f" '{s['name']}'" if s["name"] else ""
        span = f"ticks {s['first_tick']}..{s['last_tick']}" if s["samples"] else "no EE samples"
        agree = {True: " (same goal)", False: " (DIFFERENT goal)", None: ""}[s["agrees"]]
        final = ", ".join(f"{g} {v:.3f}" for g, v in s["final_posterior"].items())
        lines += [
            "",
            f"Stage {s['index']}{name} (scene {s['scene']}): {s['samples']} EE samples, {span}",
            f"  observer: beta {p['beta']:g}, p_thresh {p['p_thresh']:g}, cost {p['cost']} "
            f"(recorded: beta {rec['beta']:g}, p_thresh {rec['p_thresh']:g}, "
            f"cost {rec['cost']})",
            _commit_line("replayed commit", s["commit"]),
            _commit_line("recorded commit", s["recorded_commit"]) + agree,
            f"  final posterior: {final}",
        ]
    return "\n".join(lines)


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
def replay_cmd(
    recording: Path,
    stage: str | None,
    beta: float | None,
    threshold: float | None,
    cost: CostForm | None,
    as_json: bool,
) -> None:
    """Re-run the intent observer on the EE path of RECORDING (a daemon .rrd).

    Reports, per stage, when (tick, seconds) and on which goal the observer would have
    committed with the recorded or overridden parameters, the final posterior, and the
    commit the daemon logged.
    """
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
    report = {
        "recording": str(recording),
        "stages": [stage_report(recording, s, overrides) for s in stages],
    }
    click.echo(json.dumps(report, allow_nan=False) if as_json else render_text(report))
