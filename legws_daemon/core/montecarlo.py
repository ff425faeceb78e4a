"""Monte Carlo check of the certificate (method.md section 4), vectorised over trials.

The simulated user of section 2 drives the end effector from ``x0`` toward the true goal
``g*`` with ``v = v_max pi_h(x, g*) + eps``, ``eps ~ N(0, sigma^2 I)``, orientation held,
for the certificate's horizon ``T(g*)``. The certificate's model does not clip the speed;
``clip_speed=True`` applies the robot's clip ``|v| <= v_max`` as well. At step ``T`` the
observer's argmax is compared with ``g*``; accuracy comes with a Clopper-Pearson interval.

The commit certificate's check (method.md section 9): :func:`simulate_commits` rolls the
same users out to arrival and records each observer's first commit (step, goal, and how far
along the way); :func:`commit_rates` turns that into the promised rate by the certified
step, wrong commits and commits before arrival, per goal (:func:`monte_carlo_commit` does
both keeping only the counts).

Cost: the users are simulated in chunks of whole random streams (:data:`STREAM_TRIALS`
trials each) and the observer evaluated in slices of trials, so the arrays stay within
:data:`MEMORY_BUDGET` (256 MiB) for any number of trials, with results identical to one
unsplit run; a run is refused beyond :data:`MAX_TRIALS` trials or :data:`MAX_WORK`
goal-steps (about a minute).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import betaincinv

from legws_daemon.core.certificate import start_terms
from legws_daemon.core.costs import path_costs, posterior
from legws_daemon.core.geometry import FloatArray, IntArray, safe_unit
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.operator import (
    GRID_DIRECTIONS,
    STEERINGS,
    horizon_steps,
    mean_deflection,
    nominal_path,
    nominal_steps,
)
from legws_daemon.core.params import CostForm, Params
from legws_daemon.core.user_model import OperatorNoise, SimulatedUser, clip_unit
from legws_daemon.errors import InputError

#: Confidence level of the reported Clopper-Pearson interval (two-sided).
CONFIDENCE = 0.95


@dataclass(frozen=True, slots=True)
class GoalAccuracy:
    """Accuracy at the horizon for one true goal."""

    accuracy: float
    lower95: float
    upper95: float
    correct: int
    trials: int


def clopper_pearson(
    correct: int, trials: int, confidence: float = CONFIDENCE
) -> tuple[float, float]:
    """Exact two-sided binomial confidence interval ``(lower, upper)``."""
    if trials <= 0 or not 0 <= correct <= trials:
        raise InputError(f"need 0 <= correct <= trials and trials > 0, got {correct}/{trials}")
    tail = (1.0 - confidence) / 2.0
    # quantiles of the Beta distributions of the exact interval
    lower = 0.0 if correct == 0 else float(betaincinv(correct, trials - correct + 1, tail))
    upper = 1.0 if correct == trials else float(betaincinv(correct + 1, trials - correct, 1 - tail))
    return lower, upper


@dataclass(frozen=True, slots=True)
class HorizonStates:
    """Simulated end states at each true goal's horizon.

    Attributes:
        positions: ``(M, N, 3)`` EE position at step ``T_i`` for true goal ``i``.
        lengths: ``(M, N)`` path length at that step.
        steps: ``(M,)`` the horizons ``T_i``.
    """

    positions: FloatArray
    lengths: FloatArray
    steps: IntArray


def _start_terms(goals: GoalSet, params: Params) -> tuple[FloatArray, FloatArray]:
    """Each goal's ``(|p_g - p0|, lambda_R angle)`` from the goal set's start, ``(M,)`` each."""
    x0 = goals.x0
    p0 = np.asarray(x0.position, dtype=np.float64)
    return start_terms(p0, x0.rotation, goals.positions, goals.rotations, goals.symmetry, params)


class _Walkers:
    """The simulated users of a chunk: positions ``(M, N, 3)``, path lengths ``(M, N)``, the
    AR(1) state of their noise and, with a reaction delay, where they were."""

    def __init__(
        self, p0: FloatArray, target: FloatArray, n: int, user: SimulatedUser, params: Params
    ) -> None:
        m = target.shape[0]
        self.x = np.broadcast_to(p0, (m, n, 3)).copy()
        self.length = np.zeros((m, n))
        self.target = target  # (M, 1, 3)
        self.user = user
        self.params = params
        self.noise = OperatorNoise(user.operator.rho)
        self.past: deque[FloatArray] = deque([self.x.copy()] * user.delay, maxlen=user.delay + 1)

    def draw(self, chunk: Streams) -> tuple[FloatArray, np.ndarray | None]:
        """One control period's noise ``(M, N, 3)`` (deflection units) and idle ticks
        ``(M, N)`` (``None``: never idle). Each stream draws its innovations (then, for
        idle ticks, which ticks are idle) in turn: section 2's user draws exactly as before
        the operator model."""
        user, params = self.user, self.params
        m = self.x.shape[0]
        parts = [(user.draw(g, (m, k), params.v_max), g) for g, k in chunk]
        w = parts[0][0] if len(parts) == 1 else np.concatenate([p[0] for p in parts], axis=1)
        e = self.noise.step(w)
        if not user.idle:
            return e, None
        idle = np.concatenate([g.random((m, w_.shape[1])) < user.idle for w_, g in parts], 1)
        return e, idle

    def draw_block(self, chunk: Streams, steps: int) -> tuple[FloatArray, np.ndarray]:
        """:meth:`draw` of ``steps`` control periods in turn: ``(B, M, N, 3)`` and
        ``(B, M, N)`` (the compiled rollouts' input)."""
        m, n = self.length.shape
        e = np.empty((steps, m, n, 3))
        idle = np.zeros((steps, m, n), dtype=np.bool_)
        for b in range(steps):
            e[b], tick_idle = self.draw(chunk)
            if tick_idle is not None:
                idle[b] = tick_idle
        return e, idle

    def step(self, chunk: Streams, active: np.ndarray) -> None:
        """One control period toward the targets, in place; rows where ``active``
        ``(M, 1)`` is false stay put."""
        user, params = self.user, self.params
        e, idle = self.draw(chunk)
        seen = self.past[0] if user.delay else self.x
        u = mean_deflection(seen, self.target, user.operator) + e
        if idle is not None:
            u = np.where(idle[..., None], 0.0, u)
        if user.clip:
            u = clip_unit(u)
        dx = params.v_max * params.dt * u
        self.x += np.where(active[..., None], dx, 0.0)
        self.length += np.where(active, np.sqrt(np.einsum("mnk,mnk->mn", dx, dx)), 0.0)
        if user.delay:
            self.past.append(self.x.copy())


def _user(params: Params, clip_speed: bool, user: SimulatedUser | None) -> SimulatedUser:
    """Who is simulated: ``user``, or section 2's user (with the robot's clip when
    ``clip_speed``)."""
    return user if user is not None else SimulatedUser.paper(params, clip_speed)


# --- cost and memory ------------------------------------------------------------------

#: Most simulated users per goal: at 1,000,000 the 95 % Clopper-Pearson interval is within
#: +-0.001 of the rate, finer than the model's own approximations.
MAX_TRIALS = 1_000_000
#: Most work of one Monte Carlo run, in goal-steps (see :func:`monte_carlo_work`): about a
#: minute on one core (``legws certify`` at the cap, measured: 33 s for 1,000,000 users of
#: the two-goal example, 51-57 s for two goals' check at the horizon and of commits
#: together, 19-33 s for 8 and 64 goals).
MAX_WORK = 250_000_000
#: Trials that draw from one random stream: the noise of trials ``[k S, (k + 1) S)`` comes
#: from stream ``k`` (stream 0 is the generator passed in, the others are spawned from it), so
#: results do not depend on how many trials are simulated at once, and runs of up to ``S``
#: trials draw exactly as one loop over all trials did.
STREAM_TRIALS = 4096
#: Bytes the Monte Carlo's arrays may take at once: half for the simulated users (positions,
#: path lengths, first commits and each step's temporaries), half for the observer's costs
#: of every goal. Trials are simulated in chunks of whole streams and evaluated in
#: sub-chunks to stay below it.
MEMORY_BUDGET = 256 * 2**20
#: Bytes per (true goal, trial) of the users' state and a step's temporaries, and per (true
#: goal, trial, goal) of the observer's evaluation: measured with tracemalloc at most 110
#: and 75 (commit check, 2 to 64 goals), rounded up. Measured peaks: 110 MiB (check at the
#: horizon), 145-160 MiB (commit check), for 2 to 64 goals and any number of trials.
_STATE_BYTES = 160
_EVAL_BYTES = 96


def monte_carlo_work(
    goals: GoalSet,
    params: Params,
    trials: int,
    *,
    horizon_forms: int = 1,
    commit_forms: int = 0,
    clip_speed: bool = False,
    user: SimulatedUser | None = None,
) -> int:
    """Goal-steps of a Monte Carlo run: ``trials x M x (T + M forms)`` for the check at the
    horizon with ``horizon_forms`` cost forms (every simulated step of every user, and the
    observer once at the horizon), plus ``trials x M x T_a x M x forms`` for the commit
    check with ``commit_forms`` (the observer's posterior over the M goals at every step).
    Either runs at 4 to 16 million goal-steps per second (measured; slowest for few goals)."""
    m = goals.m
    work = 0
    if horizon_forms:
        steps = int(_horizon(goals, params, clip_speed, user).max())
        work += trials * m * (steps + m * horizon_forms)
    if commit_forms:
        steps = int(_commit_arrivals(goals, params, _user(params, clip_speed, user)).max())
        work += trials * m * steps * m * commit_forms
    return work


def check_trials(
    goals: GoalSet,
    params: Params,
    trials: int,
    *,
    horizon_forms: int = 1,
    commit_forms: int = 0,
    clip_speed: bool = False,
    user: SimulatedUser | None = None,
    field: str = "trials",
) -> None:
    """Refuse a run of more than :data:`MAX_TRIALS` trials or :data:`MAX_WORK` goal-steps
    (:func:`monte_carlo_work` with the same arguments).

    Raises:
        InputError: one line naming ``field``, the work and the most trials accepted here.
    """
    if not 1 <= trials <= MAX_TRIALS:
        raise InputError(f"expected 1 to {MAX_TRIALS:,} trials, got {trials:,}", field=field)
    per_trial = monte_carlo_work(
        goals, params, 1, horizon_forms=horizon_forms, commit_forms=commit_forms,
        clip_speed=clip_speed, user=user,
    )  # fmt: skip
    work = trials * per_trial
    if work > MAX_WORK:
        what = " and ".join(
            w for w, n in (("at the horizon", horizon_forms), ("of commits", commit_forms)) if n
        )
        raise InputError(
            f"{trials:,} trials of {goals.m} goals are {work:.3g} goal-steps of simulation "
            f"(the check {what}: {per_trial:,} per trial); at most {MAX_WORK:.3g} are "
            f"accepted, {max(1, MAX_WORK // per_trial):,} trials for this goal set",
            field=field,
        )


#: Random streams of a run and the trials each draws for: ``[(generator, trials), ...]``.
Streams = list[tuple[np.random.Generator, int]]


def _streams(rng: np.random.Generator, trials: int) -> Streams:
    """``(generator, trials)`` of every :data:`STREAM_TRIALS` trials, in order."""
    n = -(-trials // STREAM_TRIALS)
    gens = [rng, *rng.spawn(n - 1)] if n > 1 else [rng]
    return [(g, min(STREAM_TRIALS, trials - i * STREAM_TRIALS)) for i, g in enumerate(gens)]


def _chunks(streams: Streams, rows: int) -> Iterator[Streams]:
    """Groups of whole streams whose users' state fits half the :data:`MEMORY_BUDGET`."""
    per = max(1, (MEMORY_BUDGET // 2) // (rows * STREAM_TRIALS * _STATE_BYTES))
    for i in range(0, len(streams), per):
        yield streams[i : i + per]


def _sub_slices(trials: int, rows: int, goals: int) -> list[slice]:
    """Slices of trials whose ``(rows, trials, goals)`` evaluation fits half the budget."""
    per = max(1, (MEMORY_BUDGET // 2) // (rows * goals * _EVAL_BYTES))
    return [slice(s, s + per) for s in range(0, trials, per)]


# --- the check at the horizon (method.md §4) ------------------------------------------


def _roll_to_horizon(
    goals: GoalSet,
    params: Params,
    steps: IntArray,
    chunk: Streams,
    user: SimulatedUser,
    rows: IntArray | None = None,
    compiled: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """Positions ``(m, n, 3)`` and path lengths ``(m, n)`` of a chunk's users at their
    true goal's horizon, for the true goals ``rows`` (default all); ``compiled``: by
    :mod:`~legws_daemon.core.rollout_kernels` (the same noise, the same end states)."""
    rows = np.arange(goals.m) if rows is None else rows
    n = sum(k for _, k in chunk)
    walk = _Walkers(goals.x0.position, goals.positions[rows, None, :], n, user, params)
    mine = steps[rows]
    if compiled:
        from legws_daemon.core.rollout_kernels import walk_block

        hist = _history(walk, user)
        targets = np.ascontiguousarray(goals.positions[rows])
        total = int(mine.max())
        for t0 in range(0, total, _BLOCK_STEPS):
            e, idle = walk.draw_block(chunk, min(_BLOCK_STEPS, total - t0))
            walk_block(walk.x, walk.length, hist, t0, mine, targets, e, idle,
                       *_kernel_user(user, params))  # fmt: skip
        return walk.x, walk.length
    for t in range(int(mine.max())):
        walk.step(chunk, (t < mine)[:, None])
    return walk.x, walk.length


#: Control periods of noise drawn at a time for the compiled rollouts.
_BLOCK_STEPS = 16


def _history(walk: _Walkers, user: SimulatedUser) -> FloatArray:
    """The positions a delayed user aims from, ``(M, N, delay + 1, 3)``, all at the start."""
    m, n = walk.length.shape
    hist = np.zeros((m, n, user.delay + 1, 3))
    hist[:, :, 0] = walk.x
    return hist


def _kernel_user(
    user: SimulatedUser, params: Params
) -> tuple[float, float, float, bool, int, FloatArray, bool, float, int]:
    """How ``user`` steers, as the compiled rollouts take it: speed, ``cos b``, ``sin b``,
    whether it turns, the steering's index, the grid of directions, the clip, ``v_max dt``
    and the delay."""
    op = user.operator
    return (op.speed, math.cos(op.bias), math.sin(op.bias), op.bias != 0.0,
            STEERINGS.index(op.steering), np.ascontiguousarray(GRID_DIRECTIONS), user.clip,
            params.v_max * params.dt, user.delay)  # fmt: skip


def _horizon(
    goals: GoalSet, params: Params, clip_speed: bool, user: SimulatedUser | None
) -> IntArray:
    """The horizons ``T`` the users are checked at: section 4's (also for the clipped user
    of ``clip_speed``, whose certificate is section 4's), or the horizon of ``user``'s own
    certificate (method.md §10: at its speed, with the robot's clip when it clips)."""
    d = np.linalg.norm(goals.positions - goals.x0.position, axis=1)
    if user is None:
        return horizon_steps(d, params)
    motion = user.operator.motion(params, user.clip)
    return horizon_steps(d, params, motion.speed)


def simulate_user(
    goals: GoalSet,
    params: Params,
    trials: int,
    rng: np.random.Generator,
    *,
    clip_speed: bool = False,
    user: SimulatedUser | None = None,
) -> HorizonStates:
    """Roll out ``trials`` noisy users per true goal up to that goal's horizon (every end
    state is returned: ``(M, N, 3)``; :func:`monte_carlo` keeps only the counts).
    ``user``: who steers (default section 2's user, clipped with ``clip_speed``)."""
    if trials < 1:
        raise InputError(f"expected at least 1 trial, got {trials}", field="trials")
    check_trials(goals, params, trials, clip_speed=clip_speed, user=user)
    steps = _horizon(goals, params, clip_speed, user)
    who = _user(params, clip_speed, user)
    parts = [
        _roll_to_horizon(goals, params, steps, chunk, who)
        for chunk in _chunks(_streams(rng, trials), goals.m)
    ]
    x = np.concatenate([x for x, _ in parts], axis=1)
    length = np.concatenate([length for _, length in parts], axis=1)
    return HorizonStates(x, length, steps)


def horizon_correct(
    goals: GoalSet,
    params: Params,
    states: HorizonStates,
    cost: CostForm,
    rows: IntArray | None = None,
) -> IntArray:
    """Number of trials per true goal (those of ``rows``, default all, one row of the states
    each) whose observer argmax at the horizon is the true goal (evaluated in slices of
    trials that fit the memory budget)."""
    trans0, rot = _start_terms(goals, params)
    d0 = trans0 + rot
    m, n = states.lengths.shape
    truth = np.arange(goals.m) if rows is None else rows
    total = np.zeros(m, dtype=np.int64)
    for sub in _sub_slices(n, m, goals.m):
        diff = states.positions[:, sub, None, :] - goals.positions[None, None, :, :]
        dist_now = np.sqrt(np.einsum("mngk,mngk->mng", diff, diff)) + rot
        costs = path_costs(states.lengths[:, sub], dist_now, d0, cost)  # (m, n, M)
        best = np.argmin(costs, axis=-1)
        total += (best == truth[:, None]).sum(axis=1)
    return total


def monte_carlo(
    goals: GoalSet,
    params: Params,
    trials: int,
    seed: int = 0,
    *,
    clip_speed: bool = False,
    costs: Sequence[CostForm] | None = None,
    user: SimulatedUser | None = None,
    true_goals: Sequence[int] | None = None,
    compiled: bool = False,
) -> dict[CostForm, dict[str, GoalAccuracy]]:
    """Accuracy at the horizon per true goal, for each requested cost form; ``user``: who
    steers (default section 2's user, with the robot's clip when ``clip_speed``), checked at
    the horizon of its own certificate; ``true_goals``: only those true goals are simulated
    and reported; ``compiled``: the users rolled out by
    :mod:`~legws_daemon.core.rollout_kernels` (the same noise and end states, several times
    faster).

    The same simulated trajectories serve every cost form (common random numbers), so the
    forms are compared on identical user behaviour. Same seed, same result, whatever the
    memory budget: the users are simulated in chunks of whole random streams and only the
    counts are kept (memory stays within :data:`MEMORY_BUDGET`).

    Raises:
        InputError: beyond :data:`MAX_TRIALS` trials or :data:`MAX_WORK` goal-steps.
    """
    forms: Sequence[CostForm] = costs if costs is not None else (params.cost,)
    if trials < 1:
        raise InputError(f"expected at least 1 trial, got {trials}", field="trials")
    check_trials(goals, params, trials, clip_speed=clip_speed, horizon_forms=len(forms), user=user)
    rng = np.random.default_rng(seed)
    steps = _horizon(goals, params, clip_speed, user)
    who = _user(params, clip_speed, user)
    rows = _commit_rows(goals, true_goals)
    correct = {form: np.zeros(len(rows), dtype=np.int64) for form in forms}
    for chunk in _chunks(_streams(rng, trials), len(rows)):
        x, length = _roll_to_horizon(goals, params, steps, chunk, who, rows, compiled)
        states = HorizonStates(x, length, steps[rows])
        for form in forms:
            correct[form] += horizon_correct(goals, params, states, form, rows)
    out: dict[CostForm, dict[str, GoalAccuracy]] = {}
    names = [goals.names[i] for i in rows]
    for form in forms:
        per_goal: dict[str, GoalAccuracy] = {}
        for name, k in zip(names, correct[form], strict=True):
            lo, hi = clopper_pearson(int(k), trials)
            per_goal[name] = GoalAccuracy(int(k) / trials, lo, hi, int(k), trials)
        out[form] = per_goal
    return out


# --- the commit check (method.md §9) ----------------------------------------------------


@dataclass(frozen=True, slots=True)
class CommitRollouts:
    """First commits of simulated users, per true goal and trial.

    Attributes:
        step: ``(M, N)`` the step of the first commit (``max_g P >= p_thresh``), ``0`` when
            none before arrival.
        goal: ``(M, N)`` the goal committed to, ``-1`` when none.
        progress: ``(M, N)`` how far along the way to the true goal the user had come by
            the first commit (the largest projection on the straight way so far), m;
            ``inf`` when none.
        arrival_steps: ``(M,)`` ``T_a`` of each true goal (method.md §9).
        along: ``(M, T + 1)`` how far along the straight way the nominal of each true goal
            has come at each step ``0..T`` (m; :func:`nominal_progress`), what the promise
            counted in progress is counted against.
    """

    step: IntArray
    goal: IntArray
    progress: FloatArray
    arrival_steps: IntArray
    along: FloatArray


def _commit_chunks(
    goals: GoalSet,
    params: Params,
    trials: int,
    rng: np.random.Generator,
    user: SimulatedUser,
    forms: Sequence[CostForm],
    rows: IntArray,
    until_arrival: bool = False,
    compiled: bool = False,
) -> Iterator[dict[CostForm, tuple[IntArray, IntArray, FloatArray]]]:
    """Per chunk of trials and cost form, the ``(step, goal, progress)`` of the first
    commits ``(len(rows), n)`` of the true goals ``rows``: up to ``T_a`` steps, or with
    ``until_arrival`` up to each user's own arrival (closer than ``v_max dt`` to the goal;
    at most :data:`ARRIVAL_SPAN` times ``T_a``)."""
    p0 = goals.x0.position
    m = len(rows)
    target = goals.positions[rows, None, :]
    trans0, rot = _start_terms(goals, params)
    t_a = _commit_arrivals(goals, params, user)[rows]
    limit = ARRIVAL_SPAN * t_a if until_arrival else t_a
    near = params.v_max * params.dt
    d0 = trans0 + rot
    way = safe_unit(goals.positions[rows] - p0)[:, None, :]  # (m, 1, 3)
    if compiled:
        yield from _commit_chunks_compiled(goals, params, trials, rng, user, forms, rows,
                                           until_arrival, limit, rot, d0, way[:, 0, :])  # fmt: skip
        return
    for chunk in _chunks(_streams(rng, trials), m):
        n = sum(k for _, k in chunk)
        subs = _sub_slices(n, m, goals.m)
        walk = _Walkers(p0, target, n, user, params)
        furthest = np.zeros((m, n))
        arrived = np.zeros((m, n), dtype=bool)
        first_step = {f: np.zeros((m, n), dtype=np.int64) for f in forms}
        first_goal = {f: np.full((m, n), -1, dtype=np.int64) for f in forms}
        first_progress = {f: np.full((m, n), np.inf) for f in forms}
        for t in range(1, int(limit.max(initial=0)) + 1):
            committed = np.logical_and.reduce([first_goal[f] >= 0 for f in forms])
            active = (t <= limit)[:, None] & ~arrived  # (m, n): still on the way
            if not (active & ~committed).any():
                break  # every user has made its first commit or arrived: nothing to learn
            walk.step(chunk, active)
            x, length = walk.x, walk.length
            furthest = np.maximum(furthest, np.einsum("mnk,mnk->mn", x - p0, way))
            if until_arrival:
                left = x - target
                arrived |= np.einsum("mnk,mnk->mn", left, left) < near * near
            for sub in subs:
                diff = x[:, sub, None, :] - goals.positions[None, None, :, :]
                dist_now = np.sqrt(np.einsum("mngk,mngk->mng", diff, diff)) + rot
                for form in forms:
                    post = posterior(path_costs(length[:, sub], dist_now, d0, form), params.beta)
                    goal = first_goal[form][:, sub]
                    hit = (np.max(post, axis=-1) >= params.p_thresh) & active[:, sub] & (goal < 0)
                    step, progress = first_step[form][:, sub], first_progress[form][:, sub]
                    first_step[form][:, sub] = np.where(hit, t, step)
                    first_goal[form][:, sub] = np.where(hit, np.argmax(post, axis=-1), goal)
                    first_progress[form][:, sub] = np.where(hit, furthest[:, sub], progress)
        yield {f: (first_step[f], first_goal[f], first_progress[f]) for f in forms}


def _commit_chunks_compiled(
    goals: GoalSet,
    params: Params,
    trials: int,
    rng: np.random.Generator,
    user: SimulatedUser,
    forms: Sequence[CostForm],
    rows: IntArray,
    until_arrival: bool,
    limit: IntArray,
    rot: FloatArray,
    d0: FloatArray,
    way: FloatArray,
) -> Iterator[dict[CostForm, tuple[IntArray, IntArray, FloatArray]]]:
    """:func:`_commit_chunks` by :func:`~legws_daemon.core.rollout_kernels.commit_block`
    (its step limits, rotation terms, start distances and ways ``(m, 3)`` given): the same
    noise, in blocks of :data:`_BLOCK_STEPS` control periods, each user followed only until
    nothing more is to be learnt from it."""
    from legws_daemon.core.rollout_kernels import DRAGAN, RATIO, commit_block

    p0 = np.ascontiguousarray(goals.x0.position, dtype=np.float64)
    m = len(rows)
    targets = np.ascontiguousarray(goals.positions[rows])
    way = np.ascontiguousarray(way)
    codes = np.array([{"dragan": DRAGAN, "ratio": RATIO}[f] for f in forms], dtype=np.int64)
    near2 = (params.v_max * params.dt) ** 2
    total = int(limit.max(initial=0))
    steering = _kernel_user(user, params)
    for chunk in _chunks(_streams(rng, trials), m):
        n = sum(k for _, k in chunk)
        walk = _Walkers(p0, targets[:, None, :], n, user, params)
        hist = _history(walk, user)
        furthest = np.zeros((m, n))
        state = np.zeros((m, n), dtype=np.int8)
        first_step = np.zeros((len(forms), m, n), dtype=np.int64)
        first_goal = np.full((len(forms), m, n), -1, dtype=np.int64)
        first_progress = np.full((len(forms), m, n), np.inf)
        for t0 in range(0, total, _BLOCK_STEPS):
            e, idle = walk.draw_block(chunk, min(_BLOCK_STEPS, total - t0))
            going = commit_block(
                walk.x, walk.length, hist, furthest, state, first_step, first_goal,
                first_progress, t0, limit, targets, way, p0, goals.positions, rot, d0,
                float(np.mean(d0)), codes, params.beta, params.p_thresh, until_arrival, near2,
                e, idle, *steering,
            )  # fmt: skip
            if not going:
                break
        yield {f: (first_step[k], first_goal[k], first_progress[k]) for k, f in enumerate(forms)}


#: With ``until_arrival`` a user is followed for at most this many times ``T_a`` steps.
ARRIVAL_SPAN = 3


def _commit_rows(goals: GoalSet, true_goals: Sequence[int] | None) -> IntArray:
    if true_goals is None:
        return np.arange(goals.m)
    return np.asarray(true_goals, dtype=np.int64)


def _commit_arrivals(goals: GoalSet, params: Params, user: SimulatedUser) -> IntArray:
    """``T_a`` of each goal for the certificate of ``user``'s model (its speed, with the
    robot's clip when it clips; at least one step for a goal it never reaches). A run asks
    several times (its cost, its rollouts, its rates): the last few answers are kept."""
    p0 = np.asarray(goals.x0.position, dtype=np.float64)
    key = (p0.tobytes(), goals.positions.tobytes(), user.operator, user.clip, params)
    if key not in _ARRIVALS:
        motion = user.operator.motion(params, user.clip)
        t_a, _ = nominal_steps(p0, goals.positions, user.operator, motion, params)
        _ARRIVALS[key] = np.asarray(np.maximum(t_a, 1), dtype=np.int64)
        while len(_ARRIVALS) > 16:
            _ARRIVALS.pop(next(iter(_ARRIVALS)))
    out: IntArray = _ARRIVALS[key].copy()
    return out


#: The arrival steps of the last few runs (:func:`_commit_arrivals`), oldest first.
_ARRIVALS: dict[tuple[object, ...], IntArray] = {}


def nominal_progress(goals: GoalSet, params: Params, user: SimulatedUser, steps: int) -> FloatArray:
    """How far along the straight way to each goal its certificate's nominal has come at
    each step ``0..steps``, ``(M, steps + 1)`` (m): the projection of the nominal's point
    (``t s v_max dt`` on a straight nominal)."""
    operator = user.operator
    motion = operator.motion(params, user.clip)
    p0 = goals.x0.position
    path = nominal_path(p0, goals.positions, operator, motion, params, max(1, steps))
    way = safe_unit(goals.positions - p0)
    along = np.einsum("mtk,mk->mt", path - p0, way)[:, :steps]
    return np.asarray(np.concatenate([np.zeros((goals.m, 1)), along], axis=1), np.float64)


def simulate_commits(
    goals: GoalSet,
    params: Params,
    trials: int,
    rng: np.random.Generator,
    *,
    clip_speed: bool = False,
    costs: Sequence[CostForm] | None = None,
    true_goals: Sequence[int] | None = None,
    user: SimulatedUser | None = None,
    until_arrival: bool = False,
    compiled: bool = False,
) -> dict[CostForm, CommitRollouts]:
    """Roll out ``trials`` noisy users per true goal for ``T_a`` steps and record each
    observer's first commit, for each cost form on the same trajectories. With
    ``clip_speed`` the users are the robot's (speed clipped to ``v_max``) and ``T_a`` is
    that slower motion's (:func:`~legws_daemon.core.commit.clipped_user`); ``user`` is any
    simulated operator (method.md §10), rolled out for its own certificate's ``T_a``.
    ``true_goals`` limits the rollouts to those true goals (the other rows stay without a
    commit). ``until_arrival``: each user is followed to its own arrival instead of
    ``T_a`` (a slower user's commits, counted in progress along the way). ``compiled``:
    rolled out by :mod:`~legws_daemon.core.rollout_kernels` (the same noise and first
    commits, each user followed only until its first commit or arrival: many times
    faster).

    Every trial's first commit is returned (``(M, N)`` arrays per form);
    :func:`monte_carlo_commit` keeps only the counts, in bounded memory."""
    if trials < 1:
        raise InputError(f"expected at least 1 trial, got {trials}", field="trials")
    forms: Sequence[CostForm] = costs if costs is not None else (params.cost,)
    check_trials(
        goals, params, trials, horizon_forms=0, commit_forms=len(forms), clip_speed=clip_speed,
        user=user,
    )  # fmt: skip
    who = _user(params, clip_speed, user)
    rows = _commit_rows(goals, true_goals)
    parts = list(
        _commit_chunks(goals, params, trials, rng, who, forms, rows, until_arrival, compiled)
    )
    t_a_all = _commit_arrivals(goals, params, who)
    along = nominal_progress(goals, params, who, int(t_a_all.max()))
    out: dict[CostForm, CommitRollouts] = {}
    for f in forms:
        steps = np.zeros((goals.m, trials), dtype=np.int64)
        chosen = np.full((goals.m, trials), -1, dtype=np.int64)
        progress = np.full((goals.m, trials), np.inf)
        for target, i in ((steps, 0), (chosen, 1), (progress, 2)):
            target[rows] = np.concatenate([part[f][i] for part in parts], axis=1)
        out[f] = CommitRollouts(steps, chosen, progress, t_a_all, along)
    return out


@dataclass(frozen=True, slots=True)
class GoalCommitRate:
    """Monte Carlo of one true goal's first commit (interfaces.md ``monte_carlo_commit``).

    Attributes:
        rate_by_step: fraction whose first commit is on the true goal at or before
            ``by_step`` (the certified commit step, or ``T_a`` when the goal has none).
        lower95, upper95: its Clopper-Pearson interval.
        rate_by_progress: fraction whose first commit is on the true goal before they
            first came further along the way than the nominal at ``by_step``
            (:func:`nominal_progress`): the promise in distance rather than time, which is
            what a slower user gets.
        progress_upper95: the Clopper-Pearson upper bound of ``rate_by_progress``.
        wrong: fraction whose first commit (before arrival) is on another goal.
        before_arrival: fraction whose first commit is on the true goal before arrival.
        by_step: the step ``rate_by_step`` is counted at.
        trials: simulated users.
    """

    rate_by_step: float
    lower95: float
    upper95: float
    rate_by_progress: float
    progress_upper95: float
    wrong: float
    before_arrival: float
    by_step: int
    trials: int


def commit_rates(
    rollouts: CommitRollouts, by_step: Sequence[int | None], names: Sequence[str]
) -> dict[str, GoalCommitRate]:
    """Per-goal commit statistics; ``by_step[i]`` is goal ``i``'s certified step (``None``:
    count up to arrival)."""
    limits = _limits(rollouts.arrival_steps, by_step)
    counts = _commit_counts(
        (rollouts.step, rollouts.goal, rollouts.progress), limits, rollouts.along
    )
    return _rates(counts, limits, rollouts.step.shape[1], names)


def monte_carlo_commit(
    goals: GoalSet,
    params: Params,
    trials: int,
    rng: np.random.Generator,
    by_step: Sequence[int | None],
    *,
    clip_speed: bool = False,
    user: SimulatedUser | None = None,
    compiled: bool = False,
) -> dict[str, GoalCommitRate]:
    """:func:`commit_rates` of :func:`simulate_commits` (same rollouts, same numbers) for
    the parameters' cost form, keeping only the counts: memory stays within
    :data:`MEMORY_BUDGET` whatever the number of trials.

    Raises:
        InputError: beyond :data:`MAX_TRIALS` trials or :data:`MAX_WORK` goal-steps.
    """
    if trials < 1:
        raise InputError(f"expected at least 1 trial, got {trials}", field="trials")
    check_trials(
        goals, params, trials, horizon_forms=0, commit_forms=1, clip_speed=clip_speed, user=user
    )
    who = _user(params, clip_speed, user)
    t_a = _commit_arrivals(goals, params, who)
    limits = _limits(t_a, by_step)
    along = nominal_progress(goals, params, who, int(max(t_a.max(), max(limits))))
    total = np.zeros((4, goals.m), dtype=np.int64)
    rows = np.arange(goals.m)
    for part in _commit_chunks(
        goals, params, trials, rng, who, (params.cost,), rows, compiled=compiled
    ):
        total += _commit_counts(part[params.cost], limits, along)
    return _rates(total, limits, trials, goals.names)


def _limits(arrival: IntArray, by_step: Sequence[int | None]) -> list[int]:
    """Each goal's step its commit is counted by: the certified step, else arrival."""
    return [int(arrival[i]) if s is None else int(s) for i, s in enumerate(by_step)]


def _commit_counts(
    first: tuple[IntArray, IntArray, FloatArray], limits: Sequence[int], along: FloatArray
) -> IntArray:
    """``(4, M)`` counts per true goal of first commits: on it by its limit step, on it
    before coming further along the way than the nominal at the limit step (``along``), on
    another goal, and on it before arrival."""
    step, goal, progress = first
    out = np.zeros((4, len(limits)), dtype=np.int64)
    for i, limit in enumerate(limits):
        on_true = goal[i] == i
        out[0, i] = np.sum(on_true & (step[i] <= limit))
        reach = along[i, min(limit, along.shape[1] - 1)]
        out[1, i] = np.sum(on_true & (progress[i] <= reach + 1e-12))
        out[2, i] = np.sum((goal[i] >= 0) & ~on_true)
        out[3, i] = np.sum(on_true)
    return out


def _rates(
    counts: IntArray, limits: Sequence[int], trials: int, names: Sequence[str]
) -> dict[str, GoalCommitRate]:
    out: dict[str, GoalCommitRate] = {}
    for i, name in enumerate(names):
        timely, early, wrong, on_true = (int(c) for c in counts[:, i])
        lo, hi = clopper_pearson(timely, trials)
        out[name] = GoalCommitRate(
            rate_by_step=timely / trials,
            lower95=lo,
            upper95=hi,
            rate_by_progress=early / trials,
            progress_upper95=clopper_pearson(early, trials)[1],
            wrong=wrong / trials,
            before_arrival=on_true / trials,
            by_step=limits[i],
            trials=trials,
        )
    return out
