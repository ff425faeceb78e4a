"""numba kernels shared by the compiled parts of legws (the design objectives of
``design.fast_objectives``, the Monte Carlo's rollouts of ``core.rollout_kernels``): the
operator's aim of method.md §10, one point at a time.

numba compiles them on first use (``cache=True``: once per machine and version of this
file, into ``$NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

from legws_daemon.core.geometry import FloatArray

#: A point this close to a goal coincides with it (no pull), m: as core.geometry.
EPS = 1e-12

_F = TypeVar("_F", bound=Callable[..., Any])


def jit(f: _F) -> _F:
    """numba's ``njit`` (cached on disk, releasing the GIL), typed as the function itself."""
    return cast(_F, numba.njit(cache=True, nogil=True)(f))


@jit
def sign(x: float) -> float:
    return (1.0 if x > 0.0 else 0.0) - (1.0 if x < 0.0 else 0.0)


@jit
def aim(
    hx: float, hy: float, hz: float, gx: float, gy: float, gz: float, bc: float, bs: float,
    turn: bool, steering: int, grid: FloatArray,
) -> tuple[float, float, float]:  # fmt: skip
    """``Q(R_z(b) pi_h(here, g))`` (core.operator.aim). ``axes`` and ``axes+diagonals``
    choose from the turned difference itself (scaling by ``1 / |g - here|`` changes no
    choice), without branches: only ``free`` steering divides."""
    x, y, z = gx - hx, gy - hy, gz - hz
    n2 = x * x + y * y + z * z
    if steering == 0:
        norm = math.sqrt(n2)
        if not norm > EPS:
            return 0.0, 0.0, 0.0
        d = max(norm, EPS)
        x, y, z = x / d, y / d, z / d
        if turn:
            x, y = bc * x - bs * y, bs * x + bc * y
        return x, y, z
    live = n2 > EPS * EPS  # on the goal: no aim
    if turn:
        x, y = bc * x - bs * y, bs * x + bc * y
    ax, ay, az = abs(x), abs(y), abs(z)
    sx, sy, sz = sign(x), sign(y), sign(z)
    if steering == 1:  # the axis of the largest component (ties: x, then y, then z)
        kx = (ax >= ay) & (ax >= az) & live
        ky = (~kx) & (ay >= az) & live
        kz = (~kx) & (~ky) & live
        return (sx if kx else 0.0), (sy if ky else 0.0), (sz if kz else 0.0)
    # the closest of the 26 grid directions: with k non-zero components the best is the k
    # largest |components| with their signs, worth their sum over sqrt(k)
    top = max(ax, max(ay, az))
    low = min(ax, min(ay, az))
    mid = ax + ay + az - top - low
    one = top
    two = (top + mid) * (1.0 / math.sqrt(2.0))
    three = (ax + ay + az) * (1.0 / math.sqrt(3.0))
    k = 3 if three > max(one, two) else (2 if two > one else 1)
    # k = 1: the largest (first of x, y, z); k = 2: all but the smallest (last of z, y, x)
    first_x = (ax >= ay) & (ax >= az)
    first_y = (~first_x) & (ay >= az)
    last_z = (az <= ax) & (az <= ay)
    last_y = (~last_z) & (ay <= ax)
    last_x = (~last_z) & (~last_y)
    in_x = (k == 3) | ((k == 2) & (~last_x)) | ((k == 1) & first_x)
    in_y = (k == 3) | ((k == 2) & (~last_y)) | ((k == 1) & first_y)
    in_z = (k == 3) | ((k == 2) & (~last_z)) | ((k == 1) & (~first_x) & (~first_y))
    if not live:
        return 0.0, 0.0, 0.0
    ix = int(sx) if in_x else 0
    iy = int(sy) if in_y else 0
    iz = int(sz) if in_z else 0
    index = 9 * (ix + 1) + 3 * (iy + 1) + (iz + 1)
    index -= index > 13  # the grid leaves out (0, 0, 0)
    return grid[index, 0], grid[index, 1], grid[index, 2]
