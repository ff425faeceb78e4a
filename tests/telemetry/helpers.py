"""Synthetic daemon episodes written with :class:`RerunLog`, shared by the telemetry and
replay tests."""

from __future__ import annotations

import json
import subprocess
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import Params
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.visual import RobotVisual, robot_visual
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.telemetry.rerun_log import RerunLog
from legws_daemon.telemetry.rrd_file import rerun_cli
from legws_daemon.telemetry.snapshot import TickSnapshot

#: The ``rerun`` executable the daemon uses (``rerun rrd verify`` works headless).
RERUN = rerun_cli()


@cache
def _arm() -> World:
    world = World(load_scene("breakfast_easy"))
    home = world.scene.home
    world.set_q(home_configuration(world, home.position, home.rotation).q)
    return world


def arm_visual() -> RobotVisual:
    """The Sawyer's meshes (the real robot model, as the daemon draws it)."""
    return robot_visual(_arm())


@cache
def _arm_poses(k: int) -> tuple[FloatArray, FloatArray]:
    """Link poses of the real arm for sample ``k``: the home pose, the base joint turned
    by ``0.01 k`` rad (so the links move from sample to sample)."""
    world = _arm().twin()
    q = world.q
    q[0] += 0.01 * k
    return world.link_poses(q)


@dataclass(frozen=True)
class Episode:
    """A straight EE path at ``v_max`` from ``x0`` to one goal, then held there."""

    scene: Scene
    goals: GoalSet
    params: Params
    target: str
    positions: FloatArray  # (K, 3)

    @property
    def quaternion(self) -> FloatArray:
        return self.goals.x0.quaternion


def straight_episode(
    scene: str = "breakfast_easy",
    target: str = "banana",
    hold: int = 5,
    params: Params | None = None,
) -> Episode:
    sc = load_scene(scene)
    goals = sc.goal_set()
    p = params or Params()
    x0, goal = goals.x0.position, goals.positions[goals.index(target)]
    n = int(np.ceil(np.linalg.norm(goal - x0) / (p.v_max * p.dt)))
    path = x0 + (goal - x0) * (np.arange(1, n + 1) / n)[:, None]
    path = np.vstack([path, np.repeat(goal[None], hold, axis=0)])
    return Episode(sc, goals, p, target, path)


def objects_of(scene: Scene) -> dict[str, tuple[FloatArray, FloatArray]]:
    poses = scene.poses()
    return {
        name: (
            np.array([p.x, p.y, scene.z_center(name)]),
            np.array([np.cos(p.yaw / 2), 0.0, 0.0, np.sin(p.yaw / 2)]),
        )
        for name, p in poses.items()
    }


def setup(log: RerunLog, ep: Episode, stage: str | None = None) -> None:
    log.log_setup(
        scene=ep.scene,
        goals=ep.goals,
        goal_objects={g: g for g in ep.goals.names},
        planned=ep.scene.default_layout(),
        p_thresh=ep.params.p_thresh,
        params_json=json.dumps(ep.params.as_dict()),
        stage=stage,
    )


def tick_kwargs(ep: Episode, k: int, posterior: dict[str, float] | None) -> dict[str, Any]:
    """Arguments of ``log_tick`` for sample ``k`` (joystick released while holding)."""
    x = ep.positions[k]
    moving = k + 1 < len(ep.positions) and not np.array_equal(ep.positions[k + 1], x)
    direction = ep.goals.positions[ep.goals.index(ep.target)] - ep.goals.x0.position
    direction = direction / np.linalg.norm(direction)
    links, rotations = _arm_poses(k)
    return {
        "link_positions": links,
        "link_rotations": rotations,
        "ee_position": x,
        "ee_quaternion": ep.quaternion,
        "objects": objects_of(ep.scene),
        "posterior": posterior,
        "joystick": direction if moving else None,
        "command": direction * ep.params.v_max if moving else np.zeros(3),
        "mode": "teleop",
        "slack": 0.1,
        "committed": None,
        "tick_seconds": 0.001,
        "gripper_half_gap": 0.042,
        "phase": "infer",
        "operator": "sim_user",
        "fault": None,
    }


def log_episode(
    log: RerunLog, ep: Episode, *, tick0: int = 0, stage: str | None = None
) -> int | None:
    """Log a stage as the daemon would (commit line included); the commit tick or None."""
    setup(log, ep, stage)
    observer = IntentObserver(ep.goals, ep.params)
    commit_tick = None
    for k in range(len(ep.positions)):
        tick = tick0 + k
        post = observer.update(ep.positions[k], ep.quaternion)
        kwargs = tick_kwargs(ep, k, dict(zip(ep.goals.names, post.tolist(), strict=True)))
        if observer.committed is not None:
            goal = ep.goals.names[observer.committed]
            kwargs.update(committed=goal, mode="assist")
            if commit_tick is None:
                commit_tick = tick
                log.log_commit(tick, tick * ep.params.dt, goal, float(post[observer.committed]))
        log.log_tick(TickSnapshot(tick, tick * ep.params.dt, **kwargs))
    last = tick0 + len(ep.positions) - 1
    log.log_text(last, last * ep.params.dt, "warning", "episode end")
    return commit_tick


def record(path: Path, *episodes: Episode) -> list[int | None]:
    """Write ``episodes`` as consecutive stages ``s0``, ``s1``...; their commit ticks."""
    commits = []
    tick0 = 0
    with RerunLog(f"save:{path}", robot="sawyer-sim", tick_period=0.05) as log:
        log.log_robot(arm_visual())
        for i, ep in enumerate(episodes):
            commits.append(log_episode(log, ep, tick0=tick0, stage=f"s{i}"))
            tick0 += len(ep.positions)
    return commits


def verify(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(RERUN), "rrd", "verify", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def raw_recording(path: Path, robot: str = "sawyer-sim") -> Path:
    """A recording as the daemon leaves it when killed: two stages written as the daemon
    writes them, closed without the finishing step (no footer)."""
    log = RerunLog(f"save:{path}", robot=robot)
    first = straight_episode("breakfast_easy", "banana", hold=2)
    log_episode(log, first, stage="easy")
    log.flush()
    second = straight_episode("desk", "white_mug", hold=2)
    log_episode(log, second, tick0=len(first.positions), stage="desk")
    log.close(finish_file=False)
    assert log.finished is None
    return path
