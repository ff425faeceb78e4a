"""Reachability map: a cheap screen of grasp feasibility, computed once per robot model.

A layout optimiser evaluates ~10^5 layouts per scene, far too many for the full IK and
collision check of :mod:`legws_daemon.robot.feasibility` (about a millisecond per grasp). The
map answers "can the arm reach this grasp without touching the table?" by a table lookup:
for each grasp kind, a boolean grid over the grasp point's height above the table, the yaw
of the grasp frame about world z, and the grasp point's ``x``, ``y`` (robot base frame).
The full check then verifies only the layouts the optimiser keeps.

Yaw of a grasp frame ``R``: ``atan2(R[1, 0], R[0, 0])``, the heading of its closing axis.
Every grasp the library derives is ``Rz(object yaw) @ R_kind``
(:mod:`~legws_daemon.scene.grasps`), whose yaw is the object's yaw plus a quarter turn for
both kinds: a bijection. Grid cell
``psi`` holds the frame ``Rz(psi) @ B_kind`` with ``B_kind`` that frame at yaw 0:
``B_top`` points the approach axis down, ``B_side`` approaches horizontally with the
frame's y axis up.

Symmetric equivalents (turns about the approach axis, as in
:func:`~legws_daemon.robot.feasibility.symmetric_rotations`):

* top grasps: a turn about the vertical approach axis is a change of yaw, so a grasp of
  symmetry ``n`` is reachable when any yaw ``psi + 2 pi k / n`` is (``n = 0``: any yaw bin);
* side grasps: a turn about the horizontal approach axis is a *roll*, not a yaw (the same
  yaw plus half a turn would approach from the other side of the object). The map keeps a
  second grid, ``side_flipped``, of the side frames rolled half a turn (fingers swapped,
  frame y axis down), indexed by the yaw of their unflipped twin; a side grasp of even
  symmetry (or 0) is reachable when either roll is. Quarter-turn rolls (fingers closing
  vertically) are not mapped and count as unreachable.

A cell is reachable when damped least-squares IK (the iteration of
:func:`~legws_daemon.robot.kinematics.solve_ik`, run for many cells at once in numpy) ends
within :data:`~legws_daemon.robot.feasibility.TOL_POSITION` and
:data:`~legws_daemon.robot.feasibility.TOL_ROTATION` with the arm touching no table, from
one of the full check's seeds (home, then its fixed restarts) or warm started from a
neighbouring cell's solution (:func:`build`). Objects are moved out of the way while
building: clearance to objects is the optimiser's business.

Lookups snap to the nearest cell in ``x``, ``y``, height and yaw; outside the grid (more
than half a step beyond its edges, below its lowest height) a grasp is unreachable.

The map is cached on disk per robot model (:func:`load_or_build`), keyed by a hash of the
robot description, the gripper, the table, the IK seeds, the tolerances and the grid. The
file is written atomically (a temporary file, then a rename) and used only when it
validates (:meth:`ReachabilityMap.load`: format, key, grid, array names, shapes and
types); a truncated, garbage or stale file is logged as a warning and rebuilt.

legws ships the map of the default grid for the Sawyer model it fetches (:data:`SHIPPED`,
~10 kB; the robosuite release ``legws assets fetch`` pins): when its key is the cache's, it is
validated like a cached file and copied into the cache instead of building (~1.5 min). A
changed model, table, seed, tolerance or grid changes the key, and the map is built as
before. ``legws assets reachability --build`` builds it regardless (to refresh the shipped
one: tests/robot/test_reachability.py fails while it is stale).
"""

from __future__ import annotations

import hashlib
import io
import itertools
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from legws_daemon.core.geometry import FloatArray, rot_z
from legws_daemon.errors import LegwsError
from legws_daemon.formats.files import output_folder, regular_file, write_atomic
from legws_daemon.formats.nesting import check_json_nesting
from legws_daemon.robot.assets import arm_key, assets_dir
from legws_daemon.robot.batch_kinematics import BatchKinematics, batch_ik
from legws_daemon.robot.feasibility import TOL_POSITION, TOL_ROTATION, far_enough, ik_seeds
from legws_daemon.robot.gripper import FINGER_GAP, TCP_OFFSET
from legws_daemon.robot.world import World
from legws_daemon.scene.grasps import GRASP_KINDS, SIDE_MIN_HEIGHT, derive_grasp
from legws_daemon.scene.scene import ObjectPose, Scene

BoolArray = NDArray[np.bool_]
log = logging.getLogger("legws.reachability")

#: Bumped whenever the meaning of a cached map changes (algorithm, layout of the arrays).
FORMAT_VERSION = 1
#: Maps shipped with legws, named ``KEY.npz`` like the cache's.
SHIPPED = Path(__file__).parent / "maps"
#: Patience (iterations without 1 % progress) of warm starts and restarts.
_PATIENCE = 5
#: Where objects are moved while building (x, metres): out of the arm's reach.
_AWAY_X = 5.0
#: Cells solved at once (numpy's arrays stay in cache; ~1 kB per cell).
_CHUNK = 16_384


def _range(lo: float, hi: float, step: float) -> FloatArray:
    n = round((hi - lo) / step) + 1
    return np.asarray(lo + step * np.arange(n), dtype=np.float64)


def _heights(lo: float, hi: float, step: float) -> tuple[float, ...]:
    return tuple(round(float(h), 6) for h in _range(lo, hi, step))


@dataclass(frozen=True, slots=True)
class ReachabilityGrid:
    """Where the map is sampled.

    Attributes:
        x_range: ``(first, last)`` cell centre in x, metres (robot base frame).
        y_range: ``(first, last)`` cell centre in y.
        step: cell size in x and y.
        yaw_bins: number of yaw cells, centred on ``-pi + 2 pi k / yaw_bins``.
        top_heights: heights of the grasp point above the table for top grasps, ascending.
        side_heights: the same for side grasps. The default adds
            :data:`~legws_daemon.scene.grasps.SIDE_MIN_HEIGHT` (0.07 m), the height of the
            side grasp of every object 0.09 to 0.14 m tall, which would otherwise fall
            exactly between two cells.
        max_iterations: IK iterations per cell from the home configuration (as the full
            check).
        home_patience: from home, a cell also stops once its error has not dropped by 1 %
            for this many iterations (0: never); the warm starts pick up the few that
            would still have converged.
        warm_iterations: IK iterations of a warm start from a neighbouring cell's solution.
        restart_iterations: IK iterations from each further seed of the full check
            (:func:`~legws_daemon.robot.feasibility.ik_seeds`); ~95 % of those that succeed
            within 200 do within 30.
        inner_tolerance: IK stops iterating once within this fraction of the feasibility
            tolerances (the full check uses 1/5); it then needs to be within them.
    """

    x_range: tuple[float, float] = (0.20, 0.95)
    y_range: tuple[float, float] = (-0.55, 0.55)
    step: float = 0.025
    yaw_bins: int = 16
    top_heights: tuple[float, ...] = _heights(0.0, 0.26, 0.02)
    side_heights: tuple[float, ...] = tuple(sorted({*_heights(0.06, 0.26, 0.02), SIDE_MIN_HEIGHT}))
    max_iterations: int = 200
    home_patience: int = 20
    warm_iterations: int = 20
    restart_iterations: int = 30
    inner_tolerance: float = 0.2

    def __post_init__(self) -> None:
        for hs in (self.top_heights, self.side_heights):
            if not hs or any(b <= a for a, b in itertools.pairwise(hs)):
                raise LegwsError(f"grid heights must be non-empty and ascending, got {hs}")
        if self.step <= 0 or self.yaw_bins < 1 or self.max_iterations < 1:
            raise LegwsError("grid step, yaw bins and IK iterations must be positive")
        if min(self.home_patience, self.warm_iterations, self.restart_iterations) < 0:
            raise LegwsError("IK patience and iteration budgets must not be negative")
        if self.x_range[1] < self.x_range[0] or self.y_range[1] < self.y_range[0]:
            raise LegwsError(f"empty grid ranges x {self.x_range}, y {self.y_range}")

    @property
    def xs(self) -> FloatArray:
        return _range(self.x_range[0], self.x_range[1], self.step)

    @property
    def ys(self) -> FloatArray:
        return _range(self.y_range[0], self.y_range[1], self.step)

    @property
    def yaws(self) -> FloatArray:
        return np.asarray(-np.pi + 2 * np.pi * np.arange(self.yaw_bins) / self.yaw_bins)

    def heights(self, kind: str) -> FloatArray:
        return np.array(self.top_heights if kind == "top" else self.side_heights)

    def shape(self, kind: str) -> tuple[int, int, int, int]:
        """``(heights, yaws, xs, ys)`` of one kind's grid."""
        return (len(self.heights(kind)), self.yaw_bins, len(self.xs), len(self.ys))

    def cells(self) -> int:
        """IK problems of a build: top, side and flipped side frames."""
        return int(np.prod(self.shape("top")) + 2 * np.prod(self.shape("side")))

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)


#: The default grid: the tabletop in front of the Sawyer at 2.5 cm, 16 yaws.
DEFAULT_GRID = ReachabilityGrid()


def base_rotation(kind: str) -> FloatArray:
    """``B_kind``: the grasp frame of ``kind`` at yaw 0 (``atan2(R[1,0], R[0,0]) = 0``)."""
    R = derive_grasp("box", (0.1, 0.1, 0.1), "top" if kind == "top" else "side").rotation
    return np.asarray(rot_z(-np.arctan2(R[1, 0], R[0, 0])) @ R, dtype=np.float64)


def grasp_yaw(rotations: ArrayLike) -> FloatArray:
    """Yaw ``atan2(R[1, 0], R[0, 0])`` of grasp frames ``(..., 3, 3)``."""
    R = np.asarray(rotations, dtype=np.float64)
    return np.asarray(np.arctan2(R[..., 1, 0], R[..., 0, 0]), dtype=np.float64)


@dataclass(frozen=True, slots=True, eq=False)
class ReachabilityMap:
    """Reachable cells per grasp kind, each ``(heights, yaws, xs, ys)`` boolean.

    Attributes:
        grid: where the cells are.
        table_height: the table top the heights are measured from, metres.
        top: top grasps, frame ``Rz(yaw) @ B_top``.
        side: side grasps, frame ``Rz(yaw) @ B_side`` (frame y axis up).
        side_flipped: side grasps rolled half a turn about the approach axis,
            ``Rz(yaw) @ B_side @ Rz(pi)``, indexed by the yaw of the unflipped frame.
        key: the cache key the map was built for (empty when not from the cache).
        build_seconds: wall time of the build.
    """

    grid: ReachabilityGrid
    table_height: float
    top: BoolArray
    side: BoolArray
    side_flipped: BoolArray
    key: str = ""
    build_seconds: float = 0.0

    def __post_init__(self) -> None:
        for kind, arr in (("top", self.top), ("side", self.side), ("side", self.side_flipped)):
            if arr.shape != self.grid.shape(kind) or arr.dtype != np.bool_:
                raise LegwsError(
                    f"reachability grid of {kind} grasps has shape {arr.shape} and dtype "
                    f"{arr.dtype}; expected {self.grid.shape(kind)} bool"
                )

    def fraction(self, kind: str) -> float:
        """Share of reachable cells of one kind (``side`` counts either roll)."""
        arr = self.top if kind == "top" else self.side | self.side_flipped
        return float(arr.mean())

    # --- queries ------------------------------------------------------------------
    def lookup(
        self, kind: str, positions: ArrayLike, rotations: ArrayLike, symmetry: ArrayLike
    ) -> BoolArray:
        """Whether grasps are reachable without touching the table, by the nearest cell.

        Args:
            kind: ``top`` or ``side``, the kind of every grasp queried.
            positions: ``(..., 3)`` grasp points, robot base frame.
            rotations: ``(..., 3, 3)`` grasp frames.
            symmetry: symmetry orders, broadcast to ``(...)``; ``0`` means any turn.

        Returns:
            ``(...)`` booleans; ``False`` outside the grid and for frames not of ``kind``
            (a top frame must approach downward, a side frame horizontally with its y axis
            vertical).
        """
        if kind not in GRASP_KINDS:
            raise LegwsError(f"unknown grasp kind '{kind}'; known: {', '.join(GRASP_KINDS)}")
        p = np.asarray(positions, dtype=np.float64)
        R = np.asarray(rotations, dtype=np.float64)
        shape = p.shape[:-1]
        if p.shape[-1:] != (3,) or R.shape != (*shape, 3, 3):
            raise LegwsError(
                f"expected positions (..., 3) and rotations (..., 3, 3), got {p.shape} and "
                f"{R.shape}"
            )
        sym = np.broadcast_to(np.asarray(symmetry, dtype=np.int64), shape)
        g = self.grid
        ix = np.rint((p[..., 0] - g.x_range[0]) / g.step).astype(np.int64)
        iy = np.rint((p[..., 1] - g.y_range[0]) / g.step).astype(np.int64)
        heights = g.heights(kind)
        h = p[..., 2] - self.table_height
        ih = np.searchsorted((heights[1:] + heights[:-1]) / 2, h)
        top_margin = (heights[-1] - heights[-2]) / 2 if len(heights) > 1 else g.step / 2
        ok = (ix >= 0) & (ix < len(g.xs)) & (iy >= 0) & (iy < len(g.ys))
        ok &= (h >= heights[0] - 1e-9) & (h <= heights[-1] + top_margin)
        yaw = grasp_yaw(R)
        if kind == "top":
            ok &= R[..., 2, 2] < -0.9  # approach axis down
            flipped = np.zeros(shape, dtype=np.bool_)
        else:
            ok &= (np.abs(R[..., 2, 2]) < 0.1) & (np.abs(R[..., 2, 1]) > 0.9)
            flipped = R[..., 2, 1] < 0.0  # frame y axis down: the half-turn roll
            yaw = np.where(flipped, yaw - np.pi, yaw)
        ix, iy, ih = ix[ok], iy[ok], ih[ok]
        yaw, sym, flipped = yaw[ok], sym[ok], flipped[ok]
        hit = np.zeros(len(ix), dtype=np.bool_)
        if kind == "top":
            for n in np.unique(sym):
                sel = sym == n
                if n == 0:
                    any_yaw: BoolArray = np.any(self.top, axis=1)
                    hit[sel] = any_yaw[ih[sel], ix[sel], iy[sel]]
                    continue
                for k in range(int(n)):
                    iw = self._yaw_bin(yaw[sel] + 2 * np.pi * k / n)
                    hit[sel] |= self.top[ih[sel], iw, ix[sel], iy[sel]]
        else:
            iw = self._yaw_bin(yaw)
            up = self.side[ih, iw, ix, iy]
            down = self.side_flipped[ih, iw, ix, iy]
            both = (sym % 2) == 0  # a half turn is among the equivalents (also for 0)
            hit[:] = np.where(flipped, down, up) | (both & np.where(flipped, up, down))
        out = np.zeros(shape, dtype=np.bool_)
        out[ok] = hit
        return out

    def _yaw_bin(self, yaw: FloatArray) -> NDArray[np.int64]:
        n = self.grid.yaw_bins
        return np.asarray(np.rint((yaw + np.pi) * n / (2 * np.pi)).astype(np.int64) % n)

    def screen(self, scene: Scene, names: Sequence[str], poses: ArrayLike) -> BoolArray:
        """Reachability of the named objects' grasps in a batch of layouts.

        Args:
            scene: the scene (its table must be the map's).
            names: M object names.
            poses: ``(B, M, 3)`` object ``(x, y, yaw)``.

        Returns:
            ``(B, M)`` booleans.
        """
        th = float(scene.workspace.table_height)
        if abs(th - self.table_height) > 1e-9:
            raise LegwsError(
                f"the reachability map was built for a table at z = {self.table_height}, "
                f"scene '{scene.name}' has it at {th}"
            )
        positions, rotations, symmetry = scene.grasp_batch(names, poses)
        out = np.zeros(positions.shape[:2], dtype=np.bool_)
        for kind in GRASP_KINDS:
            cols = [j for j, n in enumerate(names) if scene.grasps[n].kind == kind]
            if cols:
                out[:, cols] = self.lookup(
                    kind, positions[:, cols], rotations[:, cols], symmetry[cols]
                )
        return out

    # --- files --------------------------------------------------------------------
    def save(self, path: Path) -> None:
        """Write the map to ``path`` (``.npz``) atomically: complete or not at all."""
        meta = {
            "format": FORMAT_VERSION,
            "key": self.key,
            "grid": self.grid.to_json(),
            "table_height": self.table_height,
            "build_seconds": self.build_seconds,
        }
        output_folder(path.parent)
        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            meta=np.array(json.dumps(meta)),
            top=self.top,
            side=self.side,
            side_flipped=self.side_flipped,
        )
        write_atomic(path, buf.getvalue())

    @staticmethod
    def load(path: Path, grid: ReachabilityGrid, key: str | None = None) -> ReachabilityMap:
        """Read a map written by :meth:`save`.

        Raises:
            LegwsError: unreadable, or not a map of ``grid`` (and ``key`` when given).
        """
        try:
            regular_file(path, "reachability map")  # not a FIFO or a device in its place
            with np.load(path, allow_pickle=False) as f:
                text = str(f["meta"][()])
                check_json_nesting(text, str(path))
                meta: dict[str, Any] = json.loads(text)
                top, side, flipped = (np.array(f[k]) for k in ("top", "side", "side_flipped"))
            if meta.get("format") != FORMAT_VERSION:
                raise LegwsError(f"format {meta.get('format')}, expected {FORMAT_VERSION}")
            if key is not None and meta.get("key") != key:
                raise LegwsError(f"key {meta.get('key')}, expected {key}")
            if meta.get("grid") != grid.to_json():
                raise LegwsError("built for another grid")
            if not np.isfinite(float(meta["table_height"])):
                raise LegwsError(f"table height {meta['table_height']}")
            return ReachabilityMap(
                grid=grid,
                table_height=float(meta["table_height"]),
                key=str(meta["key"]),
                build_seconds=float(meta["build_seconds"]),
                top=top,
                side=side,
                side_flipped=flipped,
            )
        except Exception as e:  # any failure means: not a usable map
            raise LegwsError(f"{path} is not a usable reachability map: {e}") from e


# --- build ------------------------------------------------------------------------------


class _TableContact:
    """Whether the arm touches anything but itself at a configuration: a lean
    :meth:`World.arm_contacts` (kinematics and collision detection only, contacts read as
    arrays), ~20 µs instead of ~100 µs. Objects are out of reach while the map is built,
    so what the arm can touch is the table."""

    def __init__(self, world: World) -> None:
        self.world = world
        m = world.model
        self.robot = np.array([int(b) in world.arm.robot_bodies for b in m.geom_bodyid])

    def __call__(self, q: FloatArray) -> bool:
        w = self.world
        m, d = w.model, w.data
        d.qpos[w.arm.qpos] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        if not d.ncon:
            return False
        c = d.contact
        hits = (self.robot[c.geom1] != self.robot[c.geom2]) & (c.dist <= 0)
        return bool(hits.any())


def _targets(
    grid: ReachabilityGrid, table_height: float
) -> list[tuple[str, FloatArray, FloatArray, tuple[int, ...]]]:
    """Per family (top, side, side_flipped): positions ``(N, 3)``, rotations ``(N, 3, 3)``
    in the grid's C order over ``(heights, yaws, xs, ys)``."""
    out: list[tuple[str, FloatArray, FloatArray, tuple[int, ...]]] = []
    for name, kind, roll in (
        ("top", "top", 0.0),
        ("side", "side", 0.0),
        ("side_flipped", "side", np.pi),
    ):
        shape = grid.shape(kind)
        H, W, X, Y = np.meshgrid(grid.heights(kind), grid.yaws, grid.xs, grid.ys, indexing="ij")
        pos = np.stack([X.ravel(), Y.ravel(), table_height + H.ravel()], axis=1).astype(float)
        B = base_rotation(kind) @ rot_z(roll)
        rot = rot_z(W.ravel()) @ B
        out.append((name, pos, np.asarray(rot, dtype=np.float64), shape))
    return out


class _Solver:
    """IK plus the table check for batches of one family's cells, with per-cell seeds."""

    def __init__(self, world: World, grid: ReachabilityGrid) -> None:
        self.world = world
        self.grid = grid
        self.kin = BatchKinematics(world)
        self.touches = _TableContact(world)

    def __call__(
        self,
        positions: FloatArray,
        rotations: FloatArray,
        seeds: FloatArray,
        iterations: int,
        patience: int,
    ) -> tuple[BoolArray, FloatArray]:
        """Which targets IK reaches within the feasibility tolerances with the arm clear of
        the table, and the configurations ``(N, n)``; ``seeds`` ``(n,)`` or ``(N, n)``
        (``n`` the arm's DoF)."""
        n, dof = len(positions), self.world.dof
        ok = np.zeros(n, dtype=np.bool_)
        qs = np.empty((n, dof))
        seeds = np.broadcast_to(seeds, (n, dof))
        tol = self.grid.inner_tolerance
        for s in range(0, n, _CHUNK):
            chunk = slice(s, s + _CHUNK)
            q, ep, er = batch_ik(
                self.world,
                positions[chunk],
                rotations[chunk],
                seeds[chunk],
                tol_position=TOL_POSITION * tol,
                tol_rotation=TOL_ROTATION * tol,
                max_iterations=iterations,
                patience=patience,
                kinematics=self.kin,
            )
            hit = (ep <= TOL_POSITION) & (er <= TOL_ROTATION)
            hit &= far_enough(self.world.spec, positions[chunk])
            for i in np.flatnonzero(hit):
                hit[i] = not self.touches(q[i])
            ok[chunk], qs[chunk] = hit, q
        return ok, qs


def _neighbours(shape: tuple[int, ...]) -> NDArray[np.int64]:
    """``(N, 8)`` flat index of each cell's neighbour one step down and up each axis of
    ``(heights, yaws, xs, ys)`` (yaw wraps around), ``-1`` past an edge."""
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    out = []
    for axis in range(4):
        for step in (-1, 1):
            nb = np.roll(idx, -step, axis=axis)
            if axis != 1:
                edge = [slice(None)] * 4
                edge[axis] = slice(-1, None) if step == 1 else slice(0, 1)
                nb[tuple(edge)] = -1
            out.append(nb.ravel())
    return np.stack(out, axis=1)


def _family(
    solve: _Solver,
    positions: FloatArray,
    rotations: FloatArray,
    shape: tuple[int, ...],
    seeds: list[FloatArray],
) -> BoolArray:
    """Reachable cells of one family of grasp frames, flat."""
    g = solve.grid
    ok, qs = solve(positions, rotations, seeds[0], g.max_iterations, g.home_patience)
    neighbours = _neighbours(shape)
    tried = np.zeros(neighbours.shape, dtype=np.bool_)  # warm start from that neighbour
    restarted = np.zeros(len(ok), dtype=np.bool_)
    while True:
        # warm starts: cells next to solved ones, from their solutions, until none grows
        grew = True
        while grew:
            grew = False
            for k in range(neighbours.shape[1]):
                nb = neighbours[:, k]
                cells = np.flatnonzero(~ok & (nb >= 0) & ~tried[:, k])
                cells = cells[ok[nb[cells]]]
                if not len(cells):
                    continue
                tried[cells, k] = True
                hit, q = solve(
                    positions[cells], rotations[cells], qs[nb[cells]], g.warm_iterations, _PATIENCE
                )
                ok[cells[hit]], qs[cells[hit]] = True, q[hit]
                grew |= bool(hit.any())
        # the full check's restarts, on the unsolved cells next to solved ones
        border = ~ok & ~restarted & (ok[neighbours] & (neighbours >= 0)).any(axis=1)
        cells = np.flatnonzero(border)
        if not len(cells):
            break
        restarted[cells] = True
        # all seeds at once (one large batch): few cells are solved by any of them
        tries = np.repeat(cells, len(seeds) - 1)
        starts = np.tile(np.asarray(seeds[1:]), (len(cells), 1))
        hit, q = solve(positions[tries], rotations[tries], starts, g.restart_iterations, _PATIENCE)
        # of each cell's successful seeds, the last one's configuration is kept
        ok[tries[hit]], qs[tries[hit]] = True, q[hit]
    return ok


def build(
    world: World,
    q_home: ArrayLike,
    grid: ReachabilityGrid = DEFAULT_GRID,
    progress: Callable[[int, int], None] | None = None,
) -> ReachabilityMap:
    """Compute the reachability map of the world's arm over ``grid``.

    Each family of grasp frames (top, side, rolled side) is solved in three steps:

    1. every cell from the home configuration, as the full check's first attempt;
    2. warm starts: an unsolved cell next to a solved one starts from that cell's
       solution (few iterations), repeated while cells are added;
    3. the full check's restarts (:func:`~legws_daemon.robot.feasibility.ik_seeds`) on the
       unsolved cells next to solved ones, then back to 2 while cells are added.

    Cells far inside an unreachable region are thus never retried (most of the cost of
    the full check's restarts); a reachable pocket with no reachable neighbour would be
    missed. Objects are moved out of reach while building; the world's layout and arm
    configuration are restored afterwards.

    Args:
        world: the simulated world (its table and robot are mapped).
        q_home: ``(7,)`` home configuration, the first seed.
        grid: where to sample, and the IK budgets.
        progress: called with ``(families done, 3)`` after each family.
    """
    started = time.perf_counter()
    q_home = np.asarray(q_home, dtype=np.float64)
    table_height = float(world.scene.workspace.table_height)
    d = world.data
    saved = (d.mocap_pos.copy(), d.mocap_quat.copy(), world.q)
    solve = _Solver(world, grid)
    _check_kinematics(world, solve.kin, q_home)
    seeds = ik_seeds(world, q_home)
    families = _targets(grid, table_height)
    out: dict[str, BoolArray] = {}
    try:
        world.set_layout({n: ObjectPose(_AWAY_X, 0.0, 0.0) for n in world.scene.objects})
        for done, (name, pos, rot, shape) in enumerate(families, start=1):
            out[name] = _family(solve, pos, rot, shape, seeds).reshape(shape)
            if progress is not None:
                progress(done, len(families))
    finally:
        d.mocap_pos[:], d.mocap_quat[:] = saved[0], saved[1]
        world.set_q(saved[2])
    return ReachabilityMap(
        grid=grid,
        table_height=table_height,
        top=out["top"],
        side=out["side"],
        side_flipped=out["side_flipped"],
        build_seconds=time.perf_counter() - started,
    )


def _check_kinematics(world: World, kin: BatchKinematics, q_home: FloatArray) -> None:
    """The numpy chain must agree with MuJoCo (guards against a changed robot model)."""
    rng = np.random.default_rng(0)
    qs = np.vstack([q_home, rng.uniform(world.arm.lower, world.arm.upper, size=(4, world.dof))])
    ee, R, J = kin.forward(qs)
    saved = world.q
    try:
        for i, q in enumerate(qs):
            world.set_q(q)
            if (
                not np.allclose(ee[i], world.ee_position(), atol=1e-9)
                or not np.allclose(R[i], world.ee_rotation(), atol=1e-9)
                or not np.allclose(J[i], world.jacobian(), atol=1e-9)
            ):
                raise LegwsError(
                    "the batched kinematics of the reachability map disagree with MuJoCo's: "
                    "the robot model changed"
                )
    finally:
        world.set_q(saved)


# --- cache ------------------------------------------------------------------------------


def cache_key(world: World, q_home: ArrayLike, grid: ReachabilityGrid = DEFAULT_GRID) -> str:
    """Hash of what a map depends on: robot description (its files and the arm's whole
    registration: joints, limits, mount, hand, nearest reach), gripper, collision meshes in
    use, table, home configuration, tolerances, grid and the map's format."""
    ws = world.scene.workspace
    spec = world.spec
    h = hashlib.sha256()
    # every file of the model, verified, and the arm's whole description
    h.update(arm_key(spec).encode())
    facts = {
        "format": FORMAT_VERSION,
        "tcp_offset": TCP_OFFSET,
        "finger_gap": FINGER_GAP,
        "meshes": int(world.model.nmesh),
        "table": [ws.table_height, list(ws.table_center), list(ws.table_size)],
        "seeds": [[round(float(v), 5) for v in s] for s in ik_seeds(world, np.asarray(q_home))],
        "tolerances": [TOL_POSITION, TOL_ROTATION],
        "grid": grid.to_json(),
    }
    h.update(json.dumps(facts, sort_keys=True).encode())
    return h.hexdigest()[:20]


def load_or_build(
    world: World,
    q_home: ArrayLike,
    grid: ReachabilityGrid = DEFAULT_GRID,
    *,
    directory: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    build_anew: bool = False,
) -> ReachabilityMap:
    """The map from the cache, else the one shipped with legws for this key, else built
    (and cached) — also when the cached file is corrupt or stale.

    Args:
        directory: cache folder; default ``assets_dir() / "reachability"``.
        build_anew: build it even when the cache or legws holds it (and replace the cache).
    """
    key = cache_key(world, q_home, grid)
    path = (directory or assets_dir() / "reachability") / f"{key}.npz"
    for source in () if build_anew else (path, SHIPPED / f"{key}.npz"):
        if not source.exists():
            continue
        try:
            found = ReachabilityMap.load(source, grid, key)
        except LegwsError as err:  # the next source, else built below; the cache replaced
            what = (
                "replacing the reachability map" if source == path else "not using " + str(source)
            )
            log.warning("legws: warning: %s: %s", what, err)
            continue
        if source != path:
            _cache(found, path)
        return found
    result = replace(build(world, q_home, grid, progress), key=key)
    _cache(result, path)
    return result


def _cache(found: ReachabilityMap, path: Path) -> None:
    try:
        found.save(path)
    except (LegwsError, OSError) as err:  # the map is good; only the cache is lost
        log.warning("legws: warning: the reachability map is not cached: %s", err)
