"""Help before the commit: the operator's deflection combined with the robot's guess.

Pure math on one tick's numbers (the controller calls it; docs/decisions.md argues why
inference never sees the result). Three policies share the commit of method.md §9; they
differ in what the arm does *before* it (a fourth, ``none``, is teleoperation alone: no
commit, the operator's gripper button grasps):

- ``commit`` — nothing: the EE moves at ``v_max · u`` until the commit.
- ``blend`` — policy blending (Dragan & Srinivasa 2013): the command is
  ``(1 − α) · v_max · u + α · r``, where ``r`` is the robot's motion toward the most likely
  goal and ``α`` the arbitration weight :func:`arbitration` of that goal's posterior
  ``p`` among ``n``: ``α = α_max · clip((p − 1/n) / (p_full − 1/n), 0, 1)`` with
  ``p_full = 1/n + FULL_SHARE · (p_thresh − 1/n)`` — nothing at a uniform posterior, all
  of it a tenth of the way to the commit threshold (Dragan and Srinivasa's "aggressive"
  arbitration: at p = 0.20 of eight goals, 0.39 of three, 0.54 of two).
- ``hindsight`` — the hindsight-optimisation baseline (Javdani et al. 2015, as
  ``personalrobotics/ada_assistance_policy`` implements it): the operator's motion plus the
  posterior-weighted mean of each goal's assistance, ``v_max · u + Σ_g b(g) · a_g``, where
  ``a_g`` is minus the gradient of a Huber cost-to-go on the distance to ``g``
  (:func:`huber_pull`, that code's constants) taken after the operator's step.

Both scale the robot's part by the stick's deflection ``‖u‖``: a centred stick stops the
arm whatever the robot believes (the stick is the dead-man switch of assistance too), and
the robot never moves faster than the person asks it to. The sum is left to the adapter's
envelope (speed at most ``max(v_max, assist_speed)``, the workspace box).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray

#: The assistance policies (profile ``control.assist``, ``--assist``).
AssistPolicy = Literal["commit", "blend", "hindsight", "none"]
POLICIES: tuple[str, ...] = get_args(AssistPolicy)

#: The blend's largest arbitration weight ...
ALPHA_MAX = 1.0
#: ... reached this share of the way from a uniform posterior to the commit threshold.
FULL_SHARE = 0.1
#: Within this distance the robot's motion toward a goal slows down (proportionally), m.
SLOW_RADIUS = 0.05

#: Huber cost-to-go of the hindsight baseline (ada_assistance_policy's
#: HuberAssistancePolicy): linear beyond :data:`HUBER_SWITCH`, quadratic inside it.
HUBER_LINEAR = 2.25
HUBER_SWITCH = 0.07  # m
HUBER_CONSTANT = 0.2
#: ... divided by the robot's translation cost (that code's 40): at most 0.061 m/s.
HUBER_ROBOT_COST = 40.0
#: ... and within this distance faded out proportionally (that code's "not jumpy" part), m.
HUBER_FADE = 0.02


@dataclass(frozen=True, slots=True)
class Blended:
    """One tick's command before the commit, split by who asked for it.

    Attributes:
        velocity: (3,) the EE velocity to send, m/s (the adapter's envelope clips it).
        operator: (3,) the operator's part, m/s.
        robot: (3,) the robot's part, m/s (zero for ``commit``).
        weight: the arbitration weight (``blend``), or the posterior mass the robot acted
            on (``hindsight``: the guess's posterior); 0 for ``commit``.
        guess: the index of the goal the robot moves toward (``blend``), or of the most
            likely one (``hindsight``); ``None`` when the robot's part is zero.
    """

    velocity: FloatArray
    operator: FloatArray
    robot: FloatArray
    weight: float
    guess: int | None

    @property
    def robot_speed(self) -> float:
        return float(np.linalg.norm(self.robot))

    @property
    def operator_speed(self) -> float:
        return float(np.linalg.norm(self.operator))


def arbitration(
    p: float, n: int, p_thresh: float, alpha_max: float = ALPHA_MAX, share: float = FULL_SHARE
) -> float:
    """The blend's arbitration weight of a goal with posterior ``p`` among ``n``: 0 at or
    below the uniform ``1/n``, rising linearly to ``alpha_max`` at ``share`` of the way to
    ``p_thresh``, constant above it."""
    if n < 2:
        return alpha_max
    low = 1.0 / n
    if not p_thresh > low:
        return alpha_max if p >= p_thresh else 0.0
    full = low + share * (p_thresh - low)
    c = (p - low) / (full - low)
    return alpha_max * min(1.0, max(0.0, c))


def toward(position: ArrayLike, goal: ArrayLike, speed: float) -> FloatArray:
    """The robot's motion from ``position`` toward ``goal`` at ``speed``, slowing down
    proportionally within :data:`SLOW_RADIUS` (zero on the goal)."""
    d = np.asarray(goal, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    dist = math.sqrt(float(d @ d))
    if dist < 1e-9:
        return np.zeros(3)
    return d * (speed * min(1.0, dist / SLOW_RADIUS) / dist)


def huber_cost(distance: ArrayLike) -> FloatArray:
    """The hindsight baseline's cost-to-go of a distance to a goal (m): quadratic within
    :data:`HUBER_SWITCH`, linear beyond, continuous with its derivative."""
    d = np.asarray(distance, dtype=np.float64)
    quadratic = HUBER_LINEAR / HUBER_SWITCH
    near = 0.5 * quadratic * d * d + HUBER_CONSTANT * d
    far = (HUBER_LINEAR + HUBER_CONSTANT) * d - 0.5 * HUBER_LINEAR * HUBER_SWITCH
    return np.asarray(np.where(d <= HUBER_SWITCH, near, far), dtype=np.float64)


def huber_pull(position: ArrayLike, goals: ArrayLike) -> FloatArray:
    """``(n, 3)``: each goal's hindsight assistance at ``position`` — minus the gradient of
    the Huber cost-to-go on the distance, over the robot's cost: toward the goal at
    ``(HUBER_LINEAR + HUBER_CONSTANT) / HUBER_ROBOT_COST`` m/s beyond :data:`HUBER_SWITCH`,
    less inside it, faded out within :data:`HUBER_FADE`."""
    g = np.atleast_2d(np.asarray(goals, dtype=np.float64))
    diff = np.asarray(position, dtype=np.float64)[None, :] - g
    dist = np.linalg.norm(diff, axis=1)
    safe = np.maximum(dist, 1e-12)
    unit = diff / safe[:, None]
    quadratic = HUBER_LINEAR / HUBER_SWITCH
    far = (HUBER_LINEAR + HUBER_CONSTANT) * unit
    near = HUBER_CONSTANT * unit + quadratic * diff
    grad = np.where((dist > HUBER_SWITCH)[:, None], far, near)
    grad *= np.minimum(1.0, dist / HUBER_FADE)[:, None]
    grad[dist < 1e-12] = 0.0
    return np.asarray(-grad / HUBER_ROBOT_COST, dtype=np.float64)


def blend(
    axes: ArrayLike,
    v_max: float,
    position: ArrayLike,
    goals: ArrayLike,
    posterior: ArrayLike,
    p_thresh: float,
    speed: float,
) -> Blended:
    """The ``blend`` command (module docstring): the robot's part moves toward the most
    likely goal at ``speed · ‖u‖``; ``α`` from :func:`arbitration`."""
    u = np.asarray(axes, dtype=np.float64)
    post = np.asarray(posterior, dtype=np.float64)
    operator = v_max * u
    deflection = math.sqrt(float(u @ u))
    best = int(np.argmax(post))
    alpha = arbitration(float(post[best]), len(post), p_thresh)
    if alpha <= 0.0 or deflection <= 0.0:
        return Blended(operator, operator, np.zeros(3), 0.0, None)
    goal = np.asarray(goals, dtype=np.float64)[best]
    robot = alpha * toward(position, goal, speed * min(1.0, deflection))
    mine = (1.0 - alpha) * operator
    return Blended(mine + robot, mine, robot, alpha, best)


def hindsight(
    axes: ArrayLike,
    v_max: float,
    position: ArrayLike,
    goals: ArrayLike,
    posterior: ArrayLike,
    dt: float,
) -> Blended:
    """The ``hindsight`` command (module docstring): ``v_max · u`` plus ``‖u‖`` times the
    posterior-weighted :func:`huber_pull` where the operator's step leads."""
    u = np.asarray(axes, dtype=np.float64)
    post = np.asarray(posterior, dtype=np.float64)
    operator = v_max * u
    deflection = min(1.0, math.sqrt(float(u @ u)))
    if deflection <= 0.0:
        return Blended(operator, operator, np.zeros(3), 0.0, None)
    after = np.asarray(position, dtype=np.float64) + operator * dt
    pulls = huber_pull(after, goals)
    weights = post / max(float(post.sum()), 1e-12)
    robot = deflection * (weights @ pulls)
    best = int(np.argmax(post))
    return Blended(operator + robot, operator, robot, float(weights[best]), best)


def against(
    axes: ArrayLike,
    direction: ArrayLike,
    cosine: float,
    deflection: float,
    min_direction: float = 1e-9,
) -> bool:
    """Whether the stick points against ``direction``: a deflection of at least
    ``deflection`` at an angle whose cosine is below ``cosine`` (a direction no longer than
    ``min_direction`` has none to point against)."""
    u = np.asarray(axes, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    un = math.sqrt(float(u @ u))
    dn = math.sqrt(float(d @ d))
    return un >= deflection and dn > min_direction and float(u @ d) / (un * dn) < cosine


def slew(previous: ArrayLike, wanted: ArrayLike, step: float) -> FloatArray:
    """``wanted``, changed from ``previous`` by at most ``step`` (a vector's length)."""
    p = np.asarray(previous, dtype=np.float64)
    d = np.asarray(wanted, dtype=np.float64) - p
    n = math.sqrt(float(d @ d))
    if n <= step:
        return np.asarray(wanted, dtype=np.float64).copy()
    return np.asarray(p + d * (step / n), dtype=np.float64)
