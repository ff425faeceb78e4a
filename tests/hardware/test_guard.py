"""The guard in :class:`Adapter`'s one command path: every public method runs its hook
inside it, so an adapter's bug is a ``HardwareError``, and no subclass can go around it."""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pytest

from legws_daemon.errors import HardwareError, LegwsError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose
from tests.autonomy.rig import stand_in_profile


class _Broken(SimAdapter):
    """The stand-in, connected, whose every hook raises a non-legws error once broken."""

    broken = False

    def _fail(self) -> None:
        if self.broken:
            raise ZeroDivisionError("injected")

    def _read_state(self) -> RobotState:
        self._fail()
        return super()._read_state()

    def _kinematics(self) -> World:
        self._fail()
        return super()._kinematics()

    def _command(
        self, state: RobotState, velocity: np.ndarray, hold: np.ndarray | None, box: Box
    ) -> None:
        self._fail()

    def _command_joints(self, state: RobotState, qdot: np.ndarray) -> None:
        self._fail()

    def _connect(self) -> None:
        self._fail()
        super()._connect()

    def _disconnect(self) -> None:
        self._fail()
        super()._disconnect()

    def _grip(self, closed: bool) -> None:
        self._fail()

    def _halt(self) -> None:
        self._fail()

    def _stop_by(self, by: str) -> None:
        self._fail()

    def _paused(self, resumed: float) -> None:
        self._fail()

    def _resume(self) -> None:
        self._fail()

    def _object_poses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        self._fail()
        return {}

    def _place_objects(self, layout: Mapping[str, ObjectPose]) -> bool:
        self._fail()
        return True


#: how to call each public method of :class:`Adapter` (the state is read before breaking)
CALLS: dict[str, Callable[[Adapter, RobotState], Any]] = {
    "connect": lambda a, s: a.connect(),
    "disconnect": lambda a, s: a.disconnect(),
    "read_state": lambda a, s: a.read_state(),
    "kinematics": lambda a, s: a.kinematics,
    "send_velocity": lambda a, s: a.send_velocity(s, np.array([0.05, 0.0, 0.0])),
    "send_joint_velocity": lambda a, s: a.send_joint_velocity(s, np.full(7, 0.1)),
    "grip": lambda a, s: a.grip(True),
    "halt": lambda a, s: a.halt(),
    "stop_by": lambda a, s: a.stop_by("operator"),
    "paused": lambda a, s: a.paused(0.0),
    "resume": lambda a, s: a.resume(),
    "object_poses": lambda a, s: a.object_poses(),
    "place_objects": lambda a, s: a.place_objects({}),
    "stop": lambda a, s: a.stop(),
}


def _public(cls: type) -> set[str]:
    return {n for n, _ in inspect.getmembers(cls) if not n.startswith("_")}


@pytest.fixture(scope="module")
def profile() -> ProfileSpec:
    return stand_in_profile()


def test_every_public_method_that_reaches_the_robot_is_final_and_guarded(
    profile: ProfileSpec,
) -> None:
    # a public method added to Adapter must join FINAL and CALLS (then this test checks it)
    other = {"envelope", "FINAL"}  # the box from the profile alone; the set itself
    assert _public(Adapter) - other == set(CALLS)
    assert set(CALLS) <= Adapter.FINAL
    for name, call in CALLS.items():
        a = _Broken(profile, load_scene("desk"))
        a.connect()
        state = a.read_state()
        a.broken = True
        with pytest.raises(HardwareError, match=r": ZeroDivisionError: injected") as err:
            call(a, state)
        assert isinstance(err.value.__cause__, ZeroDivisionError), name


def test_a_subclass_that_defines_a_public_method_is_refused() -> None:
    with pytest.raises(TypeError, match="read_state"):

        class _Around(SimAdapter):  # would read the robot around the guard
            def read_state(self) -> RobotState:  # type: ignore[misc]
                return super()._read_state()

    with pytest.raises(TypeError, match="_send_velocity"):

        class _NoEnvelope(SimAdapter):  # would send without the envelope
            def _send_velocity(  # type: ignore[override]
                self, state: RobotState, velocity: object, hold: Any, floor: Any
            ) -> Any:
                return velocity


def test_expected_errors_pass_unchanged(profile: ProfileSpec) -> None:
    a = SimAdapter(profile, load_scene("desk"))
    with pytest.raises(Exception, match="not connected") as err:
        a.read_state()  # a LegwsError of the adapter's own, as it raised it
    assert not isinstance(err.value, HardwareError)
    assert isinstance(err.value, LegwsError)
