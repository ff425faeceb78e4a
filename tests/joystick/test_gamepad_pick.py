"""The operator's full hand: a gamepad's sticks, rotation axis and gripper button drive a
pick to a lift with no assistance at all (``assist = "none"``) — real ``evdev`` events
through the real reader (the xbox mapping), each sample through the daemon's inbox to the
controller on the MuJoCo stand-in. The only fake is the pad itself (tests/joystick/
fake_evdev.py)."""

from __future__ import annotations

import math

import numpy as np
from evdev import ecodes

from legws_daemon.core.geometry import symmetric_angle
from legws_daemon.formats.input_mapping import load_mapping_named
from legws_daemon.joystick.evdev_input import EvdevReader
from legws_daemon.joystick.publisher import Sample
from legws_daemon.scene.catalog import load_scene
from legws_daemon.sim.protocol import LIFT_CLEARANCE
from tests.autonomy.rig import Rig, stand_in_profile
from tests.joystick.fake_evdev import FakeInputDir, FakeNode, xbox_pad

EV_KEY, EV_ABS = ecodes.EV_KEY, ecodes.EV_ABS
_, XBOX = load_mapping_named("xbox")
DEADZONE = 0.15  # the xbox mapping's sticks: deadzone 0.15, quadratic


def raw(value: float, invert: bool = True) -> int:
    """The stick position (evdev counts) that the xbox mapping reads as ``value``."""
    v = max(-1.0, min(1.0, value))
    if v == 0.0:
        return 0
    n = DEADZONE + (1 - DEADZONE) * math.sqrt(abs(v))
    count = round(math.copysign(n, v) * 32767)
    return -count if invert else count


class Operator:
    """Holds LB (hold-to-run) and moves the pad's sticks; presses Y for the gripper."""

    def __init__(self, node: FakeNode, reader: EvdevReader) -> None:
        self.node, self.reader = node, reader
        node.frame((EV_KEY, ecodes.BTN_TL, 1))

    def hold(self, move: np.ndarray, yaw: float = 0.0) -> Sample:
        x, y, z = (float(v) for v in move)
        self.node.frame(
            (EV_ABS, ecodes.ABS_Y, raw(x)), (EV_ABS, ecodes.ABS_X, raw(y)),
            (EV_ABS, ecodes.ABS_RY, raw(z)), (EV_ABS, ecodes.ABS_RX, raw(yaw)),
        )  # fmt: skip
        self.reader.pump()
        return self.reader.sample()

    def press_gripper(self) -> Sample:
        self.node.frame((EV_KEY, ecodes.BTN_NORTH, 1))
        self.reader.pump()
        sample = self.reader.sample()
        self.node.frame((EV_KEY, ecodes.BTN_NORTH, 0))
        self.reader.pump()
        return sample


def _feed(rig: Rig, sample: Sample) -> None:
    axes, buttons = sample[0], sample[1]
    rotation = sample[2] if len(sample) == 3 else None
    rig.c.tick(rig.sample(axes, rotation, **buttons.model_dump(exclude_none=True)))


def test_a_gamepad_turns_grips_and_lifts_an_object_by_hand(devices: FakeInputDir) -> None:
    profile = stand_in_profile()
    profile = profile.model_copy(
        update={"control": profile.control.model_copy(update={"assist": "none"})}
    )
    rig = Rig(profile, load_scene("desk"))
    node = xbox_pad()
    devices.plug(3, node)
    reader = EvdevReader(XBOX, folder=devices.folder, opener=devices.open, retry=0.5)
    reader.open()
    hand = Operator(node, reader)
    goal = "black_stapler"  # a grasp from above, a quarter turn from the home orientation
    t = rig.c.stage.target(goal)
    pre = t.position - 0.08 * t.rotation[:, 2]  # above it, on the approach axis
    turned = False
    for phase, where in (("above", pre), ("down", t.position)):
        for _ in range(1500):
            s = rig.adapter.read_state()
            error = where - s.ee_position
            dist = float(np.linalg.norm(error))
            angle = float(symmetric_angle(s.ee_rotation, t.rotation, t.symmetry))
            if dist < 0.004 and angle < 0.03:
                break
            move = error / max(dist, 1e-9) * min(1.0, dist / 0.03)
            # the yaw still to turn, the sign from the z axis of R_goal R_ee^T
            r = t.rotation @ s.ee_rotation.T
            yaw = math.atan2(r[1, 0] - r[0, 1], r[0, 0] + r[1, 1])
            if abs(yaw) > math.pi / 2:  # the symmetric grasp: the nearer half turn
                yaw -= math.copysign(math.pi, yaw)
            _feed(rig, hand.hold(move, yaw=min(1.0, max(-1.0, 1.5 * yaw))))
            turned = turned or abs(yaw) > 0.5
        else:
            raise AssertionError(f"{phase}: {dist:.3f} m, {angle:.3f} rad left")
    assert turned and rig.c.mode == "teleop" and rig.c.committed is None  # nothing assisted
    assert not rig.adapter.grips
    _feed(rig, hand.press_gripper())
    assert rig.adapter.grips == [True]
    assert rig.adapter.held == goal
    assert rig.c.held is not None and rig.c.held.name == goal
    z0 = rig.adapter.object_poses()[goal][0][2]
    for _ in range(200):  # the right stick up: lift
        _feed(rig, hand.hold(np.array([0.0, 0.0, 1.0])))
    lifted = rig.adapter.object_poses()[goal][0][2] - z0
    assert lifted > 0.05 + LIFT_CLEARANCE
    assert rig.kinds().count("commit") == 0
    reader.close()
    rig.c.shutdown()
