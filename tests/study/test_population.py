"""Populations of simulated participants: validated on load, drawn within their ranges."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.validation import error_lines
from legws_daemon.study.population import load_population, populations_dir

DATA = Path(__file__).parent / "data"


@pytest.mark.parametrize("name", sorted(p.stem for p in populations_dir().glob("*.toml")))
def test_every_shipped_population_loads_and_draws_valid_operators(name: str) -> None:
    pop = load_population(name)
    o = pop.spec.operator
    rng = np.random.default_rng(0)
    people = [pop.draw(f"P{k:02d}", rng) for k in range(200)]
    for p in people:
        m = p.model
        assert o.speed.low <= m.speed <= o.speed.high
        assert o.sigma.low <= m.sigma <= o.sigma.high
        assert o.rho.low <= m.rho <= o.rho.high
        assert o.bias_deg.low <= m.bias_deg <= o.bias_deg.high
        assert p.hesitation_s >= 0
    steering = {p.model.steering for p in people}
    assert steering == {k for k, v in o.steering.items() if v > 0}
    # the truncated normal keeps its mean when the bounds are far (speed's are not)
    sigmas = np.array([p.model.sigma for p in people])
    assert abs(sigmas.mean() - o.sigma.mean) < 3 * o.sigma.sd / np.sqrt(200) + 1e-3


def test_the_same_seed_draws_the_same_participant() -> None:
    pop = load_population(DATA / "planted.toml")
    a = pop.draw("P01", np.random.default_rng([1, 2]))
    b = pop.draw("P01", np.random.default_rng([1, 2]))
    assert a == b


def test_a_planted_effect_must_name_a_condition(tmp_path: Path) -> None:
    with pytest.raises(InputError) as err:
        load_population(DATA / "planted.toml", ["early", "lte"])
    line = error_lines(err.value)[0]
    assert "planted.toml:" in line and "effects.late: a planted effect for 'late'" in line
    assert "did you mean 'lte'?" in line
    assert load_population(DATA / "planted.toml", ["early", "late"]).effect("late").tlx == 12.0
    assert load_population(DATA / "planted.toml").effect("early").hesitation_s == 0.0


def test_a_bad_distribution_names_the_file_line_and_field(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    text = (
        (DATA / "planted.toml")
        .read_text()
        .replace(
            "speed = {mean = 0.8, sd = 0.1, low = 0.5, high = 1.0}",
            "speed = {mean = 1.2, sd = 0.1, low = 0.5, high = 1.0}",
        )
    )
    bad.write_text(text.replace('name = "planted"', 'name = "bad"'), encoding="utf-8")
    with pytest.raises(InputError) as err:
        load_population(bad)
    line = error_lines(err.value)[0]
    assert line.startswith(f"{bad}:") and "operator.speed" in line
    assert "expected low <= mean <= high" in line


def test_an_unknown_population_lists_the_shipped_ones() -> None:
    with pytest.raises(InputError, match=r"unknown population 'lb'; did you mean 'lab'\?"):
        load_population("lb")
