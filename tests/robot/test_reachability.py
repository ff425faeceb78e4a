"""The reachability map: agreement with the full check, lookup semantics, the disk cache."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.arms import arm_names
from legws_daemon.core.geometry import Pose, matrix_to_quat, rot_z
from legws_daemon.core.goals import GoalSet
from legws_daemon.robot import reachability
from legws_daemon.robot.batch_kinematics import batch_ik
from legws_daemon.robot.feasibility import check_grasps
from legws_daemon.robot.kinematics import home_configuration, solve_ik
from legws_daemon.robot.reachability import (
    ReachabilityGrid,
    ReachabilityMap,
    base_rotation,
    build,
    grasp_yaw,
    load_or_build,
)
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.grasps import derive_grasp
from legws_daemon.scene.scene import ObjectPose

SMALL = ReachabilityGrid(
    x_range=(0.5, 0.8),
    y_range=(-0.2, 0.2),
    step=0.05,
    yaw_bins=8,
    top_heights=(0.04, 0.12, 0.20),
    side_heights=(0.08, 0.14, 0.20),
)
#: The far corner of the table, where the arm is at the end of its reach.
CORNER = ReachabilityGrid(
    x_range=(0.90, 0.95),
    y_range=(0.50, 0.55),
    step=0.05,
    yaw_bins=8,
    top_heights=(0.14,),
    side_heights=(0.14,),
)


@pytest.fixture(scope="module")
def desk() -> tuple[World, np.ndarray]:
    sc = load_scene("desk")
    w = World(sc)
    return w, home_configuration(w, sc.home.position, sc.home.rotation).q


@pytest.fixture(scope="module")
def small(desk: tuple[World, np.ndarray]) -> ReachabilityMap:
    return build(*desk, SMALL)


def test_base_rotations_are_a_bijection_with_the_object_yaw() -> None:
    # Grasp.world gives Rz(object yaw) @ R_kind; its yaw is the object's plus a quarter turn
    yaws = np.linspace(-np.pi, np.pi, 13, endpoint=False)
    for kind in ("top", "side"):
        g = derive_grasp("box", (0.1, 0.05, 0.2), kind)
        _, R = g.world(np.zeros_like(yaws), np.zeros_like(yaws), yaws, 0.1)
        psi = grasp_yaw(R)
        np.testing.assert_allclose(np.angle(np.exp(1j * (psi - yaws - np.pi / 2))), 0, atol=1e-12)
        np.testing.assert_allclose(R, rot_z(psi) @ base_rotation(kind), atol=1e-12)


def test_batched_ik_is_solve_ik_for_many_targets(desk: tuple[World, np.ndarray]) -> None:
    w, q_home = desk
    rng = np.random.default_rng(3)
    n = 12
    pos = np.stack(
        [rng.uniform(0.2, 0.95, n), rng.uniform(-0.55, 0.55, n), rng.uniform(0.0, 0.26, n)], 1
    )
    rot = rot_z(rng.uniform(-np.pi, np.pi, n)) @ base_rotation("side")
    q, ep, er = batch_ik(
        w, pos, rot, q_home, tol_position=1e-3, tol_rotation=1e-2, max_iterations=200
    )
    for i in range(n):
        one = solve_ik(w, pos[i], rot[i], q_home, tol_position=1e-3, tol_rotation=1e-2)
        np.testing.assert_allclose(q[i], one.q, atol=1e-8)
        assert (ep[i] <= 0.005 and er[i] <= 0.05) == (
            one.position_error <= 0.005 and one.rotation_error <= 0.05
        )
    w.set_q(q_home)


def _agreement_with_the_full_check(
    w: World, q_home: np.ndarray, m: ReachabilityMap, per_family: int, seed: int
) -> None:
    """Random cells of ``m``: the full check agrees on most, and the lookup finds them."""
    rng = np.random.default_rng(seed)
    g = m.grid
    positions, rotations, expected = [], [], []
    for kind, roll, table in (
        ("top", 0.0, m.top),
        ("side", 0.0, m.side),
        ("side", np.pi, m.side_flipped),
    ):
        for _ in range(per_family):
            ih, iw, ix, iy = (int(rng.integers(n)) for n in table.shape)
            positions.append([g.xs[ix], g.ys[iy], g.heights(kind)[ih]])
            rotations.append(rot_z(g.yaws[iw]) @ base_rotation(kind) @ rot_z(roll))
            expected.append(bool(table[ih, iw, ix, iy]))
    pos, rot = np.array(positions), np.array(rotations)
    names = tuple(f"g{i}" for i in range(len(pos)))
    home = Pose(w.scene.home.position, w.scene.home.quaternion)
    away = {n: ObjectPose(5.0, 0.0, 0.0) for n in w.scene.objects}
    checks = {}
    for part in range(0, len(pos), 25):  # a goal set holds at most MAX_GOALS goals
        cut = slice(part, part + 25)
        goals = GoalSet(names[cut], pos[cut], matrix_to_quat(rot[cut]),
                        np.ones(len(pos[cut]), dtype=np.int64), home)  # fmt: skip
        checks.update(check_grasps(w, goals, q_home, away))
    full = np.array([checks[n].feasible for n in names])
    agreement = float(np.mean(full == np.array(expected)))
    assert agreement >= 0.9, f"map and full check agree on {agreement:.0%}"
    assert full.any() and not full.all()  # the sample holds both answers
    # the lookup finds the same cells (rolled side frames included)
    kinds = ["top"] * per_family + ["side"] * (2 * per_family)
    looked = [m.lookup(k, p, r, 1) for k, p, r in zip(kinds, pos, rot, strict=True)]
    assert np.array_equal(np.array(looked), np.array(expected))
    w.set_layout(w.scene.poses())


def test_the_map_agrees_with_the_full_check_at_grid_points(
    desk: tuple[World, np.ndarray], small: ReachabilityMap
) -> None:
    _agreement_with_the_full_check(*desk, small, 25, 0)


def test_the_shipped_map_is_the_fetched_models_and_agrees_with_the_full_check(
    desk: tuple[World, np.ndarray],
) -> None:
    """legws ships the default grid's map for the model it fetches: its key is the one the
    model, table, seeds, tolerances and grid give now (else it is stale: refresh it with
    ``legws assets reachability --build`` and copy the cache's file into
    legws_daemon/robot/maps/), and random cells of it agree with the full check."""
    w, q_home = desk
    keys = {reachability.cache_key(w, q_home)}
    for name in arm_names():  # one map per registered arm, and nothing else
        if name != w.spec.name:
            other = World(w.scene, arm=name)
            home = home_configuration(other, w.scene.home.position, w.scene.home.rotation)
            keys.add(reachability.cache_key(other, home.q))
    shipped = sorted(p.name for p in reachability.SHIPPED.glob("*.npz"))
    assert shipped == sorted(f"{k}.npz" for k in keys), f"stale reachability maps: {shipped}"
    key = reachability.cache_key(w, q_home)
    m = ReachabilityMap.load(reachability.SHIPPED / f"{key}.npz", reachability.DEFAULT_GRID, key)
    _agreement_with_the_full_check(w, q_home, m, 25, 1)


def test_a_side_grasp_facing_away_at_the_far_corner_is_unreachable(
    desk: tuple[World, np.ndarray],
) -> None:
    w, q_home = desk
    w.set_q(q_home)
    before = (w.q, w.data.mocap_pos.copy())
    m = build(w, q_home, CORNER)
    # the world is left as found: arm configuration and object poses
    assert np.array_equal(w.q, before[0]) and np.array_equal(w.data.mocap_pos, before[1])
    grasp = derive_grasp("box", (0.08, 0.08, 0.28), "side")  # symmetry 2
    outward = float(np.arctan2(0.54, 0.94))
    # the gripper stands behind the object, approaching toward the robot
    p, R = grasp.world(0.94, 0.54, outward + np.pi, 0.14)
    p[:2] = [0.94, 0.54]
    assert not m.lookup("side", p, R, grasp.symmetry)
    # the same point approached from the robot's side is reachable: the map is not empty
    # there, and a half turn of yaw (what a naive symmetry would try) is not an equivalent
    p2, R2 = grasp.world(0.94, 0.54, outward, 0.14)
    p2[:2] = [0.94, 0.54]
    assert m.lookup("side", p2, R2, grasp.symmetry)
    assert not m.lookup("side", p, R, 1) and not m.lookup("side", p, R @ rot_z(np.pi), 1)
    # outside the grid: False
    assert not m.lookup("side", p + np.array([0.1, 0.0, 0.0]), R2, 2)


def _synthetic(top_bin: int, side_bin: int) -> ReachabilityMap:
    g = SMALL
    top = np.zeros(g.shape("top"), dtype=bool)
    side = np.zeros(g.shape("side"), dtype=bool)
    flipped = np.zeros(g.shape("side"), dtype=bool)
    top[1, top_bin, 3, 4] = True
    flipped[1, side_bin, 3, 4] = True
    return ReachabilityMap(g, 0.0, top, side, flipped)


def test_symmetric_grasps_are_reachable_when_any_equivalent_is() -> None:
    m = _synthetic(top_bin=2, side_bin=5)
    g = SMALL
    p = np.array([g.xs[3] + 0.01, g.ys[4] - 0.01, 0.13])  # nearest cell (1, ·, 3, 4)
    Rt = rot_z(g.yaws[6]) @ base_rotation("top")  # only bin 2 is reachable
    # a cylinder's top grasp (symmetry 0): reachable when any yaw is
    assert m.lookup("top", p, Rt, 0)
    assert not m.lookup("top", p, Rt, 1)
    assert m.lookup("top", p, Rt, 2)  # bin 6 + half a turn = bin 2
    assert not m.lookup("top", p, rot_z(g.yaws[5]) @ base_rotation("top"), 2)
    assert m.lookup("top", p, rot_z(g.yaws[4]) @ base_rotation("top"), 4)
    # batched, one symmetry per column
    both = m.lookup("top", np.stack([p, p]), np.stack([Rt, Rt]), np.array([1, 0]))
    assert both.tolist() == [False, True]
    # side: only the rolled frame of bin 5 is reachable
    Rs = rot_z(g.yaws[5]) @ base_rotation("side")
    assert m.lookup("side", p, Rs, 2)  # the half-turn roll is an equivalent
    assert not m.lookup("side", p, Rs, 1)
    assert m.lookup("side", p, Rs @ rot_z(np.pi), 1)  # the rolled frame itself
    assert not m.lookup("side", p, rot_z(g.yaws[1]) @ base_rotation("side"), 2)  # yaw + pi
    # a top frame queried as a side grasp is not a side grasp
    assert not m.lookup("side", p, Rt, 0)


def test_symmetry_zero_is_any_yaw_on_a_built_map(small: ReachabilityMap) -> None:
    g = SMALL
    H, X, Y = np.meshgrid(g.heights("top"), g.xs, g.ys, indexing="ij")
    p = np.stack([X, Y, H], axis=-1)
    R = np.broadcast_to(rot_z(1.0) @ base_rotation("top"), (*H.shape, 3, 3))
    assert np.array_equal(small.lookup("top", p, R, 0), small.top.any(axis=1))
    # below the lowest side height: False
    ps = p.copy()
    ps[..., 2] = g.side_heights[0] - 0.01
    Rs = np.broadcast_to(base_rotation("side"), R.shape)
    assert not small.lookup("side", ps, Rs, 2).any()


def test_screen_uses_each_objects_grasp(small: ReachabilityMap) -> None:
    sc = load_scene("desk")
    names = list(sc.goal_names)
    poses = np.array([[[0.6, -0.1, 0.3], [0.7, 0.1, -1.0], [0.55, 0.0, 2.0]]])[:, : len(names)]
    got = small.screen(sc, names, poses)
    pos, rot, sym = sc.grasp_batch(names, poses)
    for j, n in enumerate(names):
        kind = sc.grasps[n].kind
        assert got[0, j] == small.lookup(kind, pos[0, j], rot[0, j], sym[j])


def test_the_cache_is_written_reused_and_rebuilt_when_corrupt(
    desk: tuple[World, np.ndarray],
    small: ReachabilityMap,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    w, q_home = desk
    built = []

    def counted(*args: object, **kwargs: object) -> ReachabilityMap:
        built.append(1)
        return small

    monkeypatch.setattr(reachability, "build", counted)
    first = load_or_build(w, q_home, SMALL, directory=tmp_path)
    files = list(tmp_path.glob("*.npz"))
    assert len(built) == 1
    assert [f.name for f in files] == [f"{first.key}.npz"]

    def fail(*args: object, **kwargs: object) -> ReachabilityMap:
        raise AssertionError("rebuilt although cached")

    monkeypatch.setattr(reachability, "build", fail)
    again = load_or_build(w, q_home, SMALL, directory=tmp_path)
    for a in ("top", "side", "side_flipped"):
        assert np.array_equal(getattr(again, a), getattr(small, a))
    assert again.key == first.key

    monkeypatch.setattr(reachability, "build", counted)
    files[0].write_bytes(b"\x00garbage" * 50)
    load_or_build(w, q_home, SMALL, directory=tmp_path)
    assert len(built) == 2
    # a readable map of another grid under this key: mismatching shapes, rebuilt too
    stale = replace(small, top=small.top[:1], grid=replace(SMALL, top_heights=(0.04,)))
    stale.save(files[0])
    rebuilt = load_or_build(w, q_home, SMALL, directory=tmp_path)
    assert len(built) == 3
    assert ReachabilityMap.load(files[0], SMALL, rebuilt.key).key == rebuilt.key
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left


def test_a_shipped_map_is_copied_into_the_cache_instead_of_building(
    desk: tuple[World, np.ndarray],
    small: ReachabilityMap,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    w, q_home = desk
    key = reachability.cache_key(w, q_home, SMALL)
    shipped, cache = tmp_path / "shipped", tmp_path / "cache"
    replace(small, key=key).save(shipped / f"{key}.npz")
    monkeypatch.setattr(reachability, "SHIPPED", shipped)

    def fail(*args: object, **kwargs: object) -> ReachabilityMap:
        raise AssertionError("built although shipped")

    monkeypatch.setattr(reachability, "build", fail)
    got = load_or_build(w, q_home, SMALL, directory=cache)
    assert got.key == key and np.array_equal(got.top, small.top)
    assert ReachabilityMap.load(cache / f"{key}.npz", SMALL, key).key == key  # cached
    # --build: built although shipped and cached, and the cache replaced
    flipped = replace(small, top=~small.top)
    monkeypatch.setattr(reachability, "build", lambda *a, **k: flipped)
    anew = load_or_build(w, q_home, SMALL, directory=cache, build_anew=True)
    assert np.array_equal(anew.top, ~small.top)
    assert np.array_equal(ReachabilityMap.load(cache / f"{key}.npz", SMALL, key).top, ~small.top)
    # a damaged shipped map is not used: built instead
    (cache / f"{key}.npz").unlink()
    (shipped / f"{key}.npz").write_bytes(b"\x00garbage")
    assert np.array_equal(load_or_build(w, q_home, SMALL, directory=cache).top, ~small.top)
