"""The arm's visual meshes per link: what the telemetry draws is where MuJoCo has it."""

from __future__ import annotations

from functools import cache

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.robot.gripper import FINGER_GAP
from legws_daemon.robot.visual import (
    CLOSED_GAP,
    VISUAL_GROUP,
    RobotVisual,
    finger_half_gap,
    robot_visual,
    vertex_normals,
)
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene

PREFIX = "sawyer/"


@cache
def _world() -> World:
    world = World(load_scene("desk"))
    world.set_q([0.3, -0.6, 0.2, 1.1, -0.4, 0.8, 0.5])  # somewhere away from zero
    return world


@cache
def _visual() -> RobotVisual:
    return robot_visual(_world())


def test_every_visual_mesh_of_the_arm_is_in_it_once() -> None:
    m = _world().model
    meshes = [
        g
        for g in range(m.ngeom)
        if int(m.geom_bodyid[g]) in _world().arm.robot_bodies
        and int(m.geom_group[g]) == VISUAL_GROUP
        and int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_MESH
    ]
    expected = sum(int(m.mesh_vertnum[m.geom_dataid[g]]) for g in meshes)
    v = _visual()
    assert v.vertex_count == expected > 100_000
    assert len(v.links) == len(_world().link_ids)
    assert {m.name for m in v.meshes} >= {f"right_l{i}" for i in range(7)}
    for mesh in v.meshes:
        assert mesh.triangles.max() < len(mesh.vertices)
        assert mesh.colors.dtype == np.uint32 and len(mesh.colors) == len(mesh.vertices)
    assert [b.name for b in v.boxes] == ["gripper_base"]
    assert v.fingers is not None and v.links[v.fingers.link] == "right_hand"


def test_meshes_at_the_link_poses_are_where_mujoco_puts_its_geoms() -> None:
    """Each link's mesh, moved by that link's pose from ``link_poses`` (what the daemon
    logs each tick), lands on MuJoCo's own world placement of the geoms."""
    world = _world()
    m, d = world.model, world.data
    positions, rotations = world.link_poses()
    v = _visual()
    for mesh in v.meshes:
        body = int(world.link_ids[mesh.link])
        placed = mesh.vertices.astype(np.float64) @ rotations[mesh.link].T + positions[mesh.link]
        expected = []
        for g in range(m.ngeom):
            if int(m.geom_bodyid[g]) != body or int(m.geom_group[g]) != VISUAL_GROUP:
                continue
            if int(m.geom_type[g]) != mujoco.mjtGeom.mjGEOM_MESH:
                continue
            k = int(m.geom_dataid[g])
            local = m.mesh_vert[m.mesh_vertadr[k] : m.mesh_vertadr[k] + m.mesh_vertnum[k]]
            expected.append(local @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g])
        np.testing.assert_allclose(placed, np.concatenate(expected), atol=2e-6)
        assert m.body(body).name == PREFIX + mesh.name


def test_fingers_sit_where_the_model_has_them_when_open() -> None:
    world, v = _world(), _visual()
    assert v.fingers is not None
    m = world.model
    for side, center in zip(("l", "r"), v.fingers.centers(FINGER_GAP), strict=True):
        geom = m.geom(f"{PREFIX}finger_{side}")
        np.testing.assert_allclose(center, geom.pos, atol=1e-12)


def test_a_model_without_meshes_borrows_them() -> None:
    kinematic = World(load_scene("desk"), visual=False)
    v = robot_visual(kinematic)
    assert v.vertex_count == _visual().vertex_count
    assert v.links == _visual().links
    assert v.drawn_links == _visual().drawn_links


@pytest.mark.parametrize(
    ("closed", "width", "gap"),
    [(False, None, FINGER_GAP), (False, 0.03, FINGER_GAP), (True, None, CLOSED_GAP),
     (True, 0.03, 0.015), (True, 0.5, FINGER_GAP), (True, float("nan"), CLOSED_GAP),
     (True, -1.0, CLOSED_GAP)],
)  # fmt: skip
def test_finger_half_gap(closed: bool, width: float | None, gap: float) -> None:
    assert finger_half_gap(closed, width) == pytest.approx(gap)


@settings(max_examples=30, deadline=None)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_vertex_normals_are_unit_and_face_outward_on_a_convex_solid(seed: int) -> None:
    """On a convex hull, every vertex normal points away from the centre."""
    from scipy.spatial import ConvexHull

    points = np.random.default_rng(seed).normal(size=(40, 3))
    hull = ConvexHull(points)
    triangles = hull.simplices.copy()
    centre = points[hull.vertices].mean(axis=0)
    for t in triangles:  # orient every face outward (the hull's order is arbitrary)
        n = np.cross(points[t[1]] - points[t[0]], points[t[2]] - points[t[0]])
        if n @ (points[t[0]] - centre) < 0:
            t[1], t[2] = t[2], t[1]
    normals = vertex_normals(points, triangles)
    used = np.unique(triangles)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert np.all(np.sum(normals[used] * (points[used] - centre), axis=1) > 0)
    unused = np.setdiff1d(np.arange(len(points)), used)
    np.testing.assert_array_equal(normals[unused], np.tile([0.0, 0.0, 1.0], (len(unused), 1)))
