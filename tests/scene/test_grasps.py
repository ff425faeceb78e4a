"""Grasp library: poses derived from bounding boxes, approach axes, declared symmetry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from legws_daemon.scene.grasps import FINGER_DEPTH, SIDE_MIN_HEIGHT, derive_grasp


def test_top_grasp_of_a_box_points_down_below_the_top_surface() -> None:
    g = derive_grasp("box", (0.16, 0.04, 0.05), "top")
    pos, rot = g.world(0.7, -0.1, 0.0, z_center=0.025)
    np.testing.assert_allclose(pos, [0.7, -0.1, 0.05 - FINGER_DEPTH])
    np.testing.assert_allclose(rot[:, 2], [0, 0, -1], atol=1e-15)  # approach: down
    np.testing.assert_allclose(rot[:, 0], [0, 1, 0], atol=1e-15)  # fingers close across local y
    assert np.linalg.det(rot) == pytest.approx(1.0)
    assert g.symmetry == 2


def test_top_grasp_yaw_follows_the_object() -> None:
    g = derive_grasp("box", (0.16, 0.04, 0.05), "top")
    _, rot = g.world(0.7, 0.0, math.pi / 2, z_center=0.025)
    np.testing.assert_allclose(rot[:, 0], [-1, 0, 0], atol=1e-12)  # local y turned to -x


def test_side_grasp_approaches_horizontally_at_mid_height() -> None:
    g = derive_grasp("cylinder", (0.04, 0.22), "side")  # a bottle: mid-height 11 cm
    pos, rot = g.world(0.6, 0.2, math.pi / 2, z_center=0.11)
    np.testing.assert_allclose(rot[:, 2], [0, 1, 0], atol=1e-12)  # local +x turned to +y
    np.testing.assert_allclose(rot[:, 1], [0, 0, 1], atol=1e-12)
    # origin FINGER_DEPTH inside the face on the approach side, at mid-height
    np.testing.assert_allclose(pos, [0.6, 0.2 - (0.04 - FINGER_DEPTH), 0.11], atol=1e-12)
    assert g.symmetry == 2


@pytest.mark.parametrize(
    ("height", "grasp_z"),
    [(0.095, SIDE_MIN_HEIGHT), (0.122, SIDE_MIN_HEIGHT), (0.14, SIDE_MIN_HEIGHT), (0.2, 0.1),
     (0.08, 0.08 - FINGER_DEPTH)],
)  # fmt: skip
def test_low_side_grasps_are_raised_to_clear_the_wrist(height: float, grasp_z: float) -> None:
    """Mid-height, raised to SIDE_MIN_HEIGHT above the table, never above top - depth."""
    g = derive_grasp("cylinder", (0.04, height), "side")
    pos, _ = g.world(0.6, 0.0, 0.0, z_center=height / 2)  # resting on a table at z = 0
    assert pos[2] == pytest.approx(grasp_z)


@pytest.mark.parametrize(
    ("shape", "size", "kind", "symmetry"),
    [
        ("cylinder", (0.03, 0.1), "top", 0),
        ("sphere", (0.04,), "top", 0),
        ("box", (0.05, 0.05, 0.05), "top", 4),
        ("box", (0.19, 0.07, 0.28), "top", 2),
        ("box", (0.19, 0.07, 0.28), "side", 2),
    ],
)
def test_symmetry_is_derived_from_the_shape(
    shape: str, size: tuple[float, ...], kind: str, symmetry: int
) -> None:
    assert derive_grasp(shape, size, kind).symmetry == symmetry  # type: ignore[arg-type]
    assert derive_grasp(shape, size, kind, symmetry=1).symmetry == 1  # type: ignore[arg-type]


def test_thin_objects_are_grasped_at_their_centre() -> None:
    g = derive_grasp("box", (0.07, 0.055, 0.01), "top")
    pos, _ = g.world(0.5, 0.0, 0.0, z_center=0.005)
    assert pos[2] == pytest.approx(0.005)


def test_batched_world_poses() -> None:
    g = derive_grasp("box", (0.1, 0.05, 0.05), "side")
    x = np.array([[0.5, 0.6], [0.7, 0.8]])
    pos, rot = g.world(x, np.zeros_like(x), np.zeros_like(x), z_center=0.025)
    assert pos.shape == (2, 2, 3) and rot.shape == (2, 2, 3, 3)
    np.testing.assert_allclose(pos[..., 0], x - (0.05 - FINGER_DEPTH))
