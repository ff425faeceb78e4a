"""Goal-set files: validation, normalisation, defaults and the write/read round trip."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.goalset import goalset_from_data, goalset_to_data, load_goalset
from legws_daemon.scene.layout_file import dump_json
from tests.cli.helpers import EXAMPLE_GOALSET

X0 = {"position": [0.55, 0.0, 0.30], "quaternion": [0, 1, 0, 0]}


def example() -> dict[str, Any]:
    return {
        "x0": {"position": [0.55, 0.0, 0.30], "quaternion": [0, 1, 0, 0]},
        "goals": [
            {"name": "mug", "position": [0.62, 0.21, 0.07], "quaternion": [0, 1, 0, 0]},
            {"name": "stapler", "position": [0.70, -0.18, 0.04], "quaternion": [0, 0, 2, 0]},
        ],
    }


# --- strategies -----------------------------------------------------------------------

coords = st.tuples(
    st.floats(0.2, 1.0, allow_nan=False),
    st.floats(-0.6, 0.6, allow_nan=False),
    st.floats(-0.1, 0.5, allow_nan=False),
).map(list)


@st.composite
def quaternions(draw: st.DrawFn) -> list[float]:
    """A random rotation, given with a random (non-unit) norm and sign."""
    q = draw(st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 4))
    norm = float(np.linalg.norm(q))
    assume(norm > 0.1)
    scale = draw(st.sampled_from([1.0, -1.0, 0.01, 3.7, -250.0]))
    return [float(c / norm * scale) for c in q]


@st.composite
def goal_set_documents(draw: st.DrawFn) -> dict[str, Any]:
    x0 = {"position": draw(coords), "quaternion": draw(quaternions())}
    m = draw(st.integers(2, 8))
    names = draw(st.lists(st.text(min_size=1, max_size=12), min_size=m, max_size=m, unique=True))
    goals = []
    for name in names:
        position = draw(coords)
        assume(np.linalg.norm(np.subtract(position, x0["position"])) >= 0.01)
        goal: dict[str, Any] = {
            "name": name,
            "position": position,
            "quaternion": draw(quaternions()),
        }
        symmetry = draw(st.one_of(st.none(), st.integers(0, 4)))
        if symmetry is not None:
            goal["symmetry"] = symmetry
        goals.append(goal)
    return {"x0": x0, "goals": goals}


def unit(q: Any) -> np.ndarray:
    arr = np.asarray(q, dtype=np.float64)
    return arr / np.linalg.norm(arr)


def same_rotation(a: Any, b: Any) -> bool:
    """Quaternions equal up to sign (q and -q are one rotation)."""
    return abs(float(np.dot(unit(a), unit(b)))) == pytest.approx(1.0, abs=1e-12)


def assert_same_goal_set(a: GoalSet, b: GoalSet) -> None:
    """Equal names, positions and symmetry; quaternions equal up to re-normalisation (1 ulp)."""
    assert a.names == b.names
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_allclose(a.quaternions, b.quaternions, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(a.symmetry, b.symmetry)
    np.testing.assert_array_equal(a.x0.position, b.x0.position)
    np.testing.assert_allclose(a.x0.quaternion, b.x0.quaternion, rtol=0, atol=1e-15)


# --- round trip -----------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(goal_set_documents())
def test_round_trip(doc: dict[str, Any]) -> None:
    goals, params = goalset_from_data(doc, "doc")
    # faithful to the input
    assert list(goals.names) == [g["name"] for g in doc["goals"]]
    np.testing.assert_array_equal(goals.positions, [g["position"] for g in doc["goals"]])
    np.testing.assert_array_equal(goals.x0.position, doc["x0"]["position"])
    assert goals.symmetry.tolist() == [g.get("symmetry", 1) for g in doc["goals"]]
    for q_in, q_out in zip([g["quaternion"] for g in doc["goals"]], goals.quaternions, strict=True):
        assert np.linalg.norm(q_out) == pytest.approx(1.0, abs=1e-12)
        assert same_rotation(q_in, q_out)
    assert same_rotation(doc["x0"]["quaternion"], goals.x0.quaternion)
    assert params == Params()

    # written and read back: identical, in memory and through a JSON file
    data = goalset_to_data(goals, params)
    again, params_again = goalset_from_data(data, "written")
    assert_same_goal_set(goals, again)
    assert params_again == params
    from_text, _ = goalset_from_data(json.loads(dump_json(data)), "text")
    assert_same_goal_set(goals, from_text)


def test_round_trip_through_file(tmp_path: Path) -> None:
    doc = example()
    doc["params"] = {"beta": 2, "cost": "ratio"}
    goals, params = goalset_from_data(doc, "doc")
    path = tmp_path / "goals.json"
    path.write_text(dump_json(goalset_to_data(goals, params)), encoding="utf-8")
    again, params_again = load_goalset(path)
    assert_same_goal_set(goals, again)
    assert params_again == params


def test_written_file_has_every_field() -> None:
    goals, params = goalset_from_data(example(), "doc")
    data = goalset_to_data(goals, params)
    assert set(data) == {"x0", "goals", "params"}
    assert data["params"] == Params().as_dict()
    for goal in data["goals"]:
        assert set(goal) == {"name", "position", "quaternion", "symmetry"}
        assert all(type(v) is float for v in goal["position"] + goal["quaternion"])
        assert type(goal["symmetry"]) is int


# --- normalisation and defaults -------------------------------------------------------


@pytest.mark.parametrize(
    ("given_q", "unit_q"),
    [
        ([0, 0, 2, 0], [0, 0, 1, 0]),
        ([3, 0, 0, 4], [0.6, 0, 0, 0.8]),
        ([-3, 0, 0, 4], [0.6, 0, 0, -0.8]),  # w made non-negative: same rotation
        ([0.5, 0.5, 0.5, 0.5], [0.5, 0.5, 0.5, 0.5]),
        ([1e-4, 0, 0, 0], [1, 0, 0, 0]),
    ],
)
def test_quaternions_are_normalised(given_q: list[float], unit_q: list[float]) -> None:
    doc = example()
    doc["goals"][1]["quaternion"] = given_q
    doc["x0"]["quaternion"] = given_q
    goals, _ = goalset_from_data(doc, "doc")
    np.testing.assert_allclose(goals.quaternions[1], unit_q, atol=1e-15)
    np.testing.assert_allclose(goals.x0.quaternion, unit_q, atol=1e-15)


def test_default_symmetry_is_one() -> None:
    doc = example()
    doc["goals"][0]["symmetry"] = 0
    goals, _ = goalset_from_data(doc, "doc")
    assert goals.symmetry.tolist() == [0, 1]


@pytest.mark.parametrize("params", [None, {}])
def test_params_default(params: dict[str, Any] | None) -> None:
    doc = example()
    if params is not None:
        doc["params"] = params
    _, got = goalset_from_data(doc, "doc")
    assert got == Params()
    assert got.cost == "dragan"


def test_params_override() -> None:
    doc = example()
    doc["params"] = {"beta": 2, "sigma": 0.01, "cost": "ratio", "horizon_fraction": 1}
    _, got = goalset_from_data(doc, "doc")
    assert got == Params(beta=2.0, sigma=0.01, cost="ratio", horizon_fraction=1.0)
    assert got.alpha == Params().alpha  # the rest keep their defaults


def test_interfaces_example_params_are_the_defaults() -> None:
    doc = example()
    doc["params"] = copy.deepcopy(EXAMPLE_GOALSET["params"])
    assert goalset_from_data(doc, "doc")[1] == Params()


# --- errors name the source and the field ----------------------------------------------


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        pytest.param(lambda d: d["goals"][1].pop("position"), "goals[1].position", id="missing"),
        pytest.param(
            lambda d: d["goals"][0].update(position=["0.6", 0.2, 0.07]),
            "goals[0].position[0]",
            id="string",
        ),
        pytest.param(lambda d: d["goals"].pop(), "goals", id="one-goal"),
        pytest.param(lambda d: d["goals"][1].update(name="mug"), "goals", id="duplicate-name"),
        pytest.param(
            lambda d: d["goals"][1].update(position=[0.55, 0.0, 0.3005]),
            "goals[1].position",
            id="half-a-millimetre-from-x0",
        ),
        pytest.param(lambda d: d.update(params={"cost": "x"}), "params.cost", id="cost"),
        pytest.param(lambda d: d.update(params={"sigma": -1}), "params.sigma", id="sigma"),
        pytest.param(lambda d: d.update(params={"betta": 5}), "params.betta", id="typo"),
    ],
)
def test_errors_name_source_and_field(edit: Any, field: str) -> None:
    doc = example()
    edit(doc)
    with pytest.raises(InputError) as info:
        goalset_from_data(doc, "my.json")
    message = str(info.value)
    assert message.startswith(f"my.json: {field}")
    assert "\n" not in message


def test_goal_just_over_a_millimetre_from_x0_is_fine() -> None:
    doc = example()
    doc["goals"][1]["position"] = [0.55, 0.0, 0.3015]
    goals, _ = goalset_from_data(doc, "doc")
    assert goals.m == 2
