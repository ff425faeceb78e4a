"""The adapter registry and the sim adapter on the real MuJoCo model."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import legws_daemon.hardware.sim  # noqa: F401  (registers "sim")
from legws_daemon.errors import InputError
from legws_daemon.formats.profile import load_profile
from legws_daemon.hardware.base import adapter_class
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.scene.catalog import load_scene

PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sim.toml"


@pytest.fixture
def adapter() -> SimAdapter:
    profile = load_profile(PROFILE)
    fast = profile.model_copy(update={"sim": profile.sim.model_copy(update={"realtime": False})})
    return SimAdapter(fast, load_scene("desk"))


def test_registry() -> None:
    assert adapter_class("sim") is SimAdapter
    with pytest.raises(InputError, match=r"known: .*sim"):
        adapter_class("ur5")


def test_starts_at_home_and_moves_as_commanded(adapter: SimAdapter) -> None:
    with adapter:
        s0 = adapter.read_state()
        np.testing.assert_allclose(s0.ee_position, adapter.scene.home.position, atol=1e-3)
        for _ in range(20):
            sent = adapter.send_velocity(adapter.read_state(), [0.03, 0.0, -0.02])
            np.testing.assert_allclose(sent, [0.03, 0.0, -0.02])
        s1 = adapter.read_state()
        np.testing.assert_allclose(s1.ee_position - s0.ee_position, [0.03, 0.0, -0.02], atol=2e-3)


def test_what_is_sent_is_clamped_and_bad_commands_are_zero(adapter: SimAdapter) -> None:
    with adapter:
        sent = adapter.send_velocity(adapter.read_state(), [3.0, 0.0, 0.0])
        assert math.isclose(float(np.linalg.norm(sent)), adapter.v_max)
        p = adapter.read_state().ee_position
        np.testing.assert_array_equal(
            adapter.send_velocity(adapter.read_state(), [math.nan, 0.0, 0.0]), 0.0
        )
        np.testing.assert_array_equal(adapter.read_state().ee_position, p)  # did not move
        np.testing.assert_array_equal(adapter.stop(), 0.0)
        # pushing down into the table for a while: the EE never leaves the workspace box
        for _ in range(200):
            adapter.send_velocity(adapter.read_state(), [0.0, 0.0, -0.1])
        assert adapter.box.contains(adapter.read_state().ee_position, tol=1e-6)
