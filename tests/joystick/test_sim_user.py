"""The simulated user's choices and stick, from status messages."""

from __future__ import annotations

from typing import Any

import numpy as np

from legws_daemon.formats.messages import StatusMessage
from legws_daemon.joystick.sim_user import SimUser


def status(mode: str = "teleop", stage: str = "s", **targets: Any) -> StatusMessage:
    return StatusMessage.model_validate(
        {"schema": 1, "robot": "r", "seq": 1, "stamp": 0.0, "mode": mode, "stage": stage,
         "adapter": "sim", "ee": {"position": [0.0, 0.0, 0.0], "quaternion": [1, 0, 0, 0]},
         "targets": targets},
    )  # fmt: skip


def user(*wants: str, sigma: float = 0.0) -> SimUser:
    return SimUser(list(wants), sigma, 0.05, np.random.default_rng(0))


def test_goes_for_the_first_wanted_goal_on_offer_without_noise() -> None:
    u = user("b", "c")
    s = u.sample(status(a=[1.0, 0.0, 0.0], b=[0.0, 2.0, 0.0]), 0.0)
    assert s is not None
    np.testing.assert_allclose(s[0], [0.0, 1.0, 0.0])
    assert u.chosen == [("s", "b")]
    # next decision: b is used up, c is on offer
    s = u.sample(status(stage="t", c=[0.0, 0.0, -3.0], b=[0.0, 2.0, 0.0]), 0.0)
    assert s is not None
    np.testing.assert_allclose(s[0], [0.0, 0.0, -1.0])
    assert u.chosen[-1] == ("t", "c")


def test_random_choice_is_seeded_and_among_the_offer() -> None:
    picks = {user().sample(status(a=[1, 0, 0], b=[0, 1, 0]), 0.0) is not None for _ in range(3)}
    assert picks == {True}
    a, b = user(), user()
    a.sample(status(a=[1, 0, 0], b=[0, 1, 0], c=[0, 0, 1]), 0.0)
    b.sample(status(a=[1, 0, 0], b=[0, 1, 0], c=[0, 0, 1]), 0.0)
    assert a.chosen == b.chosen
    assert a.chosen[0][1] in {"a", "b", "c"}


def test_confirms_at_the_goal_lets_go_during_assistance_and_cancels_once() -> None:
    u = user("a")
    s = u.sample(status(a=[0.005, 0.0, 0.0]), 0.0)
    assert s is not None
    assert s[1].confirm
    u = SimUser(["a"], 0.03, 0.05, np.random.default_rng(0), cancel_after=0.5)
    s = u.sample(status("assist", a=[1, 0, 0]), 10.0)
    assert s is not None
    assert s[0] == (0.0, 0.0, 0.0)
    assert not s[1].cancel
    s = u.sample(status("assist", a=[1, 0, 0]), 10.6)
    assert s is not None
    assert s[1].cancel
    s = u.sample(status("assist", a=[1, 0, 0]), 11.0)
    assert s is not None
    assert not s[1].cancel
    assert u.sample(None, 0.0) is None  # no status: nothing to steer by


def test_noisy_stick_stays_within_the_unit_ball() -> None:
    u = user("a", sigma=0.5)
    for _ in range(200):
        s = u.sample(status(a=[1.0, 1.0, 1.0]), 0.0)
        assert s is not None
        assert np.linalg.norm(s[0]) <= 1.0 + 1e-9
