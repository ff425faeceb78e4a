"""The simulated user's choices and stick, from status messages."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.core.operator import OperatorModel
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import StatusMessage
from legws_daemon.joystick.sim_user import SimUser, UserView


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


# --- simulated operators (method.md §10) and calibrations ---------------------------------


def test_without_an_operator_the_stick_is_section_2s_draw_for_draw() -> None:
    from legws_daemon.core.user_model import clip_unit, deflection, noise

    u = user("a", sigma=0.03)
    rng = np.random.default_rng(0)
    for k in range(20):
        s = u.sample(status(a=[1.0, 0.5, 0.2]), 0.05 * k)
        assert s is not None
        expected = clip_unit(deflection(np.zeros(3), [1.0, 0.5, 0.2], noise(rng, (), 0.03, 0.05)))
        np.testing.assert_allclose(s[0], expected)


def operator_user(op: OperatorModel, seed: int = 0) -> SimUser:
    return SimUser([], op.sigma, 0.05, np.random.default_rng(seed), operator=op)


def test_an_operator_aims_with_its_bias_speed_and_steering() -> None:
    quiet = dict(sigma=1e-6, rho=0.0)
    u = operator_user(OperatorModel(0.7, bias_deg=30.0, **quiet))
    s = u.sample(status(a=[1.0, 0.0, 0.0]), 0.0)  # the only goal on offer
    assert s is not None
    turned = [np.cos(np.radians(30)), np.sin(np.radians(30)), 0.0]
    np.testing.assert_allclose(s[0], 0.7 * np.array(turned), atol=1e-4)  # left, 0.7 of full
    u = operator_user(OperatorModel(1.0, steering="axes", **quiet))
    s = u.sample(status(a=[1.0, 0.4, 0.0]), 0.0)
    assert s is not None
    np.testing.assert_allclose(s[0], [1.0, 0.0, 0.0], atol=1e-4)


def test_the_noise_is_correlated_over_the_real_time_between_samples() -> None:
    """rho per control period: two samples 1 ms apart are nearly the same, two a second apart
    (20 periods: rho^20) nearly independent; the clip keeps them in the unit ball."""
    op = OperatorModel(1.0, 0.01, 0.9, 0.0, "free")  # small noise: no clipping to speak of

    def pairs(gap: float) -> float:
        u = operator_user(op, seed=3)
        a, b = [], []
        for k in range(400):
            t = 10.0 * k
            s1 = u.sample(status(a=[10.0, 0.0, 0.0]), t)
            s2 = u.sample(status(a=[10.0, 0.0, 0.0]), t + gap)
            assert s1 is not None and s2 is not None
            a.append(s1[0][1])
            b.append(s2[0][1])
        return float(np.corrcoef(a, b)[0, 1])

    assert pairs(0.001) > 0.99
    assert abs(pairs(1.0)) < 0.25


def test_a_new_reach_starts_the_noise_afresh() -> None:
    op = OperatorModel(1.0, 0.03, 0.95, 0.0, "free")
    u = operator_user(op)
    assert u._stick is not None
    u.sample(status(a=[1.0, 0.0, 0.0]), 0.0)
    kept = u._stick._e
    u.sample(status(a=[1.0, 0.0, 0.0]), 0.05)
    assert u._stick._e is not kept  # the same reach: the noise moves on from where it was
    u.sample(status("assist", a=[1.0, 0.0, 0.0]), 0.1)  # the robot acts: hands off
    resets = []
    original = u._stick.reset
    u._stick.reset = lambda: (resets.append(1), original())[1]  # type: ignore[method-assign]
    u.sample(status(a=[1.0, 0.0, 0.0]), 5.0)  # steering again: a new reach
    assert resets == [1]


def test_in_a_calibration_it_steers_to_the_target_shown_and_never_confirms() -> None:
    for u in (user("a"), operator_user(OperatorModel(1.0, 1e-6, 0.0, 0.0, "free"))):
        s = u.sample(status("calibrate", "calibration", calibration=[0.0, 0.0, 2.0]), 0.0)
        assert s is not None
        np.testing.assert_allclose(s[0], [0.0, 0.0, 1.0], atol=1e-4)
        s = u.sample(status("calibrate", "calibration", calibration=[0.001, 0.0, 0.0]), 0.1)
        assert s is not None and not s[1].confirm  # at the target: no confirm
        s = u.sample(status("calibrate", "calibration"), 0.2)  # between targets
        assert s is not None and s[0] == (0.0, 0.0, 0.0)
        assert u.chosen == []  # a calibration target is no decision


def test_the_cli_options_make_the_operator_and_refuse_mixing_with_a_file(
    tmp_path: Path,
) -> None:
    from legws_daemon.cli.main import run
    from legws_daemon.cli.sim_user import simulated_operator

    assert simulated_operator(0.03, None, None, None, None, None) is None
    op = simulated_operator(0.03, None, 0.8, -20.0, "axes", None)
    assert op == OperatorModel(1.0, 0.03, 0.8, -20.0, "axes")
    for args in (["--rho", "1.5"], ["--bias", "90"], ["--speed", "0"], ["--steering", "diag"]):
        assert run(["joystick", "sim-user", *args, "--duration", "0.1"]) == 2
    path = tmp_path / "alice.json"
    path.write_text("{}")
    assert run(["joystick", "sim-user", "--operator", str(path), "--duration", "0.1"]) == 2
    assert run(["joystick", "sim-user", "--operator", str(path), "--rho", "0.5"]) == 2


def test_between_status_messages_it_aims_from_where_its_own_deflections_moved_the_arm() -> None:
    # the target 0.1 m along x and 0.1 m along y from the EE the status shows
    u = SimUser(["a"], 0.0, 0.2, np.random.default_rng(0))
    shown = status(a=[0.1, 0.1, 0.0])
    first = u.sample(shown, 0.0, received=0.0)
    assert first is not None
    np.testing.assert_allclose(first[0], [2**-0.5, 2**-0.5, 0.0], atol=1e-9)
    # 0.25 s later with no new status: the arm went 0.05 m along the diagonal
    later = u.sample(shown, 0.25, received=0.0)
    assert later is not None
    np.testing.assert_allclose(later[0], [2**-0.5, 2**-0.5, 0.0], atol=1e-9)
    # an aim off the diagonal shows the dead reckoning: the target straight along +y of the
    # status's EE, but the stick has pushed +x meanwhile
    u = SimUser(["a"], 0.0, 0.2, np.random.default_rng(0))
    assert u.sample(status(a=[0.2, 0.0, 0.0]), 0.0, received=0.0) is not None  # sends +x
    s = u.sample(status(a=[0.1, 0.1, 0.0]), 0.5, received=0.0)  # moved 0.1 m along +x
    assert s is not None
    np.testing.assert_allclose(s[0], [0.0, 1.0, 0.0], atol=1e-9)
    # without the time of the status, the aim is from the EE shown, as before
    u = SimUser(["a"], 0.0, 0.2, np.random.default_rng(0))
    s = u.sample(status(a=[0.1, 0.1, 0.0]), 0.5)
    assert s is not None
    np.testing.assert_allclose(s[0], [2**-0.5, 2**-0.5, 0.0], atol=1e-9)


def test_a_goal_that_is_no_target_of_the_decision_is_one_line_naming_the_targets() -> None:
    u = user("cereal")
    view = status(stage="pick", white_mug=[1, 0, 0], black_stapler=[0, 1, 0])
    with pytest.raises(InputError) as err:
        u.sample(view, 0.0)
    assert str(err.value) == (
        "--goal: cereal is not a target of decision 0 (stage pick); its targets: "
        "black_stapler, white_mug"
    )
    # goals used up at a later decision: said so, with what it offers
    u = user("a")
    assert u.sample(status(stage="s", a=[1, 0, 0], b=[0, 1, 0]), 0.0) is not None
    later = status(stage="t", c=[1, 0, 0], d=[0, 1, 0]).model_copy(update={"decision": 2})
    with pytest.raises(InputError, match=r"every goal given was gone for \(a\); decision 2"):
        u.sample(later, 0.0)
    # one candidate needs no goal of its own; outside teleop nothing is chosen
    u = user("a")
    assert u.choose(UserView.from_status(status("assist", b=[1, 0, 0]))) is None  # type: ignore[arg-type]
    assert u.sample(status(stage="s", b=[1, 0, 0]), 0.0) is not None
    assert u.chosen == [("s", "b")]
