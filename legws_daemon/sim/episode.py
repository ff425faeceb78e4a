"""One shared-autonomy episode on the stand-in (method.md §8).

The simulated user of §2 pushes the joystick toward the true goal's grasp position with
Gaussian velocity noise; the robot moves its EE at ``v_max * u`` with ``|u|`` clipped to 1,
orientation held, through the arm's differential kinematics (joint speed and position
limits respected). The observer runs every tick on the EE position the arm actually
reached. The episode ends at the first commit, when the EE arrives at the grasp position,
or at the timeout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import Params
from legws_daemon.robot.kinematics import small_rotation_error, velocity_step
from legws_daemon.robot.world import World

#: Episode limit of the paper's protocol, seconds.
TIMEOUT_S = 30.0
#: The EE has arrived when it is this close to the grasp position, metres.
ARRIVAL_TOLERANCE = 0.01
#: Gain holding the EE orientation during teleoperation, 1/s.
ORIENTATION_GAIN = 2.0


@dataclass(frozen=True, slots=True)
class EpisodeResult:
    """Outcome of one episode.

    Attributes:
        true_goal: what the simulated user wanted.
        committed: the goal the observer committed to, or ``None``.
        commit_time: seconds from motion onset to the commit, or ``None``.
        final_goal: the inferred goal at the end (the commitment, else the argmax).
        arrived: the EE reached the grasp position before any commit.
        duration: seconds simulated.
    """

    true_goal: str
    committed: str | None
    commit_time: float | None
    final_goal: str
    arrived: bool
    duration: float

    @property
    def correct(self) -> bool:
        return self.final_goal == self.true_goal


def run_episode(
    world: World,
    goals: GoalSet,
    true_goal: str,
    q_home: FloatArray,
    rng: np.random.Generator,
    params: Params | None = None,
    *,
    timeout: float = TIMEOUT_S,
) -> EpisodeResult:
    """Run one episode from the home configuration toward ``true_goal``'s grasp."""
    params = params or Params()
    dt, v_max = params.dt, params.v_max
    world.set_q(q_home)
    observer = IntentObserver(goals, params)
    target = goals.positions[goals.index(true_goal)]
    hold = goals.x0.rotation
    ticks = math.ceil(timeout / dt - 1e-9)
    noise = rng.standard_normal((ticks, 3)) * (params.sigma / v_max)
    arrived = False
    twist = np.zeros(6)
    tick = 0
    for tick in range(1, ticks + 1):
        p = world.ee_position()
        to_goal = target - p
        dist = math.sqrt(float(to_goal @ to_goal))
        u = (to_goal / dist if dist > 1e-9 else np.zeros(3)) + noise[tick - 1]
        norm = math.sqrt(float(u @ u))
        if norm > 1.0:
            u = u / norm
        twist[:3] = v_max * u
        twist[3:] = ORIENTATION_GAIN * small_rotation_error(world.ee_rotation(), hold)
        velocity_step(world, twist, dt)
        here = world.ee_position()
        observer.update(here)
        if observer.committed is not None:
            break
        left = target - here
        if float(left @ left) < ARRIVAL_TOLERANCE**2:
            arrived = True
            break
    committed = observer.committed
    final = committed if committed is not None else int(np.argmax(observer.posterior))
    return EpisodeResult(
        true_goal=true_goal,
        committed=goals.names[committed] if committed is not None else None,
        commit_time=observer.commit_tick * dt if observer.commit_tick is not None else None,
        final_goal=goals.names[final],
        arrived=arrived,
        duration=tick * dt,
    )
