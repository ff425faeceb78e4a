"""Compiled rollouts of the Monte Carlo (:mod:`legws_daemon.core.montecarlo`).

The numpy rollouts step every simulated user of a chunk together, one control period at a
time, until the last one is done: the per-step cost is a few dozen array operations over
``(rows, trials, 3)`` whatever is left to learn. These kernels take the same noise (drawn
by the numpy code, in blocks of steps, in exactly the order it draws it) and follow one
user at a time, in registers, stopping each as soon as nothing more is to be learnt from
it: at its horizon (the check of section 4), or at its first commit under every cost form
asked for, its arrival or its step limit (the check of section 9). Same model, same
arithmetic term for term (tests/core/test_rollout_kernels.py checks that both give the same
first commits and end states).

State persists between blocks in the arrays passed in; each kernel returns whether any
user still needs steps.
"""

from __future__ import annotations

import math

import numpy as np

from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.kernels import aim, jit

#: Cost forms by index (core.costs).
DRAGAN, RATIO = 0, 1


@jit
def _deflect(
    hx: float, hy: float, hz: float, tx: float, ty: float, tz: float, ex: float, ey: float,
    ez: float, idle: bool, speed: float, bc: float, bs: float, turn: bool, steering: int,
    grid: FloatArray, clip: bool,
) -> tuple[float, float, float]:  # fmt: skip
    """``u = s Q(R_z(b) pi_h(x, g)) + e`` (zero on an idle tick), clipped to ``|u| <= 1``."""
    if idle:
        return 0.0, 0.0, 0.0
    ax, ay, az = aim(hx, hy, hz, tx, ty, tz, bc, bs, turn, steering, grid)
    ux, uy, uz = speed * ax + ex, speed * ay + ey, speed * az + ez
    if clip:
        d = max(math.sqrt(ux * ux + uy * uy + uz * uz), 1.0)
        ux, uy, uz = ux / d, uy / d, uz / d
    return ux, uy, uz


@jit
def _advance(
    x: FloatArray, length: FloatArray, hist: FloatArray, r: int, i: int, done: int,
    tx: float, ty: float, tz: float, e: FloatArray, idle: bool, speed: float, bc: float,
    bs: float, turn: bool, steering: int, grid: FloatArray, clip: bool, step_len: float,
    delay: int,
) -> tuple[float, float, float]:  # fmt: skip
    """User ``(r, i)``'s step after ``done`` steps: aimed from where it is (or, delayed,
    was ``delay`` steps ago), its noise ``e (3,)``; ``x``, ``length`` and ``hist`` in place.
    Returns the new position."""
    ring = delay + 1
    if delay:
        seen = hist[r, i, max(done - delay, 0) % ring]
        hx, hy, hz = seen[0], seen[1], seen[2]
    else:
        hx, hy, hz = x[r, i, 0], x[r, i, 1], x[r, i, 2]
    ux, uy, uz = _deflect(
        hx, hy, hz, tx, ty, tz, e[0], e[1], e[2], idle, speed, bc, bs, turn, steering, grid, clip
    )
    dx, dy, dz = step_len * ux, step_len * uy, step_len * uz
    px, py, pz = x[r, i, 0] + dx, x[r, i, 1] + dy, x[r, i, 2] + dz
    x[r, i, 0], x[r, i, 1], x[r, i, 2] = px, py, pz
    length[r, i] += math.sqrt(dx * dx + dy * dy + dz * dz)
    if delay:
        hist[r, i, (done + 1) % ring, 0] = px
        hist[r, i, (done + 1) % ring, 1] = py
        hist[r, i, (done + 1) % ring, 2] = pz
    return px, py, pz


@jit
def walk_block(
    x: FloatArray, length: FloatArray, hist: FloatArray, t0: int, steps: IntArray,
    targets: FloatArray, e: FloatArray, idle: np.ndarray, speed: float, bc: float, bs: float,
    turn: bool, steering: int, grid: FloatArray, clip: bool, step_len: float, delay: int,
) -> bool:  # fmt: skip
    """Steps ``t0 .. t0 + B - 1`` of every user (``x (R, N, 3)``, ``length (R, N)`` in
    place; ``hist (R, N, delay + 1, 3)`` the positions a delayed user aims from) that has
    not reached its row's ``steps``; ``e (B, R, N, 3)`` the noise in deflection units,
    ``idle (B, R, N)``. Returns whether any user needs steps beyond the block."""
    b_steps, rows, n = e.shape[0], e.shape[1], e.shape[2]
    left = False
    for r in range(rows):
        tx, ty, tz = targets[r, 0], targets[r, 1], targets[r, 2]
        for i in range(n):
            for b in range(b_steps):
                if t0 + b >= steps[r]:
                    break
                _advance(x, length, hist, r, i, t0 + b, tx, ty, tz, e[b, r, i], idle[b, r, i],
                         speed, bc, bs, turn, steering, grid, clip, step_len, delay)  # fmt: skip
            if t0 + b_steps < steps[r]:
                left = True
    return left


@jit
def commit_block(
    x: FloatArray, length: FloatArray, hist: FloatArray, furthest: FloatArray,
    state: np.ndarray, first_step: IntArray, first_goal: IntArray, first_progress: FloatArray,
    t0: int, limit: IntArray, targets: FloatArray, way: FloatArray, p0: FloatArray,
    goals: FloatArray, rot: FloatArray, d0: FloatArray, scale: float, forms: IntArray,
    beta: float, p_thresh: float, until_arrival: bool, near2: float, e: FloatArray,
    idle: np.ndarray, speed: float, bc: float, bs: float, turn: bool, steering: int,
    grid: FloatArray, clip: bool, step_len: float, delay: int,
) -> bool:  # fmt: skip
    """Steps ``t0 + 1 .. t0 + B`` of the commit check (core.montecarlo._commit_chunks) for
    every user not done (``state (R, N)``: 0 going, 1 done). Per user: one step, how far
    along the way it has come (``furthest``), arrival (``until_arrival``: closer than
    ``sqrt(near2)`` to its goal), then each cost form's posterior over the goals
    (``goals (M, 3)``, ``rot``, ``d0 (M,)``; ``scale``: ``mean d0`` of the dragan form) and
    its first commit (``first_* (F, R, N)``). A user is done once every form has committed,
    it has arrived or it is past its row's ``limit``. Returns whether any is going."""
    b_steps, rows, n = e.shape[0], e.shape[1], e.shape[2]
    m, n_forms = goals.shape[0], forms.shape[0]
    logits = np.empty(m)
    left = False
    for r in range(rows):
        tx, ty, tz = targets[r, 0], targets[r, 1], targets[r, 2]
        wx, wy, wz = way[r, 0], way[r, 1], way[r, 2]
        for i in range(n):
            if state[r, i]:
                continue
            for b in range(b_steps):
                t = t0 + b + 1
                if t > limit[r]:
                    state[r, i] = 1
                    break
                px, py, pz = _advance(
                    x, length, hist, r, i, t - 1, tx, ty, tz, e[b, r, i], idle[b, r, i], speed,
                    bc, bs, turn, steering, grid, clip, step_len, delay,
                )  # fmt: skip
                along = (px - p0[0]) * wx + (py - p0[1]) * wy + (pz - p0[2]) * wz
                furthest[r, i] = max(furthest[r, i], along)
                arrived = False
                if until_arrival:
                    lx, ly, lz = px - tx, py - ty, pz - tz
                    arrived = lx * lx + ly * ly + lz * lz < near2
                waiting = False
                for f in range(n_forms):
                    if first_goal[f, r, i] >= 0:
                        continue
                    top, best = -np.inf, 0
                    for g in range(m):
                        qx, qy, qz = px - goals[g, 0], py - goals[g, 1], pz - goals[g, 2]
                        dist = math.sqrt(qx * qx + qy * qy + qz * qz) + rot[g]
                        if forms[f] == DRAGAN:
                            cost = (length[r, i] + dist - d0[g]) / scale
                        else:
                            cost = (length[r, i] + dist) / d0[g]
                        logits[g] = -beta * cost
                        if logits[g] > top:
                            top, best = logits[g], g
                    total = 0.0
                    for g in range(m):
                        total += math.exp(logits[g] - top)
                    if 1.0 / total >= p_thresh:
                        first_step[f, r, i] = t
                        first_goal[f, r, i] = best
                        first_progress[f, r, i] = furthest[r, i]
                    else:
                        waiting = True
                if arrived or not waiting:
                    state[r, i] = 1
                    break
            if not state[r, i]:
                left = True
    return left
