"""``legws replay``: the posterior at the commit, how each commit came, the end of inference.

The recording has three stages written with :class:`RerunLog` as the daemon would:

* ``confirmed``: the person steers to the banana; the operator confirms at a posterior
  below the threshold; the daemon stops inferring (no posterior logged), drives to the
  banana and back home.
* ``abandoned``: the person steers a quarter of the way to the stapler, no commit; the
  arm goes home without inference.
* ``single``: one candidate (set up by its name, as the daemon does), a ``how=single``
  commit and no posterior at all.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.observer import IntentObserver
from legws_daemon.formats.log_lines import How, commit_text
from legws_daemon.telemetry.rerun_log import RerunLog
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.cli.helpers import Result
from tests.telemetry.helpers import Episode, setup, straight_episode, tick_kwargs

Cli = Callable[..., Result]

HOME = 20  # samples from where inference stopped back to x0


@dataclass(frozen=True)
class Logged:
    """One stage as logged: its EE path, first tick, the last sample with a posterior."""

    episode: Episode
    path: FloatArray
    tick0: int
    stop: int  # index in ``path`` of the last sample with a posterior (-1: none)

    def observer_at(self, k: int) -> dict[str, float]:
        """The observer's posterior after samples ``0..k`` of the path, computed afresh."""
        observer = IntentObserver(self.episode.goals, self.episode.params)
        for x in self.path[: k + 1]:
            observer.update(x, self.episode.quaternion)
        return dict(zip(self.episode.goals.names, observer.posterior.tolist(), strict=True))


def _home(ep: Episode, start: FloatArray) -> FloatArray:
    x0 = ep.goals.x0.position
    return start + (x0 - start) * (np.arange(1, HOME + 1) / HOME)[:, None]


def _log_stage(
    log: RerunLog,
    ep: Episode,
    path: FloatArray,
    *,
    tick0: int,
    stage: str,
    stop: int,
    line: tuple[How, str] | None,
    single: str | None = None,
) -> Logged:
    """Log ``path`` with the posterior up to sample ``stop``, the commit line (if any) there
    (``single``: a stage of that one candidate, set up by its name)."""
    if single is None:
        setup(log, ep, stage)
    else:
        log.log_setup(
            scene=ep.scene,
            goals=[single],
            goal_objects={single: single},
            planned=ep.scene.default_layout(),
            p_thresh=ep.params.p_thresh,
            params_json=json.dumps(ep.params.as_dict()),
            stage=stage,
        )
    steered = Episode(ep.scene, ep.goals, ep.params, ep.target, path)
    observer = IntentObserver(ep.goals, ep.params)
    for k in range(len(path)):
        tick, t = tick0 + k, (tick0 + k) * ep.params.dt
        posterior = None
        if k <= stop:
            post = observer.update(path[k], ep.quaternion)
            posterior = dict(zip(ep.goals.names, post.tolist(), strict=True))
        if line is not None and k == max(stop, 0):
            how, goal = line
            p = posterior[goal] if posterior else 1.0
            log.log_text(tick, t, "INFO", commit_text(goal, round(p, 4), how=how))
        log.log_tick(TickSnapshot(tick, t, **tick_kwargs(steered, k, posterior)))
    return Logged(ep, path, tick0, stop)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Logged]]:
    path = tmp_path_factory.mktemp("replay-commits") / "commits.rrd"
    banana = straight_episode("breakfast_easy", "banana")
    stapler = straight_episode("desk", "black_stapler")
    mug = straight_episode("desk", "white_mug", hold=0)
    confirm = 30  # p(banana) ~ 0.73
    quarter = len(stapler.positions) // 4
    stages = []
    with RerunLog(f"save:{path}", robot="sawyer-sim") as log:
        to_goal = np.vstack([banana.positions, _home(banana, banana.positions[-1])])
        stages.append(
            _log_stage(log, banana, to_goal, tick0=0, stage="confirmed", stop=confirm,
                       line=("confirmed", "banana"))
        )  # fmt: skip
        tick0 = len(to_goal)
        halfway = np.vstack(
            [stapler.positions[: quarter + 1], _home(stapler, stapler.positions[quarter])]
        )
        stages.append(
            _log_stage(log, stapler, halfway, tick0=tick0, stage="abandoned", stop=quarter,
                       line=None)
        )  # fmt: skip
        tick0 += len(halfway)
        stages.append(
            _log_stage(log, mug, mug.positions[:5], tick0=tick0, stage="single", stop=-1,
                       line=("single", "white_mug"), single="white_mug")
        )  # fmt: skip
    return path, stages


def _report(cli: Cli, *argv: str | Path) -> dict[str, Any]:
    result = cli("replay", *argv, "--json")
    assert result.code == 0, result
    report: dict[str, Any] = json.loads(result.out)
    return report


def _approx(posterior: dict[str, float]) -> Any:
    return pytest.approx(posterior, rel=1e-12, abs=1e-15)


def test_a_confirmed_commit_below_the_threshold(
    cli: Cli, recording: tuple[Path, list[Logged]]
) -> None:
    path, (logged, _, _) = recording
    stage = _report(cli, path, "--stage", "confirmed")["stages"][0]
    (commit,) = stage["recorded_commits"]
    confirm_tick = logged.tick0 + logged.stop
    expected = logged.observer_at(logged.stop)
    assert expected["banana"] < 0.9
    assert (commit["tick"], commit["goal"], commit["how"]) == (confirm_tick, "banana", "confirmed")
    assert commit["time"] == pytest.approx(confirm_tick * 0.05)
    assert commit["p"] == round(expected["banana"], 4)
    assert commit["below_threshold"] is True
    assert commit["posterior_tick"] == confirm_tick
    assert commit["recorded_posterior"] == expected  # logged as the daemon saw it
    assert commit["replayed_posterior"] == _approx(expected)
    # the replay stops where the operator confirmed: after it the arm drove to the banana
    # on its own, and a posterior of that path (which commits, see below) means nothing
    assert stage["replayed_samples"] == logged.stop + 1
    assert stage["commit"] is None and stage["agrees"] is None
    assert logged.observer_at(len(logged.path) - HOME - 1)["banana"] > 0.9
    assert stage["mismatches"] == []
    end = stage["end_of_inference"]
    assert (end["tick"], end["cause"]) == (confirm_tick, "commit")
    assert end["time"] == pytest.approx(confirm_tick * 0.05)
    assert end["recorded_posterior"] == expected
    assert end["replayed_posterior"] == _approx(expected)


def test_without_a_commit_the_posterior_at_the_end_of_inference(
    cli: Cli, recording: tuple[Path, list[Logged]]
) -> None:
    path, (_, logged, _) = recording
    stage = _report(cli, path, "--stage", "abandoned")["stages"][0]
    assert stage["commit"] is None
    assert stage["recorded_commits"] == [] and stage["recorded_commit"] is None
    end = stage["end_of_inference"]
    end_tick = logged.tick0 + logged.stop
    expected = logged.observer_at(logged.stop)
    assert (end["tick"], end["time"]) == (end_tick, pytest.approx(end_tick * 0.05))
    assert end["cause"] == "last posterior"
    assert stage["replayed_samples"] == logged.stop + 1
    assert end["recorded_posterior"] == expected
    assert end["replayed_posterior"] == _approx(expected)
    at_home = logged.observer_at(len(logged.path) - 1)  # what the old report showed
    assert at_home == _approx(dict.fromkeys(at_home, 1 / 3))
    assert max(expected.values()) > 0.4
    assert stage["last_tick"] == logged.tick0 + len(logged.path) - 1


def test_a_single_candidate_commit_has_no_posterior(
    cli: Cli, recording: tuple[Path, list[Logged]]
) -> None:
    path, (_, _, logged) = recording
    stage = _report(cli, path, "--stage", "single")["stages"][0]
    assert (stage["inference"], stage["set_up"], stage["candidates"]) == (
        False,
        True,
        ["white_mug"],
    )
    (commit,) = stage["recorded_commits"]
    assert (commit["tick"], commit["how"], commit["p"]) == (logged.tick0, "single", 1.0)
    assert commit["recorded_posterior"] is None  # not the previous stage's
    assert commit["replayed_posterior"] is None  # nothing inferred, nothing replayed
    assert stage["commit"] is None and stage["replayed_samples"] == 0
    assert stage["end_of_inference"] is None
    assert stage["mismatches"] == []


def test_the_text_report_marks_how_each_commit_came(
    cli: Cli, recording: tuple[Path, list[Logged]]
) -> None:
    path, (confirmed, abandoned, single) = recording
    result = cli("replay", path)
    assert result.code == 0 and result.err == ""
    out = result.out
    tick = confirmed.tick0 + confirmed.stop
    p = round(confirmed.observer_at(confirmed.stop)["banana"], 4)
    assert (
        f"recorded commit: banana at tick {tick} (logged at time {tick * 0.05:.3f} s), "
        f"p = {p:.3f} (confirmed by the operator, below p_thresh 0.9 as expected)\n"
    ) in out
    assert f"recorded posterior at tick {tick}: cereal_box " in out
    assert f"replayed commit: none by tick {tick}\n" in out
    end = abandoned.tick0 + abandoned.stop
    assert (
        f"posterior at the end of inference, tick {end} (time {end * 0.05:.3f} s) "
        "(its last recorded posterior):"
    ) in out
    assert "Stage 2 single (scene desk): a single candidate, white_mug: no inference" in out
    assert f"recorded commit: white_mug at tick {single.tick0} " in out
    assert "(single candidate, no inference)" in out
    assert "MISMATCH" not in out
    assert "final posterior" not in out


def test_an_inferred_commit_below_the_threshold_is_a_mismatch(cli: Cli, tmp_path: Path) -> None:
    path = tmp_path / "low.rrd"
    ep = straight_episode("breakfast_easy", "banana")
    with RerunLog(f"save:{path}", robot="r") as log:
        _log_stage(log, ep, ep.positions[:8], tick0=0, stage="low", stop=5,
                   line=("inferred", "banana"))  # fmt: skip
    (stage,) = _report(cli, path)["stages"]
    assert stage["recorded_commit"]["below_threshold"] is True
    (mismatch,) = stage["mismatches"]
    assert "inferred commit on banana at tick 5" in mismatch and "below p_thresh 0.9" in mismatch
    text = cli("replay", path).out
    assert "  MISMATCH: inferred commit on banana at tick 5" in text
    assert "(inferred)" in text
