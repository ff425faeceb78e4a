"""Scene composition, the EE frame convention, the asset cache."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene, scene_names
from legws_daemon.scene.scene import ObjectPose


@pytest.mark.parametrize("name", scene_names())
def test_every_scene_composes_and_compiles(name: str) -> None:
    sc = load_scene(name)
    w = World(sc)
    m = w.model
    assert m.nq == 7  # the arm's joints; objects are mocap bodies
    for obj in sc.objects:
        assert m.body(f"obj/{obj}").mocapid[0] >= 0
    # the object sits on the table at its layout pose
    pose = sc.poses()[next(iter(sc.objects))]
    body = w.data.body(f"obj/{next(iter(sc.objects))}")
    np.testing.assert_allclose(body.xpos[:2], [pose.x, pose.y], atol=1e-9)
    # the arm reaches the EE home with the gripper pointing down
    q = home_configuration(w, sc.home.position, sc.home.rotation).q
    np.testing.assert_allclose(w.ee_position(), sc.home.position, atol=1e-3)
    np.testing.assert_allclose(w.ee_rotation()[:, 2], [0, 0, -1], atol=1e-3)
    assert np.all(q >= w.arm.lower) and np.all(q <= w.arm.upper)
    assert w.arm_contacts() == []


def test_set_layout_moves_objects_without_recompiling() -> None:
    sc = load_scene("desk")
    w = World(sc, visual=False)
    w.set_layout({"white_mug": ObjectPose(0.5, -0.3, 1.0)})
    body = w.data.body("obj/white_mug")
    np.testing.assert_allclose(body.xpos, [0.5, -0.3, sc.z_center("white_mug")], atol=1e-12)
    np.testing.assert_allclose(body.xquat, [np.cos(0.5), 0, 0, np.sin(0.5)], atol=1e-12)


def test_without_meshes_kinematics_is_the_same() -> None:
    sc = load_scene("breakfast_easy")
    full, bare = World(sc), World(sc, visual=False)
    q = np.array([0.3, -0.9, 0.2, 1.5, -0.3, 1.0, 0.4])
    full.set_q(q)
    bare.set_q(q)
    np.testing.assert_allclose(full.ee_position(), bare.ee_position(), atol=1e-12)
    np.testing.assert_allclose(full.jacobian(), bare.jacobian(), atol=1e-12)


def test_jacobian_matches_finite_differences() -> None:
    w = World(load_scene("breakfast_easy"), visual=False)
    q = np.array([0.1, -0.8, 0.3, 1.6, -0.2, 0.9, 0.5])
    w.set_q(q)
    J = w.jacobian()
    h = 1e-6
    for k in range(7):
        e = np.zeros(7)
        e[k] = h
        w.set_q(q + e)
        p1, R1 = w.ee_position(), w.ee_rotation().copy()
        w.set_q(q - e)
        p0, R0 = w.ee_position(), w.ee_rotation().copy()
        np.testing.assert_allclose((p1 - p0) / (2 * h), J[:3, k], atol=1e-6)
        dR = (R1 - R0) / (2 * h) @ R0.T  # skew(omega)
        np.testing.assert_allclose([dR[2, 1], dR[0, 2], dR[1, 0]], J[3:, k], atol=1e-5)


def test_missing_asset_cache_says_which_command_fetches_it(
    tmp_path: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("LEGWS_ASSETS", str(tmp_path))
    with pytest.raises(InputError, match=r"fetch it with: \./dev setup") as info:
        World(load_scene("desk"))
    assert "\n" not in str(info.value)
